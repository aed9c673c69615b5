"""Shared plumbing of the rasterizers: input validation, projection and culled pair generation.

A *pair* is one (pixel, face) combination that a rasterizer evaluates. Pairs are generated from
each face's screen-space bounding box (optionally grown by a margin) clipped to the image, fully
vectorized: per-face pixel ranges -> ``repeat_interleave`` -> flat lists. The dense
pixels x faces product is never formed.
"""

from __future__ import annotations

import threading

import numpy as np
import torch

from easyhoi import compiled
from easyhoi.checks import check_faces, check_finite
from easyhoi.errors import InvalidInputError
from easyhoi.structures import Camera

#: Kernel backend of the soft silhouette and the z-buffer: "auto" (numba when importable, else
#: torch), "numba", "torch" (eager) or "compile" (torch.compile); set by
#: :func:`easyhoi.render.soft.set_backend`.
BACKEND = {"name": "auto"}
_NUMBA: dict[str, object] = {}


class _BuiltKernels:
    """The renderer's kernels from the module built ahead of time (:mod:`easyhoi.aot`), by the
    names of :mod:`easyhoi.render._numba_kernels`; a call of other argument types, or a name the
    built module lacks, goes to numba's module."""

    def __init__(self):
        self._kernels = {}

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        if name not in self._kernels:
            k = compiled.kernel("easyhoi.render._numba_kernels", name)
            if k is None:
                from easyhoi.render import _numba_kernels

                k = getattr(_numba_kernels, name)
            self._kernels[name] = k
        return self._kernels[name]


def numba_kernels():
    """The compiled kernels (built ahead of time when :mod:`easyhoi.aot` has them for this
    machine, else numba's module), or None when numba is missing or broken (torch is used)."""
    if "mod" not in _NUMBA:
        from easyhoi import aot

        mod = _BuiltKernels() if aot.loaded() is not None else None
        if mod is None:
            try:
                from easyhoi.render import _numba_kernels as mod
            except Exception:  # noqa: BLE001 - any import failure falls back to torch
                mod = None
        _NUMBA["mod"] = mod
    return _NUMBA["mod"]


def numba_call(name: str, *args) -> bool:
    """Run the numba kernel ``name``; False (and torch from now on) when numba itself fails.

    A kernel that cannot be compiled or run on this machine must not stop a reconstruction:
    :func:`easyhoi.compiled.run` warns once and marks it failed, and here the compiled kernels
    are disabled for the process (``auto`` resolves to ``torch``; they share one compiled
    module) and the caller uses its torch path. Errors that are not numba's propagate.
    """
    ok, _ = compiled.run(name, getattr(numba_kernels(), name), *args,
                         fallback="using the slower torch kernels")  # fmt: skip
    if not ok:
        _NUMBA["mod"] = None
        if BACKEND["name"] == "numba":
            BACKEND["name"] = "auto"
    return ok


def get_backend() -> str:
    """The soft-silhouette backend in use now (``auto`` resolved to ``numba`` or ``torch``)."""
    name = BACKEND["name"]
    if name == "auto":
        return "numba" if numba_kernels() is not None else "torch"
    return name


def as_verts(verts, name: str = "verts") -> tuple[torch.Tensor, bool]:
    """Validate vertices; returns ``(verts (B, V, 3), batched)``; floats kept, others -> float32."""
    if not isinstance(verts, torch.Tensor):
        try:
            verts = torch.as_tensor(np.asarray(verts, dtype=np.float32))
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"{name} is not a numeric array: {exc}") from None
    if not verts.is_floating_point():
        verts = verts.float()
    if verts.ndim not in (2, 3) or verts.shape[-1] != 3:
        raise InvalidInputError(
            f"{name} must have shape (V, 3) or (B, V, 3), got {tuple(verts.shape)}"
        )
    check_finite(verts.detach(), name)
    batched = verts.ndim == 3
    return (verts if batched else verts.unsqueeze(0)), batched


def as_faces(faces, num_vertices: int, name: str = "faces") -> torch.Tensor:
    """Validate faces: (F, 3) integers in ``[0, V)``; returns a long tensor."""
    if not isinstance(faces, torch.Tensor):
        faces = torch.as_tensor(np.asarray(faces))
    bad_dtype = faces.is_floating_point() or faces.dtype == torch.bool or faces.is_complex()
    if bad_dtype and faces.numel():  # an empty (0, 3) array of any dtype is an empty mesh
        raise InvalidInputError(f"{name} must hold integers, got dtype {faces.dtype}")
    faces = faces.long()
    check_faces(faces, num_vertices, name)
    return faces


def as_camera(camera) -> Camera:
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be an easyhoi Camera, got {type(camera).__name__}")
    return camera


