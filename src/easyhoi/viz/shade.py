"""Shaded rendering of triangle meshes with the project's compiled z-buffer (no OpenGL).

Every mesh of a scene is rasterized together (one z-buffer of face ids,
:func:`easyhoi.render.raster.face_buffer`, so meshes occlude each other), each
pixel is shaded with Lambert lighting (two lights fixed to the camera plus an ambient term) from
crease-aware interpolated normals, and the result is alpha-blended over a background image or a
plain colour. Pixels no mesh covers keep the background exactly.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from easyhoi import compiled
from easyhoi.errors import InvalidInputError
from easyhoi.render.raster import face_buffer
from easyhoi.structures import Camera

__all__ = [
    "HAND_COLOR",
    "OBJECT_COLOR",
    "Render",
    "SceneMesh",
    "corner_normals",
    "render_shaded",
]

#: Default colours (RGB 0-255): a skin tone for hands, a clear blue for objects.
HAND_COLOR: tuple[int, int, int] = (250, 165, 115)
OBJECT_COLOR: tuple[int, int, int] = (70, 130, 230)

#: Lights in the camera frame (x right, y down, z forward), pointing from the surface to the
#: light: a headlight and a key light from the upper left; weights sum with the ambient to 1.
_LIGHTS = (
    (np.array([0.0, 0.0, -1.0]), 0.40),
    (np.array([-0.45, -0.6, -0.65]), 0.35),
)
_AMBIENT = 0.30


@dataclass(frozen=True)
class SceneMesh:
    """One mesh to draw.

    Attributes:
        vertices ((V, 3) float): World-space vertices (the camera's world frame and units).
        faces ((F, 3) int): Triangles.
        color ((3,) int): RGB colour in 0..255.
        name (str): Label used in legends.
    """

    vertices: np.ndarray
    faces: np.ndarray
    color: tuple[int, int, int]
    name: str = ""

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3:
            raise InvalidInputError(f"mesh {self.name!r} vertices must be (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise InvalidInputError(f"mesh {self.name!r} faces must be (F, 3) int, got {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise InvalidInputError(f"mesh {self.name!r} faces index missing vertices")
        c = tuple(int(x) for x in self.color)
        if len(c) != 3 or min(c) < 0 or max(c) > 255:
            raise InvalidInputError(f"mesh colour must be 3 values in 0..255, got {self.color}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f.astype(np.int64))
        object.__setattr__(self, "color", c)

    @cached_property
    def corner_normals(self) -> np.ndarray:
        """(F, 3, 3) :func:`corner_normals` of the mesh (read-only).

        Computed once per mesh content in a process: the pictures of a result each build their
        own meshes of the same hand and object (overlay, views, stages, masks), and the normals
        cost more than the rest of a small picture's shading.
        """
        key = (
            hashlib.blake2b(
                self.vertices.tobytes() + self.faces.tobytes(), digest_size=16
            ).digest(),
            self.vertices.shape,
            self.faces.shape,
        )
        with _NORMALS_LOCK:
            if key in _NORMALS:
                _NORMALS.move_to_end(key)
                return _NORMALS[key]
        n = corner_normals(self.vertices, self.faces)
        n.flags.writeable = False
        with _NORMALS_LOCK:
            _NORMALS[key] = n
            while len(_NORMALS) > _NORMALS_KEPT:
                _NORMALS.popitem(last=False)
        return n


#: Corner normals of the meshes drawn last, by content (vertices and faces bytes, shapes).
_NORMALS: OrderedDict[tuple, np.ndarray] = OrderedDict()
_NORMALS_KEPT = 16
_NORMALS_LOCK = threading.Lock()


@dataclass(frozen=True)
class Render:
    """A shaded picture and what covers each pixel.

    Attributes:
        image ((H, W, 3) uint8): The composited picture.
        labels ((H, W) int64): Index of the mesh seen at each pixel (into the ``meshes`` given), -1
            where none.
        depth ((H, W) float64): Camera z of the nearest surface, ``inf`` where none.
    """

    image: np.ndarray
    labels: np.ndarray
    depth: np.ndarray

    def mask(self, index: int) -> np.ndarray:
        """(H, W) bool, pixels where mesh ``index`` is the nearest surface."""
        return self.labels == index


def corner_normals(vertices: np.ndarray, faces: np.ndarray, crease_deg: float = 40.0):
    """Per-corner normals, smooth across soft edges and sharp across creases.

    Args:
        vertices: (V, 3) float
        faces: (F, 3) int
        crease_deg (float): A neighbouring face contributes to a corner's normal only if its normal
            is within this angle of the corner's own face normal (so a box keeps flat sides).

    Returns:
        (F, 3, 3) float64: Unit normal at each corner of each face (area-weighted average of the
            contributing neighbours; the face normal where nothing else contributes).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # |cross| = 2 * area
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    unit = cross / np.maximum(length, 1e-30)
    cos_crease = float(np.cos(np.radians(crease_deg)))
    acc = _compiled_sums(f, len(v), cross, unit, cos_crease)
    if acc is None:
        acc = _pair_sums(f, len(v), cross, unit, cos_crease)
    n = np.linalg.norm(acc, axis=1, keepdims=True)
    out = np.where(n > 1e-30, acc / np.maximum(n, 1e-30), np.repeat(unit, 3, axis=0))
    return out.reshape(len(f), 3, 3)


def _pair_sums(f, n_vertices, cross, unit, cos_crease) -> np.ndarray:
    """(3F, 3): per corner, the summed ``cross`` of the faces around its vertex within the
    crease angle, from (corner, neighbour face) pairs in NumPy (the path without numba)."""
    corner_vertex = f.reshape(-1)
    corner_face = np.repeat(np.arange(len(f)), 3)
    order = np.argsort(corner_vertex, kind="stable")
    sorted_v = corner_vertex[order]
    starts = np.searchsorted(sorted_v, np.arange(n_vertices))
    counts = np.bincount(corner_vertex, minlength=n_vertices)
    # pairs (corner c, neighbour face n) for all neighbours of c's vertex
    deg = counts[corner_vertex]
    pair_corner = np.repeat(np.arange(len(corner_vertex)), deg)
    offset = np.arange(len(pair_corner)) - np.repeat(np.cumsum(deg) - deg, deg)
    pair_face = corner_face[order[starts[corner_vertex[pair_corner]] + offset]]
    own = unit[corner_face[pair_corner]]
    keep = (own * unit[pair_face]).sum(1) >= cos_crease
    corner, w = pair_corner[keep], cross[pair_face[keep]]
    return np.stack([np.bincount(corner, w[:, j], len(corner_vertex)) for j in range(3)], axis=1)


def _compiled_sums(f, n_vertices, cross, unit, cos_crease) -> np.ndarray | None:
    """:func:`_pair_sums` by the compiled kernel (the same sums); None without numba, or once
    the kernel failed to compile or run in this process (:mod:`easyhoi.compiled`: a warning
    names the failure once, and a failing compile is not retried at every picture)."""
    from easyhoi.render import get_backend

    if get_backend() != "numba" or not len(f):
        return None
    fn = compiled.kernel("easyhoi.viz._normals_kernel", "corner_sums")
    if fn is None:
        return None
    ok, sums = compiled.run("corner_sums", fn, f, n_vertices, cross, unit, cos_crease,
                            fallback="the pictures' normals use the slower NumPy path")  # fmt: skip
    return sums if ok else None


def _as_background(background, camera: Camera) -> np.ndarray:
    H, W = camera.height, camera.width
    if background is None:
        return np.full((H, W, 3), 255, dtype=np.uint8)
    bg = np.asarray(background)
    if bg.ndim == 1 and bg.shape == (3,):
        return np.broadcast_to(bg.astype(np.uint8), (H, W, 3)).copy()
    if bg.shape != (H, W, 3) or bg.dtype != np.uint8:
        raise InvalidInputError(
            f"background must be an ({H}, {W}, 3) uint8 image matching the camera, "
            f"got {bg.shape} {bg.dtype}"
        )
    return bg.copy()


def render_shaded(
    meshes: Sequence[SceneMesh],
    camera: Camera,
    background=None,
    alpha: float = 1.0,
    outline: bool = True,
) -> Render:
    """Draw meshes, shaded, over a background.

    Args:
        meshes (sequence of SceneMesh): In the camera's world frame; they occlude each other.
        camera (Camera): Output size ``(camera.height, camera.width)``.
        background ((H, W, 3) uint8, (3,) colour, or None): What lies behind the meshes; None is
            white.
        alpha (float): Opacity of the meshes in [0, 1]; 1 hides the background where a mesh is.
        outline (bool): Darken covered pixels on the border between two meshes or a mesh and the
            background, so that hand and object stay apart in the picture.

    Returns:
        Render: Picture, per-pixel mesh labels and depth. Pixels no mesh covers equal the
            background.
    """
    if not 0.0 <= alpha <= 1.0:
        raise InvalidInputError(f"alpha must be in [0, 1], got {alpha}")
    bg = _as_background(background, camera)
    H, W = camera.height, camera.width
    labels = np.full((H, W), -1, dtype=np.int64)
    depth = np.full((H, W), np.inf)
    meshes = [m for m in meshes if len(m.faces)]
    if not meshes:
        return Render(bg, labels, depth)
    cam = camera.detach().to(dtype=torch.float64)
    verts = np.concatenate([m.vertices for m in meshes])
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets[:-1], strict=True)])
    face_start = np.cumsum([0] + [len(m.faces) for m in meshes])
    colors = np.array([m.color for m in meshes], dtype=np.float64)

    fid, z = face_buffer(torch.from_numpy(verts), torch.from_numpy(faces), cam)
    fid = fid.numpy().reshape(-1)
    pix = np.flatnonzero(fid >= 0)  # covered pixels, flat index row * W + col
    if not len(pix):
        return Render(bg, labels, depth)
    depth.reshape(-1)[pix] = z.numpy().reshape(-1)[pix]
    f = fid[pix]
    lab = np.searchsorted(face_start, f, side="right") - 1
    labels.reshape(-1)[pix] = lab
    vt = torch.from_numpy(verts)
    uv = cam.project(vt)[0].numpy()
    p_cam = cam.world_to_camera(vt).numpy()
    bary = _perspective_bary(uv, p_cam[:, 2], faces[f], pix, W)
    normals = np.concatenate([m.corner_normals for m in meshes])
    normals = normals @ cam.R.numpy().T  # camera frame
    n = np.einsum("pk,pkj->pj", bary, normals[f])
    n /= np.maximum(np.sqrt(np.einsum("pj,pj->p", n, n)), 1e-30)[:, None]
    p = np.einsum("pk,pkj->pj", bary, p_cam[faces[f]])
    # two-sided: a normal facing away from the eye (n . p > 0, the eye at the origin) is flipped
    n[np.einsum("pj,pj->p", n, p) > 0] *= -1.0
    light = np.full(len(n), _AMBIENT)
    for direction, weight in _LIGHTS:
        d = direction / np.linalg.norm(direction)
        light += weight * np.maximum(n @ d, 0.0)
    shade = colors[lab] * np.minimum(light, 1.0)[:, None]
    if outline:
        edge = _border(labels).reshape(-1)[pix]
        shade[edge] *= 0.45
    _blend(bg.reshape(-1, 3), pix, shade, alpha)
    return Render(bg, labels, depth)


