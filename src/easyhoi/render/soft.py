"""Differentiable soft silhouettes (SoftRas-style coverage) with screen-space culling.

For a pixel centre ``p`` and a projected triangle ``T`` let ``d`` be the 2D distance (pixels)
from ``p`` to the boundary of ``T`` and ``delta = +1`` if ``p`` is inside ``T``, ``-1`` outside.
The triangle's coverage probability is ``D = sigmoid(delta * d**2 / sigma)`` and the silhouette is
the probabilistic union ``A = 1 - prod_T (1 - D_T)``, evaluated as
``A = 1 - exp(sum_T log sigmoid(-delta d**2 / sigma))`` (numerically stable: no ``log(0)``).

``sigma`` is in pixels squared: the coverage is 0.27 at ``d = sqrt(sigma)`` px outside an edge and
1e-8 at ``sqrt(18.4 sigma)`` px. SoftRas's customary ``sigma = 1e-4`` in normalised device
coordinates equals ``1e-4 * (S / 2) ** 2`` px^2 for an ``S`` px image (1.64 px^2 at 256 px); use
:func:`sigma_from_ndc` to convert.

Culling: only pairs (pixel, face) whose pixel centre lies in the face's bounding box grown by
``margin = sqrt(sigma * log(1 / cull_eps))`` pixels are evaluated; every neglected term has
``D < cull_eps``. Pairs are generated vectorized and aggregated by scatter-add of
``log(1 - D)``; the backward pass is analytic (envelope theorem on the closest edge point),
saving only five numbers per pair.

Conventions: coverage is orientation independent, so back faces are included. A face with any
vertex closer to the camera than ``near`` (camera z, world units) is dropped (no clipping); a mesh
entirely behind the camera, an empty mesh or a mesh outside the image renders a zero mask.
"""

from __future__ import annotations

import math

import torch

from easyhoi.render._common import (
    as_camera,
    as_faces,
    as_verts,
    bbox_pairs,
    check_positive,
    pixel_uv,
    project_faces,
)
from easyhoi.structures import Camera

#: Default sharpness in pixels squared.
DEFAULT_SIGMA = 1.0
#: Default near plane (camera z, world units).
DEFAULT_NEAR = 1e-3
#: Default bound on each neglected coverage term.
DEFAULT_CULL_EPS = 1e-8


def sigma_from_ndc(sigma_ndc: float, camera: Camera) -> float:
    """Convert a SoftRas sigma in normalised device coordinates to pixels squared.

    NDC span 2 units over ``max(width, height)`` pixels, so one NDC unit is ``max(W, H) / 2`` px.
    """
    return float(sigma_ndc) * (max(camera.width, camera.height) / 2.0) ** 2


def cull_margin(sigma: float, cull_eps: float = DEFAULT_CULL_EPS) -> float:
    """Bounding-box growth in pixels beyond which every coverage term is below ``cull_eps``."""
    return math.sqrt(sigma * math.log(1.0 / cull_eps))


def _pair_terms(tri: torch.Tensor, p: torch.Tensor, sigma: float):
    """Per-pair ``x = delta d^2 / sigma`` and the closest boundary point data.

    Args:
        tri: (P, 3, 2) triangle corners per pair.
        p: (P, 2) pixel centres.
    Returns:
        x: (P,), r: (P, 2) ``p - closest``, t: (P,) edge parameter, k: (P,) closest edge
        (edge k runs from corner k to corner (k + 1) % 3), delta: (P,) +-1.
    """
    a = tri
    e = torch.roll(tri, shifts=-1, dims=1) - a  # (P, 3, 2) edge vectors
    w = p.unsqueeze(1) - a  # (P, 3, 2)
    ee = (e * e).sum(-1).clamp(min=1e-30)
    t = ((w * e).sum(-1) / ee).clamp(0.0, 1.0)  # (P, 3)
    r = w - t.unsqueeze(-1) * e
    d2 = (r * r).sum(-1)
    d2min, k = d2.min(dim=1)
    cross = e[..., 0] * w[..., 1] - e[..., 1] * w[..., 0]  # (P, 3)
    inside = (cross >= 0).all(dim=1) | (cross <= 0).all(dim=1)
    delta = inside.to(tri.dtype) * 2.0 - 1.0
    x = delta * d2min / sigma
    kk = k.unsqueeze(1)
    r_k = r.gather(1, kk.unsqueeze(-1).expand(-1, 1, 2)).squeeze(1)
    t_k = t.gather(1, kk).squeeze(1)
    return x, r_k, t_k, k, delta


