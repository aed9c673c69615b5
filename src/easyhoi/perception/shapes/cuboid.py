"""Cuboid: boxes (cereal, tea, gelatin, sugar), blocks, staplers seen as blocks.

An oriented box seen orthographically: centre ``(u, v)``, rotation (rotation vector, 3) and
half-extents (3, log scale). Its outline is the convex hull of the 8 projected corners — a
rectangle face-on, a hexagon when two or three faces are seen, which pins the box's depth and
tilt. The 8 parameters maximise the weighted silhouette IoU by Nelder-Mead from several starts
(the mask's minimum-area rectangle face-on and tilted by +-35 degrees about its sides). When
the fitted box is nearly face-on the depth is not in the outline and comes from the grasp or
a prior (half the shorter side); a weak pull towards that depth keeps the optimiser from
drifting along the flat direction.

Edge evidence: where two visible faces of a box meet, the image has a straight edge (the faces
are lit differently), all along the line where they meet. On each projected internal edge the
gradient magnitude (the largest within a pixel of the line) is sampled along the middle of the
edge, and the edge's level is the median of the samples; the mean of the edges' levels over
the median gradient inside the outline is ``edge_ratio``; ``edge_evidence = clip((ratio - 1) /
2, 0, 1)``. The median, not the mean: a curved rim (a mug's or a can's), a handle, a label or a
finger's shadow that crosses the line adds gradient at a few points of it, and would otherwise
count as an edge.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from easyhoi import compiled
from easyhoi.perception.shapes.common import Hypothesis, WorkFrame, fit_iou

_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
#: box faces as corner indices (counter-clockwise seen from outside) and their outward axis
_FACES = (
    ((0, 1, 3, 2), (-1, 0, 0)),
    ((4, 6, 7, 5), (1, 0, 0)),
    ((0, 4, 5, 1), (0, -1, 0)),
    ((2, 3, 7, 6), (0, 1, 0)),
    ((0, 2, 6, 4), (0, 0, -1)),
    ((1, 5, 7, 3), (0, 0, 1)),
)
#: Initial simplex steps (pixels, radians, log-extents).
_STEPS = np.array([2.0, 2.0, 0.3, 0.3, 0.3, 0.15, 0.15, 0.3])
#: Prior depth of a face-on box as a fraction of its shorter visible side.
PRIOR_DEPTH_RATIO = 0.5


def _rotvec_matrix(rotvec: np.ndarray) -> np.ndarray:
    """``Rotation.from_rotvec(rotvec).as_matrix()`` for one float64 (3,) rotation vector.

    Calls the compiled kernels that ``Rotation`` itself dispatches to for NumPy input (same
    arithmetic, so the same bits) without its per-call dispatch, which costs about three times
    the kernels; ``Rotation`` itself where those kernels are missing or differ.
    """
    if _ROTATION_KERNELS is None:
        return Rotation.from_rotvec(rotvec).as_matrix()
    from_rotvec, as_matrix = _ROTATION_KERNELS
    return as_matrix(from_rotvec(np.asarray(rotvec, np.float64))[None])[0]


def _rotation_kernels():
    """scipy's compiled (from_rotvec, as_matrix), when present and equal to ``Rotation``."""
    try:
        from scipy.spatial.transform import _rotation_cy

        kernels = (_rotation_cy.from_rotvec, _rotation_cy.as_matrix)
        for rv in ([0.0, 0.0, 0.0], [1e-9, -2e-9, 3e-10], [0.3, -1.2, 2.5], [3.0, 0.1, -0.2]):
            rv = np.array(rv)
            want = Rotation.from_rotvec(rv).as_matrix()
            if not np.array_equal(kernels[1](kernels[0](rv)[None])[0], want):
                return None
        return kernels
    except Exception:  # noqa: BLE001 - a private module: any change means the public path
        return None


_ROTATION_KERNELS = _rotation_kernels()


