"""The cuboid's silhouette, computed only inside the hull's bounding box, equals the plain
half-plane test over every pixel (boxes inside, across and outside the frame); the fit's cached
objective equals the weighted IoU of that silhouette bit for bit, so the fit is unchanged."""

import numpy as np

from easyhoi.perception.shapes import common, cuboid


def _naive(x: np.ndarray, shape) -> np.ndarray:
    import cv2

    hull = cv2.convexHull(cuboid._corners(x)[:, :2].astype(np.float32)).reshape(-1, 2)
    hull = hull.astype(np.float64)
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    area2 = np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])
    sign = 1.0 if area2 >= 0 else -1.0
    inside = np.ones(shape, bool)
    for p, q in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        inside &= sign * ((q[0] - p[0]) * (v - p[1]) - (q[1] - p[1]) * (u - p[0])) >= 0
    return inside


def test_bounding_box_restriction_is_exact():
    rng = np.random.default_rng(3)
    shape = (90, 120)
    n_in = n_empty = 0
    for _ in range(300):
        x = np.zeros(8)
        x[0:2] = rng.uniform(-40, 160, 2)
        x[2:5] = rng.normal(0, 1, 3)
        x[5:8] = np.log(rng.uniform(0.3, 40, 3))
        # half-integer centres land exactly on pixel centres: the inclusive edge case
        if rng.random() < 0.3:
            x[0:2] = np.round(x[0:2]) + 0.5
        got = cuboid._silhouette(x, shape)
        ref = _naive(x, shape)
        assert np.array_equal(got, ref)
        n_in += bool(ref.any())
        n_empty += not ref.any()
    assert n_in > 100 and n_empty > 10  # both kinds were exercised


def _reference_loss_value(x: np.ndarray, wf: common.WorkFrame) -> float:
    """The objective's IoU as defined: the full silhouette, then the weighted IoU."""
    return common.fit_iou(_naive(x, wf.mask.shape), wf)


def _frames() -> list[common.WorkFrame]:
    """Work frames of a tilted box behind a hand, an ellipse and a rotated thin bar."""
    import cv2

    frames = []
    for i, (a, b, ang) in enumerate([(70, 40, 30), (55, 52, 0), (90, 9, -65)]):
        m = np.zeros((200, 220), np.uint8)
        cv2.ellipse(m, (110, 100), (a, b), ang, 0, 360, 1, -1)
        if i == 0:  # a box outline instead: a hexagon
            m[:] = 0
            x = np.array([110.0, 100.0, 0.5, -0.4, 0.3, np.log(50), np.log(30), np.log(18)])
            hull = cv2.convexHull(np.round(cuboid._corners(x)[:, :2]).astype(np.int32))
            cv2.fillConvexPoly(m, hull, 1)
        m = m.astype(bool)
        occ = np.zeros_like(m)
        occ[90:150, 40:190] = True
        img = np.random.default_rng(i).integers(0, 255, (*m.shape, 3), dtype=np.uint8)
        frames.append(common.work_frame(m, m & ~occ, occ, img))
    return frames


def test_objective_equals_fit_iou_of_the_silhouette_bit_for_bit():
    rng = np.random.default_rng(5)
    for wf in _frames():
        assert set(np.unique(wf.weight)) == {0.0, 0.5, 1.0}  # all three kinds of pixel
        objective = cuboid._SilhouetteIoU(wf)
        assert objective.exact
        values = []
        for _ in range(150):
            x = np.zeros(8)
            x[0:2] = rng.uniform(-30, 126, 2)
            x[2:5] = rng.normal(0, 1, 3)
            x[5:8] = np.log(rng.uniform(0.3, 60, 3))
            got = objective(x)
            assert got == _reference_loss_value(x, wf)  # exact equality, not approx
            values.append(got)
        assert max(values) > 0.2 and min(values) == 0.0  # overlapping and disjoint boxes


def test_objective_with_other_weights_takes_the_plain_path():
    wf = _frames()[1]
    wf.weight = wf.weight * 0.3  # not multiples of 1/4: sums would depend on their order
    objective = cuboid._SilhouetteIoU(wf)
    assert not objective.exact
    x = np.array([48.0, 48.0, 0.2, 0.1, 0.0, np.log(30), np.log(20), np.log(10)])
    assert objective(x) == _reference_loss_value(x, wf)


def test_fit_takes_the_same_path_as_the_plain_objective(monkeypatch):
    """The whole fit (Nelder-Mead from five starts) with the cached objective and with the
    plain one give the same box bit for bit."""
    frames = _frames()
    fast = [cuboid.fit(wf, depth=d) for wf, d in zip(frames, (None, 14.0, None), strict=True)]

    class Plain:
        def __init__(self, wf):
            self.wf = wf

        def __call__(self, x):
            return _reference_loss_value(x, self.wf)

    monkeypatch.setattr(cuboid, "_SilhouetteIoU", Plain)
    plain = [cuboid.fit(wf, depth=d) for wf, d in zip(frames, (None, 14.0, None), strict=True)]
    for a, b in zip(fast, plain, strict=True):
        np.testing.assert_array_equal(a.verts, b.verts)
        assert a.iou == b.iou and a.info == b.info


def test_rotation_matrix_equals_scipy_rotation():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(11)
    for i in range(2000):
        rv = rng.normal(0, 1, 3) * 10 ** rng.uniform(-9, 0.7)
        if i % 5 == 0:
            rv[rng.integers(3)] = 0.0
        want = Rotation.from_rotvec(rv).as_matrix()
        np.testing.assert_array_equal(cuboid._rotvec_matrix(rv), want)
    np.testing.assert_array_equal(cuboid._rotvec_matrix(np.zeros(3)), np.eye(3))
