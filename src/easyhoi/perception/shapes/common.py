"""Shared pieces of the shape hypotheses: the working frame, silhouettes and their fit.

Every hypothesis is fitted in a *working frame*: the amodal mask cropped to its bounding box
(with a margin) and resampled so that its longer side has :data:`WORK_SIDE` pixels. Meshes are
built in working pixels ``(u, v, z)`` (x right, y down, z away from the camera, orthographic)
and mapped back to source pixels once the winner is known.

Silhouette fit (:func:`fit_iou`) is an IoU in which each pixel carries a weight:

* visible object pixels (seen, certain): 1;
* amodal completion pixels (behind the hand, inferred): :data:`COMPLETION_WEIGHT`;
* hand pixels outside the amodal mask: 0 — the object may or may not continue behind the
  hand, so a hypothesis that extends there is neither rewarded nor penalised;
* pixels beyond the photo's edge: 0 — an object cut by the edge of the photo continues out
  of it by an unknown amount (close-ups of a hand and what it holds often are), so the edge
  is not its outline;
* everything else (background, seen): 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

#: Longer side of the working frame, pixels.
WORK_SIDE = 96
#: Supersampling of :func:`rasterize`.
SUPERSAMPLE = 3
#: Weight of amodal-only (completed, not seen) pixels in :func:`fit_iou`.
COMPLETION_WEIGHT = 0.5


@dataclass
class WorkFrame:
    """The amodal mask and its evidence in working pixels.

    Attributes:
        mask: (h, w) bool amodal mask.
        visible: (h, w) bool visible object pixels (``mask`` itself when unknown).
        weight: (h, w) float per-pixel weight of :func:`fit_iou`.
        gray: (h, w) float grey image in [0, 1] or None (edge evidence).
        scale: source pixels per working pixel.
        offset: (2,) source pixel coordinates (u, v) of working pixel coordinate (0, 0).
        in_photo: (h, w) bool working pixels inside the photo (None: all of them).
    """

    mask: np.ndarray
    visible: np.ndarray
    weight: np.ndarray
    gray: np.ndarray | None
    scale: float
    offset: np.ndarray
    in_photo: np.ndarray | None = None

    def to_source(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) working pixel coordinates -> source pixel coordinates."""
        return np.asarray(uv) * self.scale + self.offset

    def to_work(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) source pixel coordinates -> working pixel coordinates."""
        return (np.asarray(uv, dtype=np.float64) - self.offset) / self.scale


def _resample(m: np.ndarray, box, size) -> np.ndarray:
    x0, y0, x1, y1 = box
    H, W = m.shape[:2]
    pad = np.zeros((y1 - y0, x1 - x0) + m.shape[2:], m.dtype)
    sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    pad[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = m[sy0:sy1, sx0:sx1]
    return cv2.resize(pad, size, interpolation=cv2.INTER_AREA)


def work_frame(
    mask: np.ndarray,
    visible: np.ndarray | None = None,
    occluder: np.ndarray | None = None,
    image: np.ndarray | None = None,
    side: int = WORK_SIDE,
) -> WorkFrame:
    """The working frame of an (H, W) bool amodal ``mask`` (module docs).

    ``visible`` and ``occluder`` (hand) masks and the (H, W, 3) uint8 ``image`` are optional.
    """
    rows, cols = np.nonzero(mask)
    u0, u1, v0, v1 = cols.min(), cols.max() + 1, rows.min(), rows.max() + 1
    ext = max(u1 - u0, v1 - v0)
    margin = int(np.ceil(0.12 * ext)) + 2
    size_src = ext + 2 * margin
    cu, cv = (u0 + u1) // 2, (v0 + v1) // 2
    box = (cu - size_src // 2, cv - size_src // 2, cu - size_src // 2 + size_src,
           cv - size_src // 2 + size_src)  # fmt: skip
    scale = size_src / side

    def rs(m):
        return _resample(m.astype(np.float32), box, (side, side))

    m = rs(mask) >= 0.5
    vis = (rs(visible & mask) >= 0.5) & m if visible is not None else m.copy()
    weight = np.ones((side, side))
    weight[m & ~vis] = COMPLETION_WEIGHT
    if occluder is not None:
        weight[(rs(occluder) >= 0.5) & ~m] = 0.0
    in_photo = rs(np.ones(mask.shape, bool)) >= 0.5
    weight[~in_photo] = 0.0  # beyond the photo's edge
    gray = None
    if image is not None:
        g = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float32)
        gray = _resample(g / 255.0, box, (side, side)).astype(np.float64)
    offset = np.array([box[0], box[1]], float)
    return WorkFrame(m, vis, weight, gray, float(scale), offset, in_photo)


def work_resample(values: np.ndarray, wf: WorkFrame, source_mask: np.ndarray) -> np.ndarray:
    """(H, W) float source-pixel map -> working pixels (area average over the object only)."""
    side = wf.mask.shape[0]
    x0, y0 = (int(round(c)) for c in wf.offset)
    n = int(round(side * wf.scale))
    box = (x0, y0, x0 + n, y0 + n)
    m = source_mask.astype(np.float32)
    num = _resample((np.where(source_mask, values, 0.0)).astype(np.float32), box, (side, side))
    den = _resample(m, box, (side, side))
    out = np.full((side, side), np.inf)
    ok = den > 1e-3
    out[ok] = num[ok] / den[ok]
    return out


def rasterize(uv: np.ndarray, faces: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool orthographic silhouette of a mesh with working-pixel ``uv`` (V, 2).

    Drawn at :data:`SUPERSAMPLE` x the resolution and area-reduced (a pixel is in when at least
    half of it is covered): polygon filling includes every pixel an edge touches, which would
    otherwise grow each outline by half a pixel. The triangles go to :func:`polygons_mask` as
    one (F, 3, 2) array (no per-face Python objects).
    """
    return polygons_mask(np.asarray(uv)[np.asarray(faces, dtype=np.intp)], shape)