def check_positive(value: float, name: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise InvalidInputError(f"{name} must be a positive finite number, got {value}")
    return value


def project_faces(
    verts: torch.Tensor, faces: torch.Tensor, camera: Camera, near: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Project a batch of meshes and drop faces with a vertex closer than ``near``.

    Without gradients, the projection of the previous call of this thread is reused when it
    was of the same tensors (same storage, layout and version counter: unchanged since) with
    the same camera size and ``near``: the optimizer draws each hand twice per iteration, a
    soft silhouette and then a z-buffer of the same vertices through the same camera. The
    reused values are those a new projection gives (the same operations on the same numbers).

    Args:
        verts: (B, V, 3) world-space vertices.
        faces: (F, 3) long.
        camera: the camera (its tensors may require gradients).
        near: near-plane distance (camera z) in world units.

    Returns:
        tri_uv: (N, 3, 2) pixel coordinates of the kept faces' corners (differentiable).
        tri_z: (N, 3) camera z of the corners (differentiable).
        keep: (N,) long, flat index ``b * F + f`` of each kept face.
    """
    key = _projection_key(verts, faces, camera, near)
    last = getattr(_LAST_PROJECTION, "entry", None)
    if key is not None and last is not None and not torch.is_grad_enabled():
        if last[0][1:] == key[1:]:
            tri_uv, tri_z, keep = last[1]
            return tri_uv.detach(), tri_z.detach(), keep
    out = _project_faces(verts, faces, camera, near)
    _LAST_PROJECTION.entry = None if key is None else (key, out)
    return out


#: The last projection of each thread, with the tensors it was computed from (held, so that
#: their storage cannot be freed and reused by other tensors while the entry lives).
_LAST_PROJECTION = threading.local()


def _projection_key(verts, faces, camera: Camera, near: float) -> tuple | None:
    """What identifies a projection: the tensors themselves (held), their storage, layout
    and version counters, the camera size and ``near``; None for tensors without a plain
    storage (never reused)."""
    tensors = (verts, faces, camera.K, camera.R, camera.t)
    try:
        layouts = tuple(
            (x.untyped_storage().data_ptr(), x.storage_offset(), tuple(x.shape), x.stride(),
             x.dtype, x.device, x._version)
            for x in tensors
        )  # fmt: skip
    except (RuntimeError, NotImplementedError):
        return None
    return (tensors, layouts, camera.width, camera.height, float(near))


def _project_faces(
    verts: torch.Tensor, faces: torch.Tensor, camera: Camera, near: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    B = verts.shape[0]
    F = faces.shape[0]
    uv, z = camera.project(verts.to(camera.K.dtype))  # (B, V, 2), (B, V)
    corners = faces.reshape(-1)
    # index_select gathers (and its backward scatters) the same values as ``uv[:, faces]`` at
    # half the cost of advanced indexing; along the leading dimension (one mesh, the usual
    # case) its backward adds whole rows, six times faster than along dimension 1 (the same
    # sums in the same order)
    if B == 1:
        tri_uv = uv[0].index_select(0, corners).reshape(F, 3, 2)
        tri_z = z[0].index_select(0, corners).reshape(F, 3)
    else:
        tri_uv = uv.index_select(1, corners).reshape(B * F, 3, 2)
        tri_z = z.index_select(1, corners).reshape(B * F, 3)
    with torch.no_grad():
        # a face is kept when all its corners are: test the V vertices, not the 3 F corners
        ok_v = (z >= near) & torch.isfinite(uv).all(dim=2)
        if bool(ok_v.all()):  # every vertex usable (the usual case): every face kept, in order
            return tri_uv, tri_z, torch.arange(B * F, device=uv.device)
        ok = ok_v.index_select(1, corners).reshape(B * F, 3).all(dim=1)
        keep = ok.nonzero().squeeze(1)
    if keep.shape[0] == B * F:  # nothing dropped: no second gather
        return tri_uv, tri_z, keep
    return tri_uv[keep], tri_z[keep], keep


def bbox_pairs(
    tri_uv: torch.Tensor, height: int, width: int, margin: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """All (face, pixel) pairs whose pixel centre lies in the face's bounding box +- ``margin``.

    Args:
        tri_uv: (N, 3, 2) corner pixel coordinates (only read, never differentiated).
        height, width: image size; pixel (i, j) has its centre at (u, v) = (j + 0.5, i + 0.5).
        margin: growth of every bounding box, in pixels.

    Returns:
        face: (P,) long index into ``tri_uv``.
        pix: (P,) long flat pixel index ``i * width + j``.
    """
    t = tri_uv.detach()
    dev = t.device
    if t.shape[0] == 0:
        empty = torch.zeros(0, dtype=torch.long, device=dev)
        return empty, empty
    lo = t.amin(dim=1) - margin - 0.5  # pixel j is covered iff lo <= j <= hi
    hi = t.amax(dim=1) + margin - 0.5
    lim = torch.tensor([width, height], dtype=t.dtype, device=dev)
    j0 = torch.ceil(lo).clamp(min=0).minimum(lim).long()  # (N, 2): column, row
    j1 = torch.floor(hi).clamp(max=lim - 1).maximum(torch.full_like(lim, -1)).long()
    ext = (j1 - j0 + 1).clamp(min=0)  # (N, 2): nx, ny
    counts = ext[:, 0] * ext[:, 1]
    total = int(counts.sum())
    if total == 0:
        empty = torch.zeros(0, dtype=torch.long, device=dev)
        return empty, empty
    face = torch.repeat_interleave(torch.arange(t.shape[0], device=dev), counts, output_size=total)
    start = torch.cumsum(counts, 0) - counts
    k = torch.arange(total, device=dev) - start[face]
    nx = ext[face, 0]
    r = torch.div(k, nx, rounding_mode="floor")
    col = j0[face, 0] + (k - r * nx)
    row = j0[face, 1] + r
    return face, row * width + col


def pixel_uv(pix: torch.Tensor, width: int, height: int, dtype) -> torch.Tensor:
    """(P,) flat pixel indices (possibly offset by ``b * H * W``) -> (P, 2) centre coordinates."""
    local = pix % (width * height)
    v = torch.div(local, width, rounding_mode="floor")
    u = local - v * width
    return torch.stack([u.to(dtype) + 0.5, v.to(dtype) + 0.5], dim=1)
