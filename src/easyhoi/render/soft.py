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

Kernels (:func:`set_backend`): compiled numba loops by default on the CPU
(``render/_numba_kernels.py``: no pair is stored, the backward recomputes them), the vectorized
PyTorch kernel below when numba is missing, for inputs on any other device (a GPU: it creates
every tensor on its inputs' device), and as the test oracle, or that kernel through
``torch.compile``.

Conventions: coverage is orientation independent, so back faces are included. A face with any
vertex closer to the camera than ``near`` (camera z, world units) is dropped (no clipping); a mesh
entirely behind the camera, an empty mesh or a mesh outside the image renders a zero mask.
"""

from __future__ import annotations

import math

import torch

from easyhoi.errors import InvalidInputError
from easyhoi.render._common import (
    BACKEND,
    as_camera,
    as_faces,
    as_verts,
    check_positive,
    get_backend,
    numba_call,
    numba_kernels,
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


def _pair_kernel(ax, ay, bx, by, cx, cy, px, py, inv_sigma: float):
    """Per-pair coverage terms; every argument and result is a flat (P,) tensor.

    Written as one chain of elementwise operations (no reductions over a small axis) so that
    ``torch.compile`` fuses it into a single vectorized loop.

    Args:
        ax, ay, bx, by, cx, cy: (P,) triangle corners; edge k runs from corner k to (k + 1) % 3.
        px, py: (P,) pixel centre.
        inv_sigma: 1 / sigma.

    Returns:
        val: (P,) ``log(1 - D) = logsigmoid(-x)``, ``x = delta * d^2 / sigma``.
        coef: (P,) ``-2 d val / d d^2``, so that ``d val / d corner = coef * weight * r``.
        rx, ry: (P,) ``p - q`` with ``q`` the closest boundary point, on edge ``e`` (P,) long at
            parameter ``t`` (P,): ``q = (1 - t) start + t end``.
    """
    best = None
    crosses = []
    for sx, sy, ex, ey, j in ((ax, ay, bx, by, 0), (bx, by, cx, cy, 1), (cx, cy, ax, ay, 2)):
        dx, dy = ex - sx, ey - sy
        wx, wy = px - sx, py - sy
        t = ((wx * dx + wy * dy) / (dx * dx + dy * dy).clamp(min=1e-30)).clamp(0.0, 1.0)
        rx, ry = wx - t * dx, wy - t * dy
        d2 = rx * rx + ry * ry
        crosses.append(dx * wy - dy * wx)
        if best is None:
            best = [d2, rx, ry, t, torch.zeros_like(px, dtype=torch.long)]
            continue
        c = d2 < best[0]
        best = [torch.where(c, d2, best[0]), torch.where(c, rx, best[1]),
                torch.where(c, ry, best[2]), torch.where(c, t, best[3]),
                torch.where(c, j, best[4])]  # fmt: skip
    c0, c1, c2 = crosses
    inside = ((c0 >= 0) & (c1 >= 0) & (c2 >= 0)) | ((c0 <= 0) & (c1 <= 0) & (c2 <= 0))
    d2, rx, ry, t, e = best
    sgn = torch.where(inside, 1.0, -1.0).to(px.dtype)
    x = sgn * d2 * inv_sigma
    val = torch.nn.functional.logsigmoid(-x)
    coef = torch.sigmoid(x) * sgn * (2.0 * inv_sigma)
    return val, coef, rx, ry, t, e


def _face_table(tri_uv: torch.Tensor, height: int, width: int, margin: float, base: torch.Tensor):
    """Per-face pixel ranges of the grown bounding boxes (no gradients).

    Returns:
        face: (P,) long, the face of every pair (faces repeated by their pixel counts).
        table: (5, N) long rows ``col0, row0, nx, first pair index, pixel offset``.
    """
    t = tri_uv.detach()
    lim = torch.tensor([width, height], dtype=t.dtype, device=t.device)
    j0 = torch.ceil(t.amin(dim=1) - margin - 0.5).clamp(min=0).minimum(lim).long()
    j1 = torch.floor(t.amax(dim=1) + margin - 0.5).clamp(max=lim - 1).maximum(-torch.ones_like(lim))
    ext = (j1.long() - j0 + 1).clamp(min=0)
    counts = ext[:, 0] * ext[:, 1]
    total = int(counts.sum()) if counts.numel() else 0
    face = torch.repeat_interleave(
        torch.arange(t.shape[0], device=t.device), counts, output_size=total
    )
    first = torch.cumsum(counts, 0) - counts
    table = torch.stack([j0[:, 0], j0[:, 1], ext[:, 0].clamp(min=1), first, base])
    return face, table


def _fused_forward(tri6, table, face, width: int, inv_sigma: float, num_pix: int):
    """Pair decoding, coverage terms and per-pixel scatter in one function (compilable).

    Args:
        tri6: (6, N) corner coordinates ``ax ay bx by cx cy`` per face.
        table, face: from :func:`_face_table`.
    Returns:
        out: (num_pix,) ``sum log(1 - D)``; pix (P,) and the saved terms of :func:`_pair_kernel`.
    """
    tab = table[:, face]
    k = torch.arange(face.shape[0], device=face.device) - tab[3]
    r = torch.div(k, tab[2], rounding_mode="floor")
    col = tab[0] + (k - r * tab[2])
    row = tab[1] + r
    pix = tab[4] + row * width + col
    g = tri6[:, face]
    px = col.to(tri6.dtype) + 0.5
    py = row.to(tri6.dtype) + 0.5
    val, coef, rx, ry, t, e = _pair_kernel(*g.unbind(0), px, py, inv_sigma)
    out = torch.zeros(num_pix, dtype=tri6.dtype, device=tri6.device).index_add_(0, pix, val)
    return out, pix, coef, rx, ry, t, e


def _fused_backward(grad_out, face, pix, coef, rx, ry, t, e, num_faces: int):
    """Analytic gradient w.r.t. the (N, 3, 2) corners, flattened to (N * 6,) (compilable).

    ``d val / d start = coef (1 - t) r`` and ``d val / d end = coef t r`` for the closest edge
    ``e`` (envelope theorem: the closest point is optimal on the edge).
    """
    s = grad_out[pix] * coef
    ws, we = s * (1.0 - t), s * t
    i0 = (face * 3 + e) * 2
    i1 = (face * 3 + torch.remainder(e + 1, 3)) * 2
    grad = torch.zeros(num_faces * 6, dtype=s.dtype, device=s.device)
    grad.index_add_(0, i0, ws * rx).index_add_(0, i0 + 1, ws * ry)
    grad.index_add_(0, i1, we * rx).index_add_(0, i1 + 1, we * ry)
    return grad


_COMPILED: dict[str, object] = {}
BACKENDS = ("auto", "numba", "torch", "compile")


def set_backend(name: str) -> None:
    """Choose the soft-silhouette kernel: ``auto`` (numba if importable, else torch), ``numba``,
    ``torch`` (eager) or ``compile`` (``torch.compile`` of the torch kernel, see
    :func:`set_compile`). Values and gradients agree to float rounding across backends.

    Raises:
        InvalidInputError: unknown name, or ``numba`` requested but numba is not importable.
    """
    if name not in BACKENDS:
        raise InvalidInputError(f"unknown soft renderer backend {name!r}; use one of {BACKENDS}")
    if name == "numba" and numba_kernels() is None:
        raise InvalidInputError("the numba backend needs the numba package (pip install numba)")
    BACKEND["name"] = name
    if name == "compile":
        _COMPILED.setdefault("forward", torch.compile(_fused_forward, dynamic=True))
        _COMPILED.setdefault("backward", torch.compile(_fused_backward, dynamic=True))
    else:
        _drop_compiled()


def _drop_compiled() -> None:
    _COMPILED.pop("forward", None)
    _COMPILED.pop("backward", None)


def set_compile(enabled: bool) -> None:
    """Run the torch per-pair forward and backward through ``torch.compile`` (inductor).

    ``set_compile(True)`` is ``set_backend("compile")``; ``set_compile(False)`` returns to
    ``auto``. The first call in a process pays a compilation (10-60 s cold, a few seconds once
    inductor's on-disk cache is warm). Pair counts change at every call, so the functions are
    compiled with ``dynamic=True`` and do not recompile for new counts. If compilation fails
    (no C++ compiler, ...) a warning is issued and eager code is used.
    """
    set_backend("compile" if enabled else "auto")


def _call(name: str, eager, *args):
    fn = _COMPILED.get(name)
    if fn is not None:
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - any backend failure falls back to eager
            import warnings

            warnings.warn(f"torch.compile failed ({exc}); using eager kernels", stacklevel=3)
            _drop_compiled()
    return eager(*args)


class _SoftLogSum(torch.autograd.Function):
    """Per-pixel ``sum_T log(1 - D_T)`` over culled pairs, with an analytic backward."""

    @staticmethod
    def forward(ctx, tri_uv, face, table, width: int, sigma: float, num_pix: int):
        tri6 = tri_uv.detach().reshape(-1, 6).t().contiguous()
        out, *saved = _call("forward", _fused_forward, tri6, table, face, width, 1.0 / sigma,
                            num_pix)  # fmt: skip
        ctx.save_for_backward(face, *saved)
        ctx.num_faces = tri_uv.shape[0]
        return out

    @staticmethod
    def backward(ctx, grad_out):
        saved = ctx.saved_tensors
        grad = _call("backward", _fused_backward, grad_out.contiguous(), *saved, ctx.num_faces)
        return grad.view(-1, 3, 2), None, None, None, None, None


class _SoftLogSumNumba(torch.autograd.Function):
    """Same as :class:`_SoftLogSum` with the numba kernels (pairs recomputed in backward)."""

    @staticmethod
    def forward(ctx, tri_uv, base, height: int, width: int, sigma: float, margin: float,
                num_pix: int):  # fmt: skip
        tri = tri_uv.detach().reshape(-1, 6).contiguous()
        base = base.contiguous()
        out = torch.empty(num_pix, dtype=tri.dtype, device=tri.device)
        args = (tri.numpy(), base.numpy(), height, width, 1.0 / sigma, margin, num_pix)
        if not numba_call("soft_logsum_forward", *args, out.numpy()):
            raise _KernelUnavailable
        ctx.save_for_backward(tri, base)
        ctx.args = (height, width, 1.0 / sigma, margin)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        tri, base = ctx.saved_tensors
        grad = torch.empty_like(tri)
        go = grad_out.detach().to(tri.dtype).contiguous()
        args = (tri.numpy(), base.numpy(), *ctx.args, go.numpy(), grad.numpy())
        if not numba_call("soft_logsum_backward", *args):
            raise RuntimeError(
                "the numba backward kernel failed after its forward ran; the next call uses "
                "the torch kernels"
            )
        return grad.view(-1, 3, 2), None, None, None, None, None, None


class _KernelUnavailable(Exception):
    """The numba forward could not run (numba_call warned and switched to torch)."""


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
        base = torch.div(keep, F, rounding_mode="floor") * (H * W)  # batch offsets
        margin = cull_margin(sigma, cull_eps)
        logs = None
        if get_backend() == "numba" and tri_uv.device.type == "cpu":
            try:
                logs = _SoftLogSumNumba.apply(tri_uv, base, H, W, sigma, margin, B * H * W)
            except _KernelUnavailable:
                logs = None
        if logs is None:
            face, table = _face_table(tri_uv, H, W, margin, base)
            logs = _SoftLogSum.apply(tri_uv, face, table, W, sigma, B * H * W)
        logs = logs.view(B, H, W)
    sil = -torch.expm1(logs)
    if not batched:
        return sil[0], logs[0]
    return sil, logs
