"""Hand and object masks, contour filtering, inpainting and amodal completion on drawn scenes."""

from __future__ import annotations

import numpy as np
import pytest

from easyhoi.errors import InvalidInputError, NoObjectError
from easyhoi.perception.amodal import ClassicalAmodalSegmenter, amodal_prompts, convex_hull_mask
from easyhoi.perception.base import HandDetection
from easyhoi.perception.inpaint import OpenCVInpainter
from easyhoi.perception.masks import (
    ClassicalHOISegmenter,
    draw_skeleton,
    filter_by_hand_contact,
)

SKIN = (220, 170, 140)
BLUE = (40, 60, 180)
RED = (200, 30, 30)

# a right hand seen from the palm side, fingers up (OpenPose order), wrist at the bottom
KP = np.array(
    [
        (120, 210),
        (100, 195), (85, 180), (75, 165), (68, 152),
        (102, 160), (100, 140), (99, 127), (98, 115),
        (117, 158), (117, 136), (117, 122), (117, 110),
        (132, 160), (133, 140), (134, 127), (135, 116),
        (146, 165), (148, 150), (149, 140), (150, 130),
    ],
    dtype=np.float64,
)  # fmt: skip


def iou(a, b):
    return float((a & b).sum()) / max(1, float((a | b).sum()))


def scene(held=True, distractor=True, size=240):
    rng = np.random.default_rng(0)
    img = np.full((size, size, 3), 200.0) + rng.normal(0, 3, (size, size, 3))
    box = np.zeros((size, size), bool)
    if held:
        box[95:140, 60:180] = True
        img[box] = BLUE
    far = np.zeros((size, size), bool)
    if distractor:
        far[12:42, 12:42] = True
        img[far] = RED
    hand = draw_skeleton((size, size), KP, 13, palm=True)
    img[hand] = SKIN
    img = np.clip(img, 0, 255).astype(np.uint8)
    return img, hand, box & ~hand, far


def detection():
    return HandDetection(keypoints2d=KP.copy(), keypoints3d=None, side="right", score=1.0)


def test_filter_keeps_touching_and_near_components_only():
    hand = np.zeros((100, 100), bool)
    hand[40:60, 40:60] = True
    touching = np.zeros_like(hand)
    touching[40:60, 60:70] = True  # shares the hand's right edge
    near = np.zeros_like(hand)
    near[63:70, 40:60] = True  # 3 px gap below the hand
    far = np.zeros_like(hand)
    far[5:15, 5:15] = True
    kept = filter_by_hand_contact([touching | far, near], hand, max_gap_px=4)
    assert len(kept) == 2
    union = np.any(kept, axis=0)
    assert iou(union, touching | near) == 1.0
    assert not (union & far).any()
    assert filter_by_hand_contact([near], hand, max_gap_px=1) == []
    assert filter_by_hand_contact([touching], np.zeros_like(hand), 4) == []
    with pytest.raises(InvalidInputError):
        filter_by_hand_contact([touching[:50]], hand, 4)
    with pytest.raises(InvalidInputError):
        filter_by_hand_contact([touching], hand, -1)


def test_segmenter_recovers_hand_and_held_box_and_drops_distractor():
    img, hand_gt, obj_gt, far = scene()
    seg = ClassicalHOISegmenter(seed=0).segment(img, detection())
    assert seg.hand_mask.shape == seg.object_mask.shape == img.shape[:2]
    assert iou(seg.hand_mask, hand_gt) > 0.8
    assert seg.has_object
    assert iou(seg.object_mask, obj_gt) > 0.8
    assert not (seg.object_mask & far).any()


def test_segmenter_reports_no_object_when_only_a_far_distractor():
    img, hand_gt, _, _ = scene(held=False, distractor=True)
    seg = ClassicalHOISegmenter(seed=0).segment(img, detection())
    assert iou(seg.hand_mask, hand_gt) > 0.8
    assert not seg.has_object
    assert not seg.object_mask.any()
    assert seg.confidence["object"].low


