"""`shapes.common.inside_distance` against scipy's distance transform of the whole mask."""

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes.common import inside_distance


def _random_mask(rng, H, W):
    m = np.zeros((H, W), bool)
    for _ in range(rng.integers(1, 4)):
        r, c = rng.integers(0, H), rng.integers(0, W)
        h, w = rng.integers(1, 40, 2)
        m[r : r + h, c : c + w] = True
    if rng.random() < 0.3:
        m |= rng.random((H, W)) < 0.2
    return m


def test_inside_distance_equals_the_whole_frame_transform():
    rng = np.random.default_rng(7)
    touching = 0
    for _ in range(400):
        H, W = (int(x) for x in rng.integers(1, 60, 2))
        m = _random_mask(rng, H, W)
        if not (~m).any():
            continue
        touching += bool(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
        got = inside_distance(m)
        assert got.dtype == np.float64 and got.shape == m.shape
        np.testing.assert_array_equal(got, ndimage.distance_transform_edt(m))
    assert touching > 50  # masks cut by the image's edge are among the cases


def test_inside_distance_of_an_empty_mask_is_zero():
    np.testing.assert_array_equal(inside_distance(np.zeros((5, 7), bool)), np.zeros((5, 7)))


def test_inside_distance_of_a_square():
    m = np.zeros((20, 30), bool)
    m[5:10, 10:15] = True  # 5 x 5: the centre pixel is 3 pixels from the nearest outside one
    d = inside_distance(m)
    assert d[7, 12] == 3.0 and d[5, 10] == 1.0 and d[0, 0] == 0.0 and d.max() == 3.0
