"""Naive dense references (test oracles): every pixel against every face, plain autograd.

These are deliberately simple and slow (memory ~ H * W * F per intermediate). They implement the
same definitions as :mod:`easyhoi.render.soft` and :mod:`easyhoi.render.raster` through a separate
formulation (barycentric inside tests, per-edge distance written out), so a culling or analytic
gradient bug in the fast code shows up as a disagreement.
"""

from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

from easyhoi.render._common import as_camera, as_faces, as_verts, check_positive


def _segment_dist2(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distance from points (M, 1, 2) to segments (1, F, 2)-(1, F, 2) -> (M, F)."""
    ab = b - a
    ap = p - a
    denom = (ab * ab).sum(-1).clamp(min=1e-30)
    s = ((ap * ab).sum(-1) / denom).clamp(0.0, 1.0)
    q = a + s.unsqueeze(-1) * ab
    return ((p - q) ** 2).sum(-1)


def _log_empty_chunk(p: torch.Tensor, tri: torch.Tensor, sigma: float) -> torch.Tensor:
    """(M, 2) pixels, (F, 3, 2) triangles -> (M,) sum over faces of log(1 - D)."""
    P = p[:, None, :]
    A, Bv, C = tri[None, :, 0], tri[None, :, 1], tri[None, :, 2]
    d2 = torch.minimum(
        torch.minimum(_segment_dist2(P, A, Bv), _segment_dist2(P, Bv, C)), _segment_dist2(P, C, A)
    )
    # inside: barycentric coordinates all of one sign (either winding)
    v0, v1, v2 = Bv - A, C - A, P - A
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]
    l2 = v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]
    l0 = det - l1 - l2
    pos = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    neg = (l0 <= 0) & (l1 <= 0) & (l2 <= 0)
    sign = torch.where(pos | neg, 1.0, -1.0).to(p.dtype)
    # log(1 - sigmoid(x)) == logsigmoid(-x), the stable form of log(1 - D)
    return torch.nn.functional.logsigmoid(-sign * d2 / sigma).sum(1)


def dense_soft_silhouette(
    verts,
    faces,
    camera,
    sigma: float = 1.0,
    near: float = 1e-3,
    chunk_faces: int | None = None,
) -> torch.Tensor:
    """Dense soft silhouette: all pixels x all faces, ``1 - prod(1 - D)``.

    Args:
        verts: (V, 3) or (B, V, 3) world vertices.
        faces: (F, 3) integer.
        camera: :class:`~easyhoi.structures.Camera`.
        sigma: sharpness in pixels squared.
        near: faces with any vertex at camera z < near are dropped.
        chunk_faces: if given, faces are processed in chunks of this size with activation
            checkpointing, bounding memory at ``H * W * chunk_faces`` per intermediate (still
            evaluating every pair).

    Returns:
        (H, W) or (B, H, W) coverage in [0, 1].
    """
    camera = as_camera(camera)
    sigma = check_positive(sigma, "sigma")
    v, batched = as_verts(verts)
    f = as_faces(faces, v.shape[1])
    H, W = camera.height, camera.width
    pix = camera.pixel_centers().reshape(-1, 2)
    outs = []
    for b in range(v.shape[0]):
        logs = torch.zeros(H * W, dtype=camera.K.dtype)
        if f.shape[0] and v.shape[1]:
            uv, z = camera.project(v[b].to(camera.K.dtype))
            ok = (z[f] >= near).all(dim=1)
            tri = uv[f[ok]]
            step = chunk_faces or max(tri.shape[0], 1)
            for s in range(0, tri.shape[0], step):
                part = tri[s : s + step]
                if chunk_faces:
                    logs = logs + checkpoint(
                        _log_empty_chunk, pix, part, sigma, use_reentrant=False
                    )
                else:
                    logs = logs + _log_empty_chunk(pix, part, sigma)
        outs.append(-torch.expm1(logs).view(H, W))
    out = torch.stack(outs)
    return out if batched else out[0]


@torch.no_grad()
def dense_depth_layers(verts, faces, camera, num_layers: int = 4, near: float = 1e-3):
    """Dense hard rasterization reference: per pixel, the sorted camera depths of every hit.

    Pixel-centre containment is inclusive (a centre on an edge hits both faces), so use generic
    geometry when comparing with :func:`easyhoi.render.raster.peel`.

    Returns:
        depth: (H, W, num_layers) ascending camera z, ``inf`` where fewer hits.
        face_ids: (H, W, num_layers) long, -1 where fewer hits.
    """
    camera = as_camera(camera)
    v, _ = as_verts(verts)
    f = as_faces(faces, v.shape[1])
    H, W = camera.height, camera.width
    uv, z = camera.project(v[0].to(camera.K.dtype))
    P = camera.pixel_centers().reshape(-1, 1, 2)
    tri, tz = uv[f][None], z[f][None]
    A, Bv, C = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    v0, v1, v2 = Bv - A, C - A, P - A
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]) / det
    l0 = 1.0 - l1 - l2
    hit = (l0 >= 0) & (l1 >= 0) & (l2 >= 0) & (det != 0) & (tz >= near).all(-1)
    depth = 1.0 / (l0 / tz[..., 0] + l1 / tz[..., 1] + l2 / tz[..., 2])
    depth = torch.where(hit, depth, torch.full_like(depth, float("inf")))
    k = min(num_layers, depth.shape[1])
    d, idx = depth.sort(dim=1)
    d, idx = d[:, :k], idx[:, :k]
    ids = torch.where(torch.isfinite(d), idx, torch.full_like(idx, -1))
    pad = num_layers - k
    if pad:
        d = torch.cat([d, torch.full((d.shape[0], pad), float("inf"), dtype=d.dtype)], 1)
        ids = torch.cat([ids, torch.full((ids.shape[0], pad), -1, dtype=ids.dtype)], 1)
    return d.view(H, W, num_layers), ids.view(H, W, num_layers)