def _corners(x: np.ndarray) -> np.ndarray:
    R = _rotvec_matrix(x[2:5])
    return (_SIGNS * np.exp(x[5:8])) @ R.T + np.array([x[0], x[1], 0.0])


def _silhouette(x: np.ndarray, shape) -> np.ndarray:
    """Pixels whose centre lies inside the convex hull of the projected corners."""
    out = np.zeros(shape, bool)
    hit = _hull_pixels(x, shape)
    if hit is not None:
        rows, cols, inside = hit
        out[rows, cols] = inside
    return out


def _hull(x: np.ndarray) -> np.ndarray:
    """(n, 2) float32 vertices of the convex hull of the projected corners, in order."""
    return cv2.convexHull(_corners(x)[:, :2].astype(np.float32)).reshape(-1, 2)


def _hull_pixels(x: np.ndarray, shape) -> tuple[slice, slice, np.ndarray] | None:
    """The hull's pixel-centre bounding box (rows, cols) and which of its pixels are inside.

    None when no pixel centre can be inside. Only pixels whose centre (index + 0.5) lies within
    the hull's bounding box can be inside; the half-plane test of each hull edge is evaluated
    as a column term minus a row term broadcast over the box (the same floating-point operations
    per pixel as on full coordinate grids).
    """
    hull = _hull(x).astype(np.float64)
    (umin, vmin), (umax, vmax) = hull.min(axis=0).tolist(), hull.max(axis=0).tolist()
    r0 = max(0, math.ceil(vmin - 0.5))
    r1 = min(shape[0], math.floor(vmax - 0.5) + 1)
    c0 = max(0, math.ceil(umin - 0.5))
    c1 = min(shape[1], math.floor(umax - 0.5) + 1)
    if r0 >= r1 or c0 >= c1:
        return None
    v = (np.arange(r0, r1) + 0.5)[:, None]
    u = (np.arange(c0, c1) + 0.5)[None, :]
    nxt = np.concatenate([hull[1:], hull[:1]])
    area2 = np.sum(hull[:, 0] * nxt[:, 1] - nxt[:, 0] * hull[:, 1])
    # inside: sign * cross >= 0 for every edge, sign = +-1 the hull's orientation; that is the
    # smallest cross >= 0 (the largest <= 0 for sign -1): min/max return one of their inputs
    # and propagate NaN, so the test is the same as edge by edge
    positive = area2 >= 0
    extreme = np.minimum if positive else np.maximum
    acc = cross = None
    for (p0, p1), (q0, q1) in zip(hull.tolist(), nxt.tolist(), strict=True):
        cross = np.subtract((q0 - p0) * (v - p1), (q1 - p1) * (u - p0), out=cross)
        if acc is None:
            acc, cross = cross, None
        else:
            extreme(acc, cross, out=acc)
    inside = acc >= 0 if positive else acc <= 0
    return slice(r0, r1), slice(c0, c1), inside


def row_prefix_sums(q: np.ndarray) -> np.ndarray:
    """(H, W + 1) int64 ``out[r, c] = q[r, :c].sum()`` of an (H, W) integer map."""
    out = np.zeros((q.shape[0], q.shape[1] + 1), np.int64)
    np.cumsum(q, axis=1, out=out[:, 1:])
    return out


def _hull_kernel():
    """:func:`._hull_kernel.hull_weight_sums`, or None where numba cannot be imported or the
    kernel failed to compile or run in this process (:mod:`easyhoi.compiled`; the NumPy path
    is used)."""
    return compiled.kernel("easyhoi.perception.shapes._hull_kernel", "hull_weight_sums")