def _blend(image: np.ndarray, pix: np.ndarray, shade: np.ndarray, alpha: float) -> None:
    """Alpha-blend ``shade`` over the rows ``pix`` of ``image`` ((N, 3) uint8), in place.

    Only the covered pixels go through float64 (a whole-picture float copy cost more than the
    shading of a small mesh); the others keep their bytes. Each covered value is
    ``rint((1 - alpha) * background + alpha * shade)`` clipped to 0..255.
    """
    under = image[pix].astype(np.float64)
    image[pix] = np.clip(np.rint((1.0 - alpha) * under + alpha * shade), 0, 255).astype(np.uint8)


def _perspective_bary(
    uv: np.ndarray, z: np.ndarray, tri: np.ndarray, pix: np.ndarray, width: int
) -> np.ndarray:
    """Perspective-correct barycentrics of pixel centres in the faces seen there.

    The rasterizer's arithmetic (:mod:`easyhoi.render.raster`): edge functions of the
    projected corners at the pixel centre give the screen barycentrics ``l``; the
    perspective-correct ones are ``(l_i / z_i) / sum_j (l_j / z_j)``.

    Args:
        uv: (V, 2) pixel coordinates of the vertices.
        z: (V,) camera z of the vertices.
        tri: (P, 3) vertex indices of the face seen at each pixel.
        pix: (P,) flat pixel index ``row * width + col``.
        width: image width.

    Returns:
        (P, 3) float64, rows summing to 1.
    """
    c = uv[tri]  # (P, 3, 2)
    px = (pix % width + 0.5)[:, None]
    py = (pix // width + 0.5)[:, None]
    e = np.roll(c, -1, axis=1) - c  # edge k: corner k -> k + 1
    w = e[..., 0] * (py - c[..., 1]) - e[..., 1] * (px - c[..., 0])
    area2 = e[:, 0, 0] * (-e[:, 2, 1]) - e[:, 0, 1] * (-e[:, 2, 0])
    q = np.stack([w[:, 1], w[:, 2], w[:, 0]], axis=1) / area2[:, None] / z[tri]
    return q / q.sum(axis=1, keepdims=True)


def _border(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: covered pixels with a 4-neighbour of another label (image edges excluded)."""
    pad = np.pad(labels, 1, mode="edge")
    c = pad[1:-1, 1:-1]
    diff = np.zeros(labels.shape, dtype=bool)
    for sl in ((slice(None, -2), slice(1, -1)), (slice(2, None), slice(1, -1)),
               (slice(1, -1), slice(None, -2)), (slice(1, -1), slice(2, None))):  # fmt: skip
        diff |= pad[sl] != c
    return diff & (labels >= 0)
