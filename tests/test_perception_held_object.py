"""Held-object cues, proposals, prompted segmentation and confidence on drawn scenes.

Every scene has a known answer: a skin-coloured hand drawn from fixed keypoints (fingers up, palm
towards the camera) and painted regions around it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.perception import held_object as ho
from easyhoi.perception.base import HandDetection
from easyhoi.perception.chain import nearest_hand, segment_hands
from easyhoi.perception.masks import ClassicalHOISegmenter
from easyhoi.perception.prompts import Prompts
from easyhoi.perception.proposals import group, propose
from easyhoi.perception.seg_confidence import object_confidence
from easyhoi.perception.skin import draw_skeleton, palm_length, skin_model
from tests.test_perception_masks import BLUE, KP, RED, SKIN, iou

S = 240


def canvas(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.full((S, S, 3), 200.0) + rng.normal(0, 3, (S, S, 3))


def finish(img: np.ndarray, kp: np.ndarray = KP) -> tuple[np.ndarray, np.ndarray]:
    hand = draw_skeleton((S, S), kp, 13, palm=True)
    img[hand] = SKIN
    return np.clip(img, 0, 255).astype(np.uint8), hand


def det(kp: np.ndarray = KP, side: str = "right") -> HandDetection:
    return HandDetection(keypoints2d=kp.copy(), keypoints3d=None, side=side, score=1.0)


def grasped_disk() -> np.ndarray:
    """A disk between the thumb tip and the index/middle fingertips (inside the grasp)."""
    yy, xx = np.mgrid[0:S, 0:S]
    return (xx - 88) ** 2 + (yy - 128) ** 2 < 22**2


def scene_of(regions: list[tuple[np.ndarray, tuple]], kp=KP):
    img = canvas()
    for m, colour in regions:
        img[m] = colour
    return finish(img, kp)


def scene_cues(img: np.ndarray, hand: np.ndarray, other=None, kp=KP) -> ho.Scene:
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    d2 = skin_model(lab, kp).d2(lab)
    other = np.zeros(hand.shape, bool) if other is None else other
    return ho.Scene(lab=lab, hand=hand, kp=kp, skin_d2=d2, other_hands=other)


def cues_of(mask: np.ndarray, scene: ho.Scene) -> dict:
    return dict(zip(ho.CUES, ho.mask_cues(mask, scene), strict=True))


def test_skin_model_learns_this_hands_colour():
    img, hand = finish(canvas())
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    d2 = skin_model(lab, KP).d2(lab)
    core = draw_skeleton((S, S), KP, 3, palm=False)
    assert np.median(d2[core]) < 1.0
    assert np.median(d2[~hand]) > 9.0  # the grey background is not skin
    # a different skin colour: the model follows the photo, not a fixed range
    img2 = img.copy()
    img2[hand] = (120, 80, 60)
    lab2 = cv2.cvtColor(img2, cv2.COLOR_RGB2LAB).astype(np.float64)
    d2b = skin_model(lab2, KP).d2(lab2)
    assert np.median(d2b[core]) < 1.0 and np.median(d2b[~hand]) > 9.0


def test_grasp_zone_lies_between_thumb_and_fingers():
    hand = draw_skeleton((S, S), KP, 13, palm=True)
    zone = ho.grasp_zone((S, S), KP, hand)
    assert zone[128, 88] and not zone[128, 88 - 60] and not zone[20, 20]
    assert not (zone & hand).any()


def test_a_grasped_object_touches_thumb_and_fingers_and_wins():
    disk = grasped_disk()
    img, hand = scene_of([(disk, BLUE)])
    sc = scene_cues(img, hand)
    obj = disk & ~hand
    c = cues_of(obj, sc)
    assert c["thumb"] == 1.0 and c["fingers"] >= 2
    assert c["skin"] < 0.05 and c["border"] == 0.0 and c["contrast"] > 0.9
    assert 0.1 < c["area"] < 2.5
    far = np.zeros((S, S), bool)
    far[10:40, 180:230] = True
    cf = cues_of(far, sc)
    assert cf["fingers"] == 0 and cf["thumb"] == 0 and cf["contact"] == 0
    assert ho.score(ho.mask_cues(obj, sc)[None])[0] > ho.score(ho.mask_cues(far, sc)[None])[0]


def test_background_touching_the_border_loses_to_the_held_object():
    disk = grasped_disk()
    wall = np.zeros((S, S), bool)
    wall[:, 150:] = True  # a region that runs out of the picture on three sides
    img, hand = scene_of([(wall, RED), (disk, BLUE)])
    sc = scene_cues(img, hand)
    cw, cd = cues_of(wall & ~hand, sc), cues_of(disk & ~hand, sc)
    assert cw["border"] > 3.0 and cd["border"] == 0.0
    assert (
        ho.score(ho.mask_cues(disk & ~hand, sc)[None])[0]
        > ho.score(ho.mask_cues(wall & ~hand, sc)[None])[0]
    )
    seg = ClassicalHOISegmenter(seed=0).segment(img, det())
    assert seg.has_object and iou(seg.object_mask, disk & ~hand) > 0.7


def test_a_second_skin_coloured_hand_loses():
    """Another hand pressed against the fingers is skin, and is another detected hand."""
    kp2 = KP.copy()
    kp2[:, 0] = 2 * 118 - kp2[:, 0] + 95  # mirrored, beside the first hand's thumb
    disk = grasped_disk()
    img = canvas()
    img[disk] = BLUE
    img[draw_skeleton((S, S), kp2, 13, palm=True)] = SKIN
    img, hand = finish(img)
    other = draw_skeleton((S, S), kp2, 13, palm=True) & ~hand
    sc = scene_cues(img, hand, other)
    c_other = cues_of(other, scene_cues(img, hand))  # seen as a region: skin-coloured
    assert c_other["skin"] > 0.8
    seg = ClassicalHOISegmenter(seed=0).segment(img, det(), others=[det(kp2, "left")])
    assert seg.has_object
    assert not (seg.object_mask & other).any()
    assert iou(seg.object_mask, disk & ~hand & ~other) > 0.6
    assert sc.other_hands.any()


def test_outline_contrast_whole_object_versus_part_of_one():
    lab = np.zeros((120, 120, 3))
    lab[..., 0] = 200.0
    region = np.zeros((120, 120), bool)
    region[20:100, 20:100] = True
    lab[region] = (90.0, 160.0, 100.0)
    codes = ho.colour_codes(lab)
    none = np.zeros_like(region)
    assert ho.outline_contrast(region, none, codes, 6) == pytest.approx(1.0)
    half = region.copy()
    half[:, 60:] = False  # surrounded in part by more of the same object
    assert ho.outline_contrast(half, none, codes, 6) < 0.75
    assert ho.outline_contrast(none, none, codes, 6) == 0.0


def test_solidity_of_compact_and_straggling_regions():
    sq = np.zeros((100, 100), bool)
    sq[20:80, 20:80] = True
    assert ho.solidity(sq) > 0.9
    ell = np.zeros_like(sq)
    ell[10:90, 10:20] = True
    ell[80:90, 10:90] = True
    assert ho.solidity(ell) < 0.4


def test_grouping_finds_a_two_coloured_object_as_one_hypothesis():
    img = canvas()
    obj = np.zeros((S, S), bool)
    obj[60:180, 70:170] = True
    img[60:120, 70:170] = BLUE
    img[120:180, 70:170] = (40, 140, 60)
    img = np.clip(img, 0, 255).astype(np.uint8)
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    props = propose(img, lab, np.zeros((S, S), bool), scale=150, min_size=30)
    best = max(iou(props.mask(r), obj) for r in props.regions)
    assert best > 0.95
    # base segments alone do not contain it: the grouping made it
    assert max(iou(props.mask(frozenset((i,))), obj) for i in range(props.n_base)) < 0.7
    regions, sizes = group(np.full((4, 4), -1), lab[:4, :4])
    assert regions == () and len(sizes) == 0


def test_one_point_recovers_a_drawn_object_anywhere():
    yy, xx = np.mgrid[0:S, 0:S]
    obj = ((xx - 190) ** 2) / 30**2 + ((yy - 60) ** 2) / 22**2 < 1  # away from the grasp
    img, hand = scene_of([(obj, RED)])
    seg = ClassicalHOISegmenter(seed=0).segment(
        img, det(), prompts=Prompts(object_points=((190.0, 60.0),))
    )
    assert seg.has_object and seg.meta["prompted"]
    assert iou(seg.object_mask, obj) > 0.85
    # a box around it works as well
    seg_b = ClassicalHOISegmenter(seed=0).segment(
        img, det(), prompts=Prompts(object_box=(150.0, 30.0, 230.0, 90.0))
    )
    assert iou(seg_b.object_mask, obj) > 0.8
    with pytest.raises(InvalidInputError):
        ClassicalHOISegmenter().segment(img, det(), prompts=Prompts(object_points=((500, 5),)))


def test_confidence_is_high_when_clear_and_low_when_ambiguous():
    disk = grasped_disk()
    img, _ = scene_of([(disk, BLUE)])
    clear = ClassicalHOISegmenter(seed=0).segment(img, det())
    assert clear.confidence["object"].score > 0.6 and not clear.confidence["object"].reasons
    assert clear.confidence["hand"].score > 0.8
    # nothing in the hand, a skin-coloured blob beside the fingers and a region along the
    # picture's edge: whatever is chosen, the score says it is a guess
    blob = np.zeros((S, S), bool)
    blob[100:140, 150:175] = True
    edge = np.zeros((S, S), bool)
    edge[170:, :] = True
    img2, _ = scene_of([(edge, (150, 150, 150)), (blob, (215, 168, 142))])
    amb = ClassicalHOISegmenter(seed=0).segment(img2, det())
    conf = amb.confidence["object"]
    assert conf.low and conf.reasons


def test_object_confidence_reads_the_cues():
    props = propose(
        np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3)), np.zeros((8, 8), bool), 100, 1
    )
    cues = np.zeros((len(props.regions), len(ho.CUES)))
    cues[:, ho.CUES.index("area")] = 0.5
    cues[:, ho.CUES.index("contrast")] = 1.0
    hyp = ho.Hypotheses(props, cues, np.array([1.0] + [0.9] * (len(props.regions) - 1)))
    conf = object_confidence(hyp, 0, None, True, False, 0.0)
    assert "touches 0 fingertip(s)" in conf.reasons
    assert "the thumb does not touch it" in conf.reasons
    none = object_confidence(None, None, None, False, False, 0.0)
    assert none.score == 0.0 and none.low


def test_the_margin_reason_says_which_region_has_more_evidence():
    """The ranking may choose a region with less held-object evidence than the runner-up: the
    reason then says the other region looks more like a held object, not "almost as likely"."""
    img = np.zeros((8, 8, 3), np.uint8)
    img[:, 4:] = (200, 40, 40)  # two base segments: two regions to compare
    props = propose(img, img.astype(float), np.zeros((8, 8), bool), 100, 1)
    assert len(props.regions) >= 2
    cues = np.zeros((len(props.regions), len(ho.CUES)))
    cues[:, ho.CUES.index("area")] = 0.5
    scores = np.zeros(len(props.regions))
    evidence = np.full(len(props.regions), 4.0)
    evidence[0] = 3.9
    hyp = ho.Hypotheses(props, cues, scores, evidence)
    below = object_confidence(hyp, 0, 1, True, False, 0.0)
    assert "another region looks more like a held object (score margin -0.10)" in below.reasons
    assert not any("almost as likely" in r for r in below.reasons)
    clear = evidence.copy()
    clear[0] = 5.0
    close = object_confidence(ho.Hypotheses(props, cues, scores, clear), 0, 1, True, False, 0.0)
    assert "another region is almost as likely (score margin 1.00)" in close.reasons
    assert close.score > below.score


def test_a_single_clicks_close_runner_up_makes_the_prompted_confidence_low():
    props = propose(
        np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3)), np.zeros((8, 8), bool), 100, 1
    )
    cues = np.zeros((len(props.regions), len(ho.CUES)))
    cues[:, ho.CUES.index("area")] = 0.5
    hyp = ho.Hypotheses(props, cues, np.ones(len(props.regions)))
    clean = object_confidence(hyp, 0, None, True, True, 0.0)
    assert not clean.low and not clean.reasons  # no skin, a held object's size
    far = object_confidence(hyp, 0, None, True, True, 0.0, click_margin=1.2)
    assert far.score == clean.score and not far.reasons
    close = object_confidence(hyp, 0, None, True, True, 0.0, click_margin=0.2)
    assert close.low and any("almost as high (margin 0.20)" in r for r in close.reasons)


def test_click_margin_is_over_the_best_other_region():
    from easyhoi.perception.click import click_margin

    a = np.zeros((20, 20), bool)
    a[2:10, 2:10] = True
    near_copy = a.copy()
    near_copy[10, 2:10] = True  # IoU 0.89 with a: the same region
    other = np.zeros((20, 20), bool)
    other[12:18, 12:18] = True
    scored = [(5.0, {}, near_copy), (6.0, {}, a), (5.7, {}, other), (4.0, {}, other)]
    assert click_margin(scored) == pytest.approx(0.3)
    assert click_margin(scored[:2]) is None  # every candidate about the same region


def test_segment_hands_picks_the_holding_hand_and_notes_the_other():
    disk = grasped_disk()
    kp2 = KP.copy()
    kp2[:, 0] += 100  # a second hand in the same pose, on the right, holding nothing
    img = canvas()
    img[disk] = BLUE
    img[draw_skeleton((S, S), kp2, 13, palm=True)] = SKIN
    img, hand = finish(img)
    hands = [det(kp2, "left"), det(KP, "right")]
    seg_obj = ClassicalHOISegmenter(seed=0)
    idx, seg, notes, choice = segment_hands(img, hands, seg_obj)
    assert idx == 1 and seg.has_object and iou(seg.object_mask, disk & ~hand) > 0.6
    if notes:  # the empty hand was reported, and the holding one used
        assert notes == ["hand 0 (left) holds no object"] and choice == "first holding an object"
    else:  # both produced an object: the more confident one won
        assert choice == "most confident object"
    assert nearest_hand(hands, (210.0, 150.0)) == 0
    assert nearest_hand(hands, (88.0, 128.0)) == 1
    i2, _, _, why = segment_hands(img, hands, seg_obj, Prompts(hand_point=(120.0, 180.0)))
    assert i2 == 1 and why == "hand point"
    assert palm_length(KP) == pytest.approx(np.linalg.norm(KP[9] - KP[0]))