class _SilhouetteIoU:
    """``fit_iou(_silhouette(x, shape), wf)`` for many boxes ``x`` of one fit.

    The per-fit invariants (the weights inside and outside the mask, the mask's total weight)
    are computed once and each evaluation sums only over the hull's bounding box:
    ``inter = sum(w * mask * sil)``, ``union = sum(w * mask) + sum(w * ~mask * sil)``. With
    weights that are multiples of 1/4 (those of :func:`.common.work_frame`) every partial sum
    is exact in float64, so the value equals :func:`.common.fit_iou` bit for bit whatever the
    summation order; other weights take the plain path. The exact sums are taken by the
    compiled :func:`._hull_kernel.hull_weight_sums` from row-wise prefix sums of the weights
    times 4 (integers; the float64 sums are those integers over 4, exactly), or by NumPy
    over the hull's pixels where numba is not usable.
    """

    def __init__(self, wf: WorkFrame):
        self.wf = wf
        w = np.asarray(wf.weight, np.float64)
        q = 4.0 * np.abs(w)
        self.exact = bool(np.all(q == np.round(q)) and q.sum() < 2.0**50)
        self.w_in = np.where(wf.mask, w, 0.0)
        self.w_out = np.where(wf.mask, 0.0, w)
        self.mask_weight = self.w_in.sum()
        self.kernel = _hull_kernel() if self.exact else None
        if self.kernel is not None:
            self.quarters_in = row_prefix_sums(np.round(4.0 * self.w_in).astype(np.int64))
            self.quarters_out = row_prefix_sums(np.round(4.0 * self.w_out).astype(np.int64))

    def __call__(self, x: np.ndarray) -> float:
        if not self.exact:
            return fit_iou(_silhouette(x, self.wf.mask.shape), self.wf)
        if self.kernel is not None:
            args = (_hull(x), self.quarters_in, self.quarters_out)
            ran, sums = compiled.run(
                "hull_weight_sums", self.kernel, *args, fallback="the box fit sums with NumPy"
            )
            if not ran:
                self.kernel = None
            elif sums[2]:  # every vertex finite
                q_in, q_out = sums[0], sums[1]
                union = self.mask_weight + q_out / 4.0
                return float(q_in / 4.0 / union) if union > 0 else 0.0
        hit = _hull_pixels(x, self.wf.mask.shape)
        if hit is None:
            inter, union = 0.0, self.mask_weight
        else:
            rows, cols, inside = hit
            inter = self.w_in[rows, cols][inside].sum()
            union = self.mask_weight + self.w_out[rows, cols][inside].sum()
        return float(inter / union) if union > 0 else 0.0


def box_mesh(x: np.ndarray, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (u, v, z) and faces of the box ``x`` (subdivided so it samples evenly)."""
    import trimesh

    m = trimesh.creation.box(extents=2 * np.exp(x[5:8]))
    for _ in range(subdivisions):
        m = m.subdivide()
    R = Rotation.from_rotvec(x[2:5]).as_matrix()
    v = np.asarray(m.vertices) @ R.T + np.array([x[0], x[1], 0.0])
    return v, np.asarray(m.faces, np.int64)


def _internal_edges(x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Projected edges shared by two camera-facing faces (they lie inside the outline)."""
    R = Rotation.from_rotvec(x[2:5]).as_matrix()
    c = _corners(x)
    visible = [f for f, n in _FACES if (R @ np.asarray(n, float))[2] < -0.3]
    edges = {}
    for f in visible:
        for i in range(4):
            key = tuple(sorted((f[i], f[(i + 1) % 4])))
            edges[key] = edges.get(key, 0) + 1
    return [(c[i, :2], c[j, :2]) for (i, j), k in edges.items() if k == 2]


def edge_evidence(x: np.ndarray, wf: WorkFrame) -> tuple[float, float]:
    """(edge_ratio, edge_evidence) of the fitted box ``x`` (module docs); (0, 0) without image."""
    if wf.gray is None:
        return 0.0, 0.0
    g = cv2.GaussianBlur(wf.gray, (0, 0), 0.8)
    mag = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_64F, 0, 1, ksize=3))
    # max over a 3x3 neighbourhood: the edge may sit a pixel off the fitted line
    local = cv2.dilate(mag, np.ones((3, 3), np.uint8))
    inner = cv2.erode(wf.visible.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    base = float(np.median(mag[inner])) if inner.sum() > 20 else 0.0
    vals = []
    for p, q in _internal_edges(x):
        n = int(np.linalg.norm(q - p))
        if n < 6:
            continue
        t = np.linspace(0.15, 0.85, n)[:, None]
        pts = p + t * (q - p)
        ij = np.floor(pts).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < g.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < g.shape[0])
        ij = ij[ok]
        ij = ij[inner[ij[:, 1], ij[:, 0]]]
        if len(ij) >= 4:
            vals.append(np.median(local[ij[:, 1], ij[:, 0]]))
    if not vals or base <= 0:
        return 0.0, 0.0
    ratio = float(np.mean(vals) / max(base, 1e-6))
    return ratio, float(np.clip((ratio - 1.0) / 2.0, 0.0, 1.0))