def test_segmenter_is_deterministic_and_validates():
    img, _, _, _ = scene()
    a = ClassicalHOISegmenter(seed=0).segment(img, detection())
    b = ClassicalHOISegmenter(seed=0).segment(img, detection())
    assert np.array_equal(a.hand_mask, b.hand_mask)
    assert np.array_equal(a.object_mask, b.object_mask)
    with pytest.raises(InvalidInputError):
        ClassicalHOISegmenter().segment(img[..., 0], detection())
    bad = HandDetection(KP[:5], None, "right", 1.0)
    with pytest.raises(InvalidInputError):
        ClassicalHOISegmenter().segment(img, bad)


def plain_scene(region, colour, size=240):
    """The drawn hand on a plain background plus one ``region`` painted ``colour``."""
    rng = np.random.default_rng(0)
    img = np.full((size, size, 3), 200.0) + rng.normal(0, 3, (size, size, 3))
    img[region] = colour
    img[draw_skeleton((size, size), KP, 13, palm=True)] = SKIN
    return np.clip(img, 0, 255).astype(np.uint8)


def test_inpainting_a_stripe_restores_a_flat_colour():
    img = np.zeros((120, 160, 3), np.uint8)
    img[:] = (30, 140, 90)
    mask = np.zeros((120, 160), bool)
    mask[50:66, :] = True
    img[mask] = (250, 250, 0)
    out = OpenCVInpainter(dilate_px=2).inpaint(img, mask)
    err = np.abs(out[mask].astype(int) - np.array([30, 140, 90])).max()
    assert err <= 3
    assert np.array_equal(out[~mask & ~np.roll(mask, 3, 0) & ~np.roll(mask, -3, 0)],
                          img[~mask & ~np.roll(mask, 3, 0) & ~np.roll(mask, -3, 0)])  # fmt: skip
    with pytest.raises(InvalidInputError):
        OpenCVInpainter().inpaint(img, mask[:10])


def split_object_scene():
    img = np.full((200, 240, 3), 215, np.uint8)
    obj = np.zeros((200, 240), bool)
    obj[60:140, 50:190] = True
    img[obj] = (200, 40, 40)
    stripe = np.zeros_like(obj)
    stripe[40:160, 105:130] = True  # a "hand" across the object
    img[stripe] = SKIN
    return img, obj, stripe


def test_prompts_cover_every_part_and_box_is_loose():
    _, obj, stripe = split_object_scene()
    vis = obj & ~stripe
    pts, box = amodal_prompts(vis, n_per_part=4, seed=3)
    assert pts.shape == (8, 2)
    left = pts[:, 0] < 105
    assert left.sum() == 4 and (~left).sum() == 4
    assert all(vis[int(v), int(u)] for u, v in pts)
    u0, v0, u1, v1 = box
    assert u0 < 50 and v0 < 60 and u1 > 190 and v1 > 140
    assert np.allclose(box, (36.0, 52.0, 204.0, 148.0))
    again, _ = amodal_prompts(vis, n_per_part=4, seed=3)
    assert np.array_equal(pts, again)
    with pytest.raises(NoObjectError):
        amodal_prompts(np.zeros_like(vis))


def test_amodal_recovers_object_split_by_hand():
    img, obj, stripe = split_object_scene()
    vis = obj & ~stripe
    inpainted = OpenCVInpainter(dilate_px=3).inpaint(img, stripe)
    pts, box = amodal_prompts(vis, n_per_part=3, seed=0)
    seg = ClassicalAmodalSegmenter(seed=0)
    amodal = seg.segment(inpainted, pts, box, vis)
    assert iou(vis, obj) < 0.85  # the visible mask alone is not enough
    assert iou(amodal, obj) > 0.85
    assert (amodal | ~vis).all()  # contains the visible mask
    assert iou(convex_hull_mask(vis), obj) > 0.95


def test_registry_names():
    import easyhoi.perception.amodal  # noqa: F401
    import easyhoi.perception.inpaint  # noqa: F401
    import easyhoi.perception.masks  # noqa: F401
    from easyhoi.perception import base

    assert isinstance(base.create("segmenter", "classical"), ClassicalHOISegmenter)
    assert isinstance(base.create("inpainter", "opencv"), OpenCVInpainter)
    assert isinstance(base.create("amodal", "classical"), ClassicalAmodalSegmenter)
