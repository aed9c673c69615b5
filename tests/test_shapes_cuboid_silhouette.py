"""The cuboid's silhouette, computed only inside the hull's bounding box, equals the plain
half-plane test over every pixel (boxes inside, across and outside the frame)."""

import numpy as np

from easyhoi.perception.shapes import cuboid


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