def polygons_mask(polys, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool union of convex polygons (each (k, 2) working pixels), area-reduced.

    ``polys`` is a sequence of (k, 2) arrays or one (n, k, 2) array. Every polygon is filled
    at :data:`SUPERSAMPLE` x the resolution with 4 fractional bits; a pixel is in when at
    least half of its sub-pixels are. The corners of consecutive polygons of one shape and
    dtype are rounded in one array operation (elementwise, so the same values as one polygon
    at a time), and the half-coverage test counts sub-pixels as integers (``2 * count >= k * k``
    is ``mean >= 0.5`` exactly).
    """
    k = SUPERSAMPLE
    out = np.zeros((shape[0] * k, shape[1] * k), np.uint8)
    groups = [polys] if isinstance(polys, np.ndarray) else _same_size_groups(polys)
    fill, line_8 = cv2.fillConvexPoly, cv2.LINE_8  # positional: a third of each call's cost
    for group in groups:
        q = np.round((np.asarray(group) * k - 0.5) * 16).astype(np.int32)
        for corners in list(q):
            fill(out, corners, 1, line_8, 4)  # lineType, shift (4 fractional bits)
    count = out.reshape(shape[0], k, shape[1], k).sum(axis=(1, 3), dtype=np.int32)
    return 2 * count >= k * k


def _same_size_groups(polys) -> list[list[np.ndarray]]:
    """``polys`` split into runs of equal shape and dtype, in order."""
    groups: list[list[np.ndarray]] = []
    last = None
    for p in polys:
        p = np.asarray(p)
        if (p.shape, p.dtype) != last:
            groups.append([])
            last = p.shape, p.dtype
        groups[-1].append(p)
    return groups


def weighted_iou(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> float:
    """IoU of two bool masks with per-pixel weights ``w`` (0 when the union weighs nothing)."""
    inter = (w * (a & b)).sum()
    union = (w * (a | b)).sum()
    return float(inter / union) if union > 0 else 0.0


def fit_iou(sil: np.ndarray, wf: WorkFrame) -> float:
    """Weighted IoU of a predicted silhouette with the amodal mask (module docs)."""
    return weighted_iou(sil, wf.mask, wf.weight)


def inside_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float Euclidean distance of every pixel to the nearest pixel outside ``mask``
    (0 outside), as ``ndimage.distance_transform_edt(mask)``, computed over the mask's bounding
    box grown by one pixel (within the image) only.

    The same numbers: the ring of pixels around the box is outside the mask, and a pixel outside
    the grown box, clamped onto it, lands on that ring no farther from any pixel inside the box
    (clamping to a box that holds a point shortens every coordinate difference), so the nearest
    outside pixel of every pixel in the box lies within the grown box. Where the box meets the
    image's edge there is no ring and nothing beyond it; like scipy, the image's edge is not
    taken as outside.
    """
    mask = np.asarray(mask, dtype=bool)
    out = np.zeros(mask.shape, dtype=np.float64)
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if not len(rows):
        return out
    r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, mask.shape[0])
    c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, mask.shape[1])
    out[r0:r1, c0:c1] = ndimage.distance_transform_edt(mask[r0:r1, c0:c1])
    return out


def signed_distance_2d(mask: np.ndarray) -> np.ndarray:
    """(H, W) float signed distance (pixels) to the mask's contour, positive inside.

    The contour lies on pixel edges: a pixel whose 4-neighbour is outside is at +0.5.
    """
    inside = ndimage.distance_transform_edt(mask) - 0.5
    outside = ndimage.distance_transform_edt(~mask) - 0.5
    return np.where(mask, inside, -outside)


