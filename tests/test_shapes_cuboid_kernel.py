"""The cuboid objective's compiled kernel equals the NumPy half-plane formulation bit for bit:
the same pixels inside (hulls of boxes in every pose, of random points, in both orientations,
degenerate ones), the same exact weight sums, the same objective values, the same fitted box."""

import math

import cv2
import numpy as np
import pytest

from easyhoi.perception.shapes import common, cuboid
from tests.test_shapes_cuboid_silhouette import _frames

pytest.importorskip("numba")
from easyhoi.perception.shapes import _hull_kernel  # noqa: E402


def _reference_inside(hull32: np.ndarray, shape) -> np.ndarray:
    """(H, W) pixels inside ``hull32`` as the NumPy objective tests them: pixel centres in the
    hull's bounding box, every edge's cross product in float64, the shoelace sign by np.sum."""
    out = np.zeros(shape, bool)
    hull = hull32.astype(np.float64)
    (umin, vmin), (umax, vmax) = hull.min(axis=0).tolist(), hull.max(axis=0).tolist()
    r0, r1 = max(0, math.ceil(vmin - 0.5)), min(shape[0], math.floor(vmax - 0.5) + 1)
    c0, c1 = max(0, math.ceil(umin - 0.5)), min(shape[1], math.floor(umax - 0.5) + 1)
    if r0 >= r1 or c0 >= c1:
        return out
    v = (np.arange(r0, r1) + 0.5)[:, None]
    u = (np.arange(c0, c1) + 0.5)[None, :]
    nxt = np.roll(hull, -1, axis=0)
    positive = np.sum(hull[:, 0] * nxt[:, 1] - nxt[:, 0] * hull[:, 1]) >= 0
    inside = np.ones((r1 - r0, c1 - c0), bool)
    for (p0, p1), (q0, q1) in zip(hull.tolist(), nxt.tolist(), strict=True):
        cross = (q0 - p0) * (v - p1) - (q1 - p1) * (u - p0)
        inside &= cross >= 0 if positive else cross <= 0
    out[r0:r1, c0:c1] = inside
    return out


def _kernel_sums(hull32, w_a, w_b):
    """The kernel's sums of two quarter-multiple weight maps, as float64."""
    qa = cuboid.row_prefix_sums(np.round(4 * w_a).astype(np.int64))
    qb = cuboid.row_prefix_sums(np.round(4 * w_b).astype(np.int64))
    a, b, ok = _hull_kernel.hull_weight_sums(np.ascontiguousarray(hull32), qa, qb)
    assert ok
    return a / 4.0, b / 4.0


def _random_box(rng, shape) -> np.ndarray:
    """A box inside, across or outside the frame; some face-on, edge-on, tiny or huge, some
    centred on pixel centres (the inclusive edge case)."""
    x = np.zeros(8)
    x[0:2] = rng.uniform(-0.4, 1.4, 2) * np.array(shape[::-1])
    kind = rng.integers(5)
    if kind == 0:  # face-on: exactly axis-aligned or turned about the view axis only
        x[4] = rng.choice([0.0, np.pi / 2, rng.uniform(-3, 3)])
    elif kind == 1:  # edge-on: a thin side seen exactly from the side
        x[2] = np.pi / 2
    else:
        x[2:5] = rng.normal(0, 1, 3)
    x[5:8] = np.log(rng.choice([rng.uniform(0.05, 1.0), rng.uniform(1, 60), 500.0], 3))
    if rng.random() < 0.3:
        x[0:2] = np.round(x[0:2]) + 0.5
    return x


def test_kernel_finds_the_same_pixels_as_the_half_plane_tests_for_boxes():
    rng = np.random.default_rng(41)
    shape = (96, 96)
    w = rng.integers(0, 5, shape) / 4.0  # multiples of 1/4, as a work frame's
    idx = np.arange(w.size, dtype=float).reshape(shape)  # separates different pixel sets
    counts = {"empty": 0, "some": 0}
    for _ in range(3000):
        hull = cuboid._hull(_random_box(rng, shape))
        ref = _reference_inside(hull, shape)
        assert _kernel_sums(hull, w, idx) == (w[ref].sum(), idx[ref].sum())
        assert _kernel_sums(hull[::-1], w, w) == (w[ref].sum(), w[ref].sum())
        counts["some" if ref.any() else "empty"] += 1
    assert min(counts.values()) > 200