class _SoftLogSum(torch.autograd.Function):
    """Per-pixel ``sum_T log(1 - D_T)`` over culled pairs, with an analytic backward."""

    @staticmethod
    def forward(ctx, tri_uv, face, pix, p, sigma: float, num_pix: int):
        tri = tri_uv[face]
        x, r, t, k, delta = _pair_terms(tri, p, sigma)
        val = torch.nn.functional.logsigmoid(-x)
        out = torch.zeros(num_pix, dtype=tri_uv.dtype, device=tri_uv.device)
        out.index_add_(0, pix, val)
        # d val / d d2 = -sigmoid(x) * delta / sigma ; d d2 / d a = -2 r (1 - t), d b = -2 r t
        coef = torch.sigmoid(x) * delta * (2.0 / sigma)
        ctx.save_for_backward(face, pix, coef, r, t, k.to(torch.uint8))
        ctx.num_faces = tri_uv.shape[0]
        return out

    @staticmethod
    def backward(ctx, grad_out):
        face, pix, coef, r, t, k = ctx.saved_tensors
        s = (grad_out[pix] * coef).unsqueeze(1)  # (P, 1)
        ga = s * (1.0 - t).unsqueeze(1) * r  # gradient w.r.t. the edge's start corner
        gb = s * t.unsqueeze(1) * r  # ... and its end corner
        k = k.long()
        n = ctx.num_faces
        grad = torch.zeros(n * 3, 2, dtype=coef.dtype, device=coef.device)
        grad.index_add_(0, face * 3 + k, ga)
        grad.index_add_(0, face * 3 + (k + 1) % 3, gb)
        return grad.view(n, 3, 2), None, None, None, None, None


def soft_silhouette(
    verts,
    faces,
    camera: Camera,
    sigma: float = DEFAULT_SIGMA,
    near: float = DEFAULT_NEAR,
    cull_eps: float = DEFAULT_CULL_EPS,
) -> torch.Tensor:
    """Render a soft silhouette, differentiable w.r.t. ``verts`` and the camera's K, R, t.

    Args:
        verts: (V, 3) or (B, V, 3) float world-space vertices.
        faces: (F, 3) integer vertex indices (winding irrelevant).
        camera: :class:`~easyhoi.structures.Camera`; its tensors may require gradients.
        sigma: sharpness in pixels squared (see module docstring).
        near: faces with a vertex at camera z < ``near`` are dropped.
        cull_eps: bound on every neglected per-face coverage term.

    Returns:
        (H, W) or (B, H, W) coverage in [0, 1], dtype of ``camera.K``. Zero for empty meshes,
        meshes behind the camera or outside the image.

    Raises:
        InvalidInputError: wrong shapes, NaN/inf vertices, faces out of range, non-positive
            ``sigma``/``near``, ``cull_eps`` outside (0, 1), or a non-Camera camera.
    """
    out, _ = soft_log_visibility(verts, faces, camera, sigma, near, cull_eps)
    return out


def soft_log_visibility(
    verts,
    faces,
    camera: Camera,
    sigma: float = DEFAULT_SIGMA,
    near: float = DEFAULT_NEAR,
    cull_eps: float = DEFAULT_CULL_EPS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Like :func:`soft_silhouette` but also returns ``log(1 - A)`` = ``sum_T log(1 - D_T)``.

    Returns:
        silhouette: (H, W) or (B, H, W); log_empty: same shape, ``log(1 - silhouette)`` (<= 0),
        finite even where the silhouette rounds to 1.
    """
    camera = as_camera(camera)
    sigma = check_positive(sigma, "sigma")
    near = check_positive(near, "near")
    cull_eps = check_positive(cull_eps, "cull_eps")
    if cull_eps >= 1:
        from easyhoi.errors import InvalidInputError

        raise InvalidInputError(f"cull_eps must be in (0, 1), got {cull_eps}")
    v, batched = as_verts(verts)
    f = as_faces(faces, v.shape[1])
    H, W = camera.height, camera.width
    B, F = v.shape[0], f.shape[0]
    dtype = camera.K.dtype
    if v.shape[1] == 0 or F == 0:
        logs = torch.zeros(B, H, W, dtype=dtype, device=camera.K.device)
    else:
        tri_uv, _, keep = project_faces(v, f, camera, near)
        face, pix = bbox_pairs(tri_uv, H, W, cull_margin(sigma, cull_eps))
        pix = pix + torch.div(keep[face], F, rounding_mode="floor") * (H * W)
        p = pixel_uv(pix, W, H, dtype)
        logs = _SoftLogSum.apply(tri_uv, face, pix, p, sigma, B * H * W).view(B, H, W)
    sil = -torch.expm1(logs)
    if not batched:
        return sil[0], logs[0]
    return sil, logs
