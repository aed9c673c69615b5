"""Occluder-bounded amodal completion on drawn scenes with a known complete object."""

import cv2
import numpy as np
import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.perception.amodal import (
    ClassicalAmodalSegmenter,
    amodal_mask,
    amodal_prompts,
    bound_by_occluder,
    occluder_completion,
)
from easyhoi.perception.inpaint import OpenCVInpainter

SKIN = (205, 150, 120)


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def drawn(shape: str):
    """Photo, complete object mask and hand mask: a red object on a textured background, a
    skin-coloured "hand" (a finger stripe and a palm disk) covering part of it."""
    rng = np.random.default_rng(0)
    img = rng.integers(60, 200, (240, 280, 3)).astype(np.uint8)  # cluttered background
    img = cv2.GaussianBlur(img, (7, 7), 0)
    obj = np.zeros((240, 280), np.uint8)
    if shape == "ellipse":
        cv2.ellipse(obj, (140, 120), (90, 55), 20, 0, 360, 1, -1)
    else:  # a bar (pen, handle)
        cv2.fillConvexPoly(obj, np.array([[40, 100], [240, 130], [236, 156], [36, 126]]), 1)
    obj = obj.astype(bool)
    img[obj] = (200, 40, 40)
    hand = np.zeros((240, 280), np.uint8)
    cv2.rectangle(hand, (115, 20), (150, 230), 1, -1)  # a finger across the object
    cv2.circle(hand, (140, 220), 40, 1, -1)  # the palm below it, over the background
    hand = hand.astype(bool)
    img[hand] = SKIN
    return img, obj, hand


@pytest.mark.parametrize("shape", ["ellipse", "bar"])
def test_completion_recovers_hidden_part_and_adds_nothing_outside_the_hand(shape):
    img, obj, hand = drawn(shape)
    vis = obj & ~hand
    inpainted = OpenCVInpainter(dilate_px=3).inpaint(img, hand)
    pts, box = amodal_prompts(vis, seed=0)
    seg = ClassicalAmodalSegmenter(seed=0)
    out = seg.segment(inpainted, pts, box, vis, hand_mask=hand)
    assert seg.last_meta["branch"] == "occluder-hull"
    assert iou(vis, obj) < 0.85  # the hand hides a real part
    assert iou(out, obj) > 0.97
    assert (out | ~vis).all()  # contains the visible mask
    near_hand = cv2.dilate(hand.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert not (out & ~vis & ~near_hand).any()  # adds pixels only behind the hand
    # the hand region outside the object (palm over background) stays background
    assert (out & hand & ~obj).sum() < 0.02 * obj.sum()


def test_grabcut_alone_leaks_into_the_inpainted_hand_region():
    """The reference the occluder bound improves on: the same scene without the hand mask."""
    img, obj, hand = drawn("ellipse")
    vis = obj & ~hand
    inpainted = OpenCVInpainter(dilate_px=3).inpaint(img, hand)
    pts, box = amodal_prompts(vis, seed=0)
    seg = ClassicalAmodalSegmenter(seed=0)
    bounded = seg.segment(inpainted, pts, box, vis, hand_mask=hand)
    free = seg.segment(inpainted, pts, box, vis)
    assert (free & ~obj & hand).sum() > 0.01 * obj.sum()  # smeared colour taken as object
    assert iou(bounded, obj) > iou(free, obj) + 0.015
    clipped = bound_by_occluder(free, vis, hand, margin_px=0)
    assert not (clipped & ~vis & ~hand).any()
    assert np.array_equal(clipped, vis | (free & hand))


def test_nothing_hidden_means_nothing_added():
    img, obj, hand = drawn("ellipse")
    far = np.zeros_like(hand)
    far[200:230, 10:40] = True  # a hand that touches no part of the object
    out = occluder_completion(obj, far)
    assert np.array_equal(out, obj)


def test_any_backend_is_clipped_to_the_occluder():
    img, obj, hand = drawn("bar")
    vis = obj & ~hand

    class Greedy:  # an amodal backend that returns the whole box
        def segment(self, image, points, box, visible_mask):
            return np.ones(visible_mask.shape, bool)

    pts, box = amodal_prompts(vis, seed=0)
    out = amodal_mask(Greedy(), img, pts, box, vis, hand)
    expected = vis | (cv2.dilate(hand.astype(np.uint8), cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (5, 5))) > 0)  # fmt: skip
    assert np.array_equal(out, expected)
    assert np.array_equal(amodal_mask(Greedy(), img, pts, box, vis, None), np.ones_like(vis))


def test_bad_hand_mask_is_a_named_error():
    img, obj, hand = drawn("bar")
    vis = obj & ~hand
    pts, box = amodal_prompts(vis, seed=0)
    with pytest.raises(InvalidInputError):
        ClassicalAmodalSegmenter().segment(img, pts, box, vis, hand_mask=hand[:-1])