def fit(
    wf: WorkFrame,
    depth: float | None = None,
    min_depth: float | None = None,
    max_evals: int = 250,
) -> Hypothesis:
    """The best-fitting box; ``depth`` (working pixels) sets a face-on box's depth extent
    (default: the prior, at least ``min_depth``)."""
    m = wf.mask
    cnts, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = np.concatenate([c.reshape(-1, 2) for c in cnts]).astype(np.float32) + 0.5
    (cu, cv), (w, h), ang = cv2.minAreaRect(pts)
    w, h = max(w, 2.0), max(h, 2.0)
    d0 = PRIOR_DEPTH_RATIO * min(w, h) if depth is None else float(depth)
    if depth is None and min_depth is not None:
        d0 = max(d0, float(min_depth))
    log_d0 = np.log(max(d0, 1.0) / 2)
    base = np.array([cu, cv, 0.0, 0.0, np.radians(ang), np.log(w / 2), np.log(h / 2), log_d0])

    silhouette_iou = _SilhouetteIoU(wf)

    def loss(x):
        return -silhouette_iou(x) + 0.002 * (x[7] - log_d0) ** 2

    best = None
    for tilt in ((0, 0), (0.6, 0), (-0.6, 0), (0, 0.6), (0, -0.6)):
        x0 = base.copy()
        rz = Rotation.from_rotvec([0, 0, x0[4]])
        x0[2:5] = (rz * Rotation.from_rotvec([tilt[0], tilt[1], 0.0])).as_rotvec()
        if tilt != (0, 0):  # a tilted box of the same outline is thinner in the tilted side
            x0[5] += np.log(0.85) * (tilt[1] != 0)
            x0[6] += np.log(0.85) * (tilt[0] != 0)
        simplex = np.vstack([x0, x0 + np.diag(_STEPS)])
        res = minimize(loss, x0, method="Nelder-Mead",
                       options=dict(maxfev=max_evals, xatol=1e-3, fatol=1e-5,
                                    initial_simplex=simplex))  # fmt: skip
        if best is None or res.fun < best.fun - 1e-4:
            best = res
    x = best.x
    R = Rotation.from_rotvec(x[2:5]).as_matrix()
    face_on = float(np.abs(R[2]).max())  # |cos| between the view axis and the nearest box axis
    if face_on > 0.95 and depth is not None:  # depth not in the outline: take the cue
        k = int(np.argmax(np.abs(R[2])))
        x[5 + k] = np.log(max(float(depth), 1.0) / 2)
    verts, faces = box_mesh(x)
    iou = fit_iou(_silhouette(x, m.shape), wf)
    ratio, evidence = edge_evidence(x, wf)
    info = dict(half_extents=[round(float(e), 3) for e in np.exp(x[5:8])],
                face_on=round(face_on, 4), edge_ratio=round(ratio, 3),
                edge_evidence=round(evidence, 3))  # fmt: skip
    return Hypothesis("cuboid", verts, faces, iou, face_on <= 0.95, info=info)