def test_kernel_equals_the_half_plane_tests_on_random_convex_polygons():
    """Hulls of random points (up to 8 vertices, both orientations), some with collinear and
    repeated vertices, across a frame that is not square."""
    rng = np.random.default_rng(7)
    shape = (37, 53)
    idx = np.arange(np.prod(shape)).reshape(shape) % 97  # separates different pixel sets
    sizes = set()
    for i in range(4000):
        pts = rng.uniform(-10, 60, (8, 2))
        if i % 4 == 0:
            pts = np.round(pts * 2) / 2  # half-integer grid: vertices on pixel centres
        if i % 7 == 0:
            pts[3] = pts[0] + 0.5 * (pts[1] - pts[0])  # a collinear corner
        hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
        for h in (hull, hull[::-1].copy(), np.roll(hull, 2, axis=0)):
            ref = _reference_inside(h, shape)
            assert _kernel_sums(h, idx, np.ones(shape)) == (idx[ref].sum(), ref.sum())
        sizes.add(len(hull))
    assert sizes >= {3, 4, 5, 6, 7, 8}


def test_shoelace_adds_in_numpys_order():
    rng = np.random.default_rng(2)
    for n in range(1, 9):
        for _ in range(3000):
            px = rng.normal(0, 1, n) * 10.0 ** rng.integers(-6, 7, n)
            py = rng.normal(0, 1, n) * 10.0 ** rng.integers(-6, 7, n)
            want = np.sum(px * np.roll(py, -1) - np.roll(px, -1) * py)
            assert _hull_kernel._shoelace(px, py) == want


def test_kernel_declines_non_finite_hulls():
    q = cuboid.row_prefix_sums(np.ones((4, 4), np.int64))
    hull = np.array([[0, 0], [np.inf, 0], [0, 2]], np.float32)
    assert _hull_kernel.hull_weight_sums(hull, q, q) == (0, 0, False)


def _plain_objective(x: np.ndarray, wf: common.WorkFrame) -> float:
    """The objective's IoU as defined: the silhouette over the frame, then the weighted IoU."""
    return common.fit_iou(_reference_inside(cuboid._hull(x), wf.mask.shape), wf)


def test_objective_equals_the_plain_formulation_bit_for_bit(monkeypatch):
    rng = np.random.default_rng(17)
    for wf in _frames():
        fast = cuboid._SilhouetteIoU(wf)
        assert fast.kernel is not None
        monkeypatch.setattr(cuboid, "_hull_kernel", lambda: None)
        numpy_path = cuboid._SilhouetteIoU(wf)
        monkeypatch.undo()
        assert numpy_path.kernel is None
        values = set()
        for _ in range(400):
            x = _random_box(rng, wf.mask.shape)
            got = fast(x)
            assert got == _plain_objective(x, wf) == numpy_path(x)
            values.add(got)
        assert len(values) > 100 and 0.0 in values


def test_a_failing_kernel_warns_once_and_the_numpy_path_takes_over(monkeypatch):
    from numba.core.errors import NumbaError

    from easyhoi import aot, compiled

    calls = []

    def failing(*args):
        calls.append(1)
        raise NumbaError("no LLVM here")

    monkeypatch.setattr(compiled, "_FAILED", set())  # this test's failure stays in it
    monkeypatch.setitem(aot._STATE, "mod", None)  # the numba function, not the built export
    monkeypatch.setattr(_hull_kernel, "hull_weight_sums", failing)
    wf = _frames()[0]
    rng = np.random.default_rng(5)
    boxes = [_random_box(rng, wf.mask.shape) for _ in range(20)]
    objective = cuboid._SilhouetteIoU(wf)
    assert objective.kernel is failing
    with pytest.warns(RuntimeWarning, match="numba kernel hull_weight_sums failed"):
        first = objective(boxes[0])
    assert first == _plain_objective(boxes[0], wf)
    assert [objective(x) for x in boxes[1:]] == [_plain_objective(x, wf) for x in boxes[1:]]
    assert cuboid._SilhouetteIoU(wf).kernel is None  # not tried again in this process
    assert len(calls) == 1


def test_fit_chooses_the_same_box_as_with_the_plain_objective(monkeypatch):
    """The whole fit (Nelder-Mead from five starts) with the kernel and with the plain
    objective: the same box, mesh, score and info bit for bit."""
    frames = _frames()
    depths = (None, 14.0, None)
    fast = [cuboid.fit(wf, depth=d) for wf, d in zip(frames, depths, strict=True)]

    class Plain:
        def __init__(self, wf):
            self.wf = wf

        def __call__(self, x):
            return _plain_objective(x, self.wf)

    monkeypatch.setattr(cuboid, "_SilhouetteIoU", Plain)
    plain = [cuboid.fit(wf, depth=d) for wf, d in zip(frames, depths, strict=True)]
    for a, b in zip(fast, plain, strict=True):
        np.testing.assert_array_equal(a.verts, b.verts)
        np.testing.assert_array_equal(a.faces, b.faces)
        assert a.iou == b.iou and a.info == b.info and a.rigid_depth == b.rigid_depth
