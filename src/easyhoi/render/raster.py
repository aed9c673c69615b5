"""Hard rasterization and depth peeling (every surface layer along each pixel ray).

A pixel is hit by a face when its centre ``(j + 0.5, i + 0.5)`` lies inside the projected
triangle (exact edge functions; a centre exactly on an edge shared by two faces counts for one of
them only, by the top-left rule applied after orienting each triangle counter-clockwise).
Candidate (pixel, face) pairs come from the faces' bounding boxes (no dense product); hits are
sorted by (pixel, depth) and the first ``num_layers`` kept.

Depth is the camera-frame z of the hit (perspective-correct: ``1/z`` is interpolated linearly in
screen space); barycentrics are perspective-correct (they interpolate world attributes), and
``points = sum_i bary_i * X_i`` are world-space hit points, all three differentiable w.r.t. the
vertices and the camera (the choice of faces is not). Faces with a vertex at camera z < ``near``
are dropped; back faces are kept (peeling needs every layer). Empty slots: ``face_ids = -1``,
``depth = inf``, ``bary = points = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from easyhoi.errors import InvalidInputError
from easyhoi.render._common import (
    as_camera,
    as_faces,
    as_verts,
    bbox_pairs,
    check_positive,
    get_backend,
    numba_call,
    pixel_uv,
    project_faces,
)
from easyhoi.structures import Camera

DEFAULT_LAYERS = 4
_QUERY_CHUNK = 1 << 24  # candidate (query, face) comparisons per chunk in peel_pixels


@dataclass(frozen=True)
class Fragments:
    """Per-pixel (or per-query) surface hits, nearest first.

    Attributes:
        face_ids: (*S, K) long, face index into the input ``faces``; -1 where no hit.
        depth: (*S, K) camera-frame z of the hit, ascending along K; ``inf`` where no hit.
        bary: (*S, K, 3) perspective-correct barycentric coordinates; 0 where no hit.
        points: (*S, K, 3) world-space hit points; 0 where no hit.

    ``*S`` is ``(H, W)`` for :func:`rasterize` / :func:`peel` and ``(N,)`` for
    :func:`peel_pixels`.
    """

    face_ids: torch.Tensor
    depth: torch.Tensor
    bary: torch.Tensor
    points: torch.Tensor

    @property
    def mask(self) -> torch.Tensor:
        """(*S, K) bool, True where a hit exists."""
        return self.face_ids >= 0

    @property
    def num_layers(self) -> int:
        return self.face_ids.shape[-1]

    def detach(self) -> Fragments:
        return replace(self, depth=self.depth.detach(), bary=self.bary.detach(),
                       points=self.points.detach())  # fmt: skip


def _edge_terms(tri: torch.Tensor, p: torch.Tensor):
    """Edge functions of pixel ``p`` (P, 2) for triangles ``tri`` (P, 3, 2).

    Returns ``w`` (P, 3) with ``w[:, k]`` the cross product of edge k (corner k -> k+1) with
    ``p - corner_k``, multiplied by the orientation sign, ``s`` (P,) the sign and
    ``area2`` (P,) the signed doubled area.
    """
    e = torch.roll(tri, shifts=-1, dims=1) - tri
    d = p.unsqueeze(1) - tri
    w = e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]
    area2 = e[:, 0, 0] * (-e[:, 2, 1]) - e[:, 0, 1] * (-e[:, 2, 0])
    s = torch.where(area2 < 0, -1.0, 1.0).to(tri.dtype)
    return w * s.unsqueeze(1), s, area2, e


def _inside(tri: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """(P,) bool: pixel centre inside triangle, top-left rule on edges, degenerate -> False."""
    w, s, area2, e = _edge_terms(tri, p)
    oe = e * s.view(-1, 1, 1)  # edges of the counter-clockwise-oriented triangle
    top_left = (oe[..., 1] > 0) | ((oe[..., 1] == 0) & (oe[..., 0] < 0))
    ok = (w > 0) | ((w == 0) & top_left)
    return ok.all(dim=1) & (area2 != 0)


def _interp(tri_uv, tri_z, tri_x, p):
    """Perspective-correct depth (P,), barycentrics (P, 3) and world points (P, 3).

    ``tri_x`` (P, 3, 3) world corners, or None to skip the points.
    """
    w, s, area2, _ = _edge_terms(tri_uv, p)
    w = w * s.unsqueeze(1)  # undo orientation: plain edge functions
    lin = torch.stack([w[:, 1], w[:, 2], w[:, 0]], dim=1) / area2.unsqueeze(1)  # screen bary
    q = lin / tri_z
    qs = q.sum(dim=1, keepdim=True)
    bary = q / qs
    depth = 1.0 / qs.squeeze(1)
    points = None if tri_x is None else (bary.unsqueeze(-1) * tri_x).sum(dim=1)
    return depth, bary, points


def _select_layers(face, query, p, tri_uv, tri_z, num_queries: int, num_layers: int):
    """Exact hits among candidate pairs, then the first ``num_layers`` per query by depth."""
    with torch.no_grad():
        tri = tri_uv.detach()[face]
        hit = _inside(tri, p)
        face, query, p, tri = face[hit], query[hit], p[hit], tri[hit]
        depth, _, _ = _interp(tri, tri_z.detach()[face], None, p)
        order = torch.argsort(depth, stable=True)
        order = order[torch.argsort(query[order], stable=True)]
        face, query, p = face[order], query[order], p[order]
        counts = torch.bincount(query, minlength=num_queries)
        start = torch.cumsum(counts, 0) - counts
        rank = torch.arange(query.shape[0], device=query.device) - start[query]
        top = rank < num_layers
    return face[top], query[top], p[top], rank[top]


def _fragments(v, f, camera: Camera, near: float, num_layers: int, candidates, n: int):
    """Shared driver. ``candidates(tri_uv) -> (face, query, p)``; returns flat (n, K) fields."""
    dtype = camera.K.dtype
    dev = camera.K.device
    K = num_layers
    ids = torch.full((n * K,), -1, dtype=torch.long, device=dev)
    depth = torch.full((n * K,), float("inf"), dtype=dtype, device=dev)
    bary = torch.zeros(n * K, 3, dtype=dtype, device=dev)
    points = torch.zeros(n * K, 3, dtype=dtype, device=dev)
    if v.shape[1] and f.shape[0] and n:
        tri_uv, tri_z, keep = project_faces(v, f, camera, near)
        face, query, p = candidates(tri_uv)
        face, query, p, rank = _select_layers(face, query, p, tri_uv, tri_z, n, K)
        slot = query * K + rank
        tri_x = v[0].to(dtype)[f[keep[face]]]
        d, b, x = _interp(tri_uv[face], tri_z[face], tri_x, p)
        ids = ids.index_put((slot,), keep[face])
        depth = depth.index_put((slot,), d)
        bary = bary.index_put((slot,), b)
        points = points.index_put((slot,), x)
    return ids, depth, bary, points


def _query_pairs(tri_uv: torch.Tensor, uv: torch.Tensor):
    """Candidate (face, query) pairs: queries binned into unit cells, faces' boxes over cells.

    Falls back to a chunked box test of every (query, face) when the queries are spread over
    far more cells than there are queries.
    """
    N = uv.shape[0]
    origin = torch.floor(uv.amin(dim=0))
    cell_xy = torch.floor(uv - origin).long()  # (N, 2)
    gw, gh = (int(x) + 1 for x in cell_xy.amax(dim=0))
    if gw * gh <= max(1 << 20, 64 * N):
        cell = cell_xy[:, 1] * gw + cell_xy[:, 0]
        order = torch.argsort(cell, stable=True)
        counts = torch.bincount(cell, minlength=gw * gh)
        first = torch.cumsum(counts, 0) - counts
        # boxes grown by half a pixel: covers every cell [j, j+1) the face's box touches
        face, c = bbox_pairs(tri_uv - origin, gh, gw, 0.5)
        n = counts[c]
        face = torch.repeat_interleave(face, n)
        c = torch.repeat_interleave(c, n)
        k = torch.arange(face.shape[0], device=face.device)
        k = k - torch.repeat_interleave(torch.cumsum(n, 0) - n, n)
        query = order[first[c] + k]
    else:
        lo, hi = tri_uv.amin(dim=1), tri_uv.amax(dim=1)
        step = max(1, _QUERY_CHUNK // max(tri_uv.shape[0], 1))
        faces_, queries = [], []
        for s in range(0, N, step):
            q = uv[s : s + step, None, :]
            qi, fi = ((q >= lo) & (q <= hi)).all(dim=-1).nonzero(as_tuple=True)
            faces_.append(fi)
            queries.append(qi + s)
        face, query = torch.cat(faces_), torch.cat(queries)
    return face, query, uv[query]


def _prepare(verts, faces, camera, near, num_layers):
    camera = as_camera(camera)
    near = check_positive(near, "near")
    if isinstance(num_layers, bool) or not isinstance(num_layers, int) or num_layers < 1:
        raise InvalidInputError(f"num_layers must be a positive integer, got {num_layers!r}")
    v, batched = as_verts(verts)
    if batched:
        raise InvalidInputError(f"verts must have shape (V, 3), got {tuple(v.shape)}")
    return v, as_faces(faces, v.shape[1]), camera, near


def rasterize(verts, faces, camera: Camera, num_layers: int = 1, near: float = 1e-3) -> Fragments:
    """Rasterize a mesh at every pixel centre, keeping the ``num_layers`` nearest hits.

    Args:
        verts: (V, 3) world-space vertices.
        faces: (F, 3) integer vertex indices.
        camera: the camera; ``(H, W) = (camera.height, camera.width)``.
        num_layers: K, hits kept per pixel (1: a z-buffer; more: depth peeling).
        near: faces with a vertex at camera z < ``near`` are dropped.

    Returns:
        :class:`Fragments` with fields of shape (H, W, K) / (H, W, K, 3).

    Raises:
        InvalidInputError: bad shapes, NaN vertices, faces out of range, ``num_layers < 1``.
    """
    v, f, camera, near = _prepare(verts, faces, camera, near, num_layers)
    H, W = camera.height, camera.width

    def candidates(tri_uv):
        face, pix = bbox_pairs(tri_uv, H, W, 0.0)
        return face, pix, pixel_uv(pix, W, H, tri_uv.dtype)

    ids, depth, bary, points = _fragments(v, f, camera, near, num_layers, candidates, H * W)
    K = num_layers
    return Fragments(ids.view(H, W, K), depth.view(H, W, K), bary.view(H, W, K, 3),
                     points.view(H, W, K, 3))  # fmt: skip


def peel(verts, faces, camera: Camera, num_layers: int = DEFAULT_LAYERS, near: float = 1e-3):
    """Depth peeling: the first ``num_layers`` (default 4) hits along every pixel's ray.

    Same as :func:`rasterize` with a default of four layers; see it for shapes.
    """
    return rasterize(verts, faces, camera, num_layers=num_layers, near=near)


def peel_pixels(
    verts, faces, camera: Camera, uv, num_layers: int = DEFAULT_LAYERS, near: float = 1e-3
) -> Fragments:
    """Depth peeling along the rays through arbitrary image points.

    Args:
        verts: (V, 3) world-space vertices.
        faces: (F, 3) integer vertex indices.
        camera: the camera.
        uv: (N, 2) image coordinates (pixel centres are at +0.5; any real values allowed).
        num_layers: K, hits kept per ray, nearest first.
        near: faces with a vertex at camera z < ``near`` are dropped.

    Returns:
        :class:`Fragments` with fields of shape (N, K) / (N, K, 3).
    """
    v, f, camera, near = _prepare(verts, faces, camera, near, num_layers)
    uv = torch.as_tensor(uv, dtype=camera.K.dtype, device=camera.K.device)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InvalidInputError(f"uv must have shape (N, 2), got {tuple(uv.shape)}")
    if not torch.isfinite(uv).all():
        raise InvalidInputError("uv contains NaN or infinite values")
    N = uv.shape[0]

    def candidates(tri_uv):
        return _query_pairs(tri_uv.detach(), uv)

    ids, depth, bary, points = _fragments(v, f, camera, near, num_layers, candidates, N)
    K = num_layers
    return Fragments(ids.view(N, K), depth.view(N, K), bary.view(N, K, 3), points.view(N, K, 3))


@torch.no_grad()
def depth_map(verts, faces, camera: Camera, near: float = 1e-3) -> torch.Tensor:
    """Z-buffer only (no gradients, no sort): the nearest hit's camera z per pixel.

    Args:
        verts: (V, 3) world-space vertices.
        faces: (F, 3) integer vertex indices.
        camera: the camera.
        near: faces with a vertex at camera z < ``near`` are dropped.

    Returns:
        (H, W) camera z of the nearest surface, ``inf`` where the ray misses. Equals
        ``rasterize(...).depth[..., 0]`` up to rounding (the numba kernel sums in float64).
    """
    v, f, camera, near = _prepare(verts, faces, camera, near, 1)
    H, W = camera.height, camera.width
    out = torch.full((H * W,), float("inf"), dtype=camera.K.dtype, device=camera.K.device)
    if v.shape[1] and f.shape[0]:
        tri_uv, tri_z, _ = project_faces(v, f, camera, near)
        if get_backend() == "numba" and out.device.type == "cpu":
            tri = tri_uv.reshape(-1, 6).contiguous().numpy()
            if numba_call("zbuffer", tri, tri_z.contiguous().numpy(), H, W, out.numpy()):
                return out.view(H, W)
            out.fill_(float("inf"))  # the torch path below starts from an empty buffer
        face, pix = bbox_pairs(tri_uv, H, W, 0.0)
        p = pixel_uv(pix, W, H, tri_uv.dtype)
        tri = tri_uv[face]
        hit = _inside(tri, p)
        face, pix, p, tri = face[hit], pix[hit], p[hit], tri[hit]
        d, _, _ = _interp(tri, tri_z[face], None, p)
        out.scatter_reduce_(0, pix, d, reduce="amin")
    return out.view(H, W)


@torch.no_grad()
def face_buffer(verts, faces, camera: Camera, near: float = 1e-3):
    """Z-buffer with face ids (no gradients): the nearest face and its camera z per pixel.

    The compiled kernel when numba is in use (the pictures of a result are drawn with it: tens
    of times faster than :func:`rasterize`), else :func:`rasterize` with one layer. Both keep
    the same face at every pixel (of faces at exactly the same depth, the lowest index).

    Args:
        verts: (V, 3) world-space vertices.
        faces: (F, 3) integer vertex indices.
        camera: the camera.
        near: faces with a vertex at camera z < ``near`` are dropped.

    Returns:
        face_ids: (H, W) long, index into ``faces``; -1 where the ray misses.
        depth: (H, W) camera z of the nearest surface, ``inf`` where the ray misses.
    """
    v, f, camera, near = _prepare(verts, faces, camera, near, 1)
    H, W = camera.height, camera.width
    dev, dtype = camera.K.device, camera.K.dtype
    if v.shape[1] and f.shape[0] and get_backend() == "numba" and dev.type == "cpu":
        tri_uv, tri_z, keep = project_faces(v, f, camera, near)
        depth = torch.full((H * W,), float("inf"), dtype=dtype)
        ids = torch.full((H * W,), -1, dtype=torch.long)
        tri = tri_uv.reshape(-1, 6).contiguous().numpy()
        z = tri_z.contiguous().numpy()
        if numba_call("zbuffer", tri, z, H, W, depth.numpy(), ids.numpy()):
            hit = ids >= 0
            ids[hit] = keep[ids[hit]]
            return ids.view(H, W), depth.view(H, W)
    frag = rasterize(v[0], f, camera, num_layers=1, near=near)
    return frag.face_ids[..., 0], frag.depth[..., 0]
