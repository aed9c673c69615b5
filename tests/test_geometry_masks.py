"""The one mask IoU (against a pixel-by-pixel count, its rule for two empty masks, bad shapes) and
the mask box."""

import math

import numpy as np
import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.masks import mask_box, mask_iou


def _naive(a, b):
    inter = union = 0
    for x, y in zip(np.asarray(a).ravel(), np.asarray(b).ravel(), strict=True):
        inter += bool(x) and bool(y)
        union += bool(x) or bool(y)
    return inter / union


def test_matches_a_pixel_count_on_random_masks():
    rng = np.random.default_rng(3)
    for _ in range(5):
        a, b = rng.random((17, 23)) < 0.4, rng.random((17, 23)) < 0.6
        assert mask_iou(a, b) == pytest.approx(_naive(a, b), abs=1e-12)
    # non-bool input: anything non-zero is inside
    a = np.array([[0, 2], [3, 0]])
    b = np.array([[0, 1], [0, 0]])
    assert mask_iou(a, b) == pytest.approx(0.5)


def test_two_empty_masks_give_the_callers_value():
    z = np.zeros((4, 5), bool)
    assert math.isnan(mask_iou(z, z))
    assert mask_iou(z, z, empty=1.0) == 1.0
    assert mask_iou(z, z, empty=0.0) == 0.0
    one = z.copy()
    one[1, 1] = True
    assert mask_iou(z, one, empty=1.0) == 0.0  # only both empty is undefined


def test_masks_of_different_shapes_are_refused():
    with pytest.raises(InvalidInputError, match="differ in shape"):
        mask_iou(np.ones((3, 3), bool), np.ones((3, 4), bool))


def test_mask_box_is_the_edges_of_the_inside_pixels():
    m = np.zeros((6, 9), bool)
    m[2, 3] = m[4, 7] = True
    assert mask_box(m) == (3, 2, 8, 5)  # u0, v0 of the first pixels, u1, v1 one past the last
    m[:] = False
    with pytest.raises(InvalidInputError):
        mask_box(m)