def pixel_centres(mask: np.ndarray, origin: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) centres (u, v) of the True pixels of ``mask``, relative to ``origin`` if given."""
    rows, cols = np.nonzero(mask)
    pts = np.stack([cols + 0.5, rows + 0.5], axis=1)
    return pts if origin is None else pts - origin


def principal_axes(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (u, v) in pixel-centre coordinates and (2, 2) axes (rows, major first)."""
    pts = pixel_centres(mask)
    c = pts.mean(axis=0)
    cov = np.cov((pts - c).T)
    _, vec = np.linalg.eigh(cov)
    axes = vec[:, ::-1].T.copy()
    for i in range(2):  # deterministic sign: largest component positive
        if axes[i][np.argmax(np.abs(axes[i]))] < 0:
            axes[i] = -axes[i]
    return c, axes


def view_chord(verts: np.ndarray, faces: np.ndarray, u: float, v: float) -> float:
    """Depth extent (max z - min z) of a closed mesh along the view ray through (u, v).

    0 when the ray misses. Vertices in (u, v, z) working pixels.
    """
    tri = verts[faces]
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    p = np.array([u, v])
    d = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    ok = np.abs(d) > 1e-12
    d = np.where(ok, d, 1.0)
    l1 = ((b[:, 1] - c[:, 1]) * (p[0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (p[1] - c[:, 1])) / d
    l2 = ((c[:, 1] - a[:, 1]) * (p[0] - c[:, 0]) + (a[:, 0] - c[:, 0]) * (p[1] - c[:, 1])) / d
    l3 = 1 - l1 - l2
    hit = ok & (l1 >= 0) & (l2 >= 0) & (l3 >= 0)
    if not hit.any():
        return 0.0
    z = l1[hit] * tri[hit, 0, 2] + l2[hit] * tri[hit, 1, 2] + l3[hit] * tri[hit, 2, 2]
    return float(z.max() - z.min())


@dataclass
class Hypothesis:
    """One fitted shape.

    Attributes:
        name: family name ("revolution", "slab", "cuboid", "superquadric", "tube", "inflation").
        verts: (V, 3) float (u, v, z) working pixels; faces : (F, 3) int, closed, outward.
        iou: weighted silhouette IoU (:func:`fit_iou`).
        score: selection score (set by the selector).
        rigid_depth: True when the family's depth follows from its outline (round cross-sections);
            False when the depth is a free parameter set from the cues.
        info: family parameters and evidence (JSON-serialisable).
    """

    name: str
    verts: np.ndarray
    faces: np.ndarray
    iou: float
    rigid_depth: bool
    score: float = 0.0
    info: dict = field(default_factory=dict)


def scale_depth(verts: np.ndarray, factor: float) -> np.ndarray:
    """Vertices with z scaled by ``factor`` about the mid-depth."""
    out = np.array(verts, dtype=np.float64)
    zc = 0.5 * (out[:, 2].min() + out[:, 2].max())
    out[:, 2] = zc + (out[:, 2] - zc) * factor
    return out


def front_depth(verts: np.ndarray, faces: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) z of the mesh's nearest surface per working pixel (``inf`` where missed).

    Orthographic, through the project's z-buffer with a camera so far away (10^4 mesh sizes)
    that its perspective is below rounding at the working resolution.
    """
    import torch

    from easyhoi.render.raster import depth_map
    from easyhoi.structures import Camera

    size = float(np.ptp(verts, axis=0).max()) or 1.0
    D = 1e4 * size
    cam = Camera.from_focal(D, shape[1], shape[0], principal=(0.0, 0.0), dtype=torch.float64)
    v = torch.as_tensor(np.asarray(verts, np.float64) + [0.0, 0.0, D])
    z = depth_map(v, torch.as_tensor(np.asarray(faces, np.int64)), cam).numpy()
    return z - D


def relief_agreement(front: np.ndarray, hyp_front: np.ndarray, keep: np.ndarray) -> float:
    """Correlation of two front surfaces after removing the best plane from each, on ``keep``.

    A monocular depth map is known up to scale and shift (and a tilt where the camera is not
    calibrated), so what it says about the shape is its relief: curvature, edges, steps.
    0 when either relief is flat or fewer than 20 pixels are usable.
    """
    ok = keep & np.isfinite(hyp_front) & np.isfinite(front)
    if ok.sum() < 20:
        return 0.0
    v, u = np.nonzero(ok)
    A = np.stack([np.ones(len(u)), u, v], axis=1).astype(np.float64)

    def detrend(z):
        coef, *_ = np.linalg.lstsq(A, z, rcond=None)
        return z - A @ coef

    a, b = detrend(front[ok].astype(np.float64)), detrend(hyp_front[ok].astype(np.float64))
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-9 or nb < 1e-6 * max(np.abs(hyp_front[ok]).max(), 1.0):
        return 0.0
    return float(a @ b / (na * nb))
