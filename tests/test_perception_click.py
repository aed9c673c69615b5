"""One-click object segmentation (``perception.click``) on drawn scenes with a known answer:
a skin-coloured hand drawn from fixed keypoints and an object next to it that the region
proposals do not give whole (textured, two-coloured, leaving the picture); further clicks that
add a part."""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.perception.masks import ClassicalHOISegmenter
from easyhoi.perception.prompts import Prompts
from tests.test_perception_held_object import S, canvas, det, finish
from tests.test_perception_masks import KP, iou

YY, XX = np.mgrid[0:S, 0:S]


def click(img: np.ndarray, u: float, v: float, seed: int = 0) -> np.ndarray:
    seg = ClassicalHOISegmenter(seed=seed).segment(
        img, det(), prompts=Prompts(object_points=((u, v),))
    )
    assert seg.has_object and seg.meta["prompted"]
    return seg.object_mask


def test_one_click_recovers_a_textured_object():
    obj = (np.abs(XX - 195) < 32) & (np.abs(YY - 60) < 40)
    img = canvas()
    checker = ((XX // 6 + YY // 6) % 2).astype(bool)
    img[obj & checker] = (200, 40, 40)
    img[obj & ~checker] = (40, 60, 170)
    img, hand = finish(img)
    assert not (obj & hand).any()
    assert iou(click(img, 195.0, 60.0), obj) > 0.8


def test_one_click_recovers_an_object_with_a_strong_internal_edge():
    # a cup: a dark lid over a light body, the click on the body
    obj = ((XX - 195) ** 2 / 30**2 + (YY - 65) ** 2 / 45**2) < 1
    img = canvas()
    img[obj & (YY < 45)] = (60, 20, 20)
    img[obj & (YY >= 45)] = (230, 200, 60)
    img, hand = finish(img)
    assert not (obj & hand).any()
    assert iou(click(img, 195.0, 75.0), obj) > 0.8


def test_one_click_recovers_an_object_leaving_the_picture():
    obj = (XX > 175) & (np.abs(YY - 60) < 25)  # runs out of the right edge
    img = canvas()
    img[obj] = (40, 140, 60)
    img, hand = finish(img)
    m = click(img, 215.0, 60.0)
    assert iou(m, obj) > 0.8
    assert m[:, -1].sum() > 30  # it reaches the picture's edge


def test_one_click_is_deterministic():
    obj = (np.abs(XX - 195) < 30) & (np.abs(YY - 60) < 35)
    rng = np.random.default_rng(1)
    img = canvas()
    img[obj] = (200, 40, 40) + rng.normal(0, 25, (obj.sum(), 3))
    img, _ = finish(img)
    a, b = click(img, 195.0, 60.0), click(img, 195.0, 60.0)
    assert np.array_equal(a, b)
    assert iou(a, obj) > 0.8


def _body_with_a_stick(stick_colour):
    """A red disk clear of the hand and, unless ``stick_colour`` is None, a stick of another
    colour along the shortest way from it to the hand (a lollipop held by its stick)."""
    from scipy import ndimage

    from easyhoi.perception.skin import draw_skeleton

    hand = draw_skeleton((S, S), KP, 13, palm=True)
    body = (XX - 195) ** 2 + (YY - 50) ** 2 < 22**2
    d, idx = ndimage.distance_transform_edt(~hand, return_indices=True)
    a = np.unravel_index(np.argmin(np.where(body, d, np.inf)), d.shape)
    stick = np.zeros((S, S), np.uint8)
    cv2.line(stick, (int(a[1]), int(a[0])), (int(idx[1][a]), int(idx[0][a])), 1, 5)
    stick = stick.astype(bool) & ~body & ~hand
    img = canvas()
    img[body] = (200, 40, 40)
    if stick_colour is not None:
        img[stick] = stick_colour
    img, drawn = finish(img)
    assert np.array_equal(drawn, hand) and d[a] > 40  # a gap of most of a palm length
    return img, hand, body, stick


def test_a_clicked_part_clear_of_the_hand_is_joined_to_it_by_what_lies_between():
    """The click grows the red body, which the hand does not touch; the stick between them,
    of a colour of its own, is joined (the held object touches the hand). Without a stick the
    background between them is not."""
    for colour in [(30, 30, 30), (250, 250, 250), (40, 160, 60)]:
        img, hand, body, stick = _body_with_a_stick(colour)
        m = click(img, 195.0, 50.0)
        near = cv2.dilate(hand.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert (m & near).any(), colour
        assert (m & stick).sum() > 0.85 * stick.sum(), colour
        assert iou(m, body | stick) > 0.85, colour
    img, hand, body, _ = _body_with_a_stick(None)
    m = click(img, 195.0, 50.0)
    near = cv2.dilate(hand.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert not (m & near).any()
    assert iou(m, body) > 0.9


def test_pieces_on_both_sides_of_the_fingers_are_joined():
    from easyhoi.perception.click import join_across_hand

    hand = (XX >= 90) & (XX < 110)  # fingers crossing a bar held behind them
    bar = (np.abs(YY - 50) < 10) & (XX >= 40) & (XX < 160)
    far = (np.abs(YY - 150) < 10) & (XX >= 20) & (XX < 60)  # foreground not touching the hand
    fg = (bar | far) & ~hand
    left = bar & (XX < 90)
    joined = join_across_hand(fg, left, hand, 50.0)
    assert np.array_equal(joined, bar & ~hand)
    # nothing to join when the clicked piece does not reach the hand
    assert join_across_hand(fg, far, hand, 50.0) is None
    # a speck under JOIN_MIN of the clicked piece is noise, not a part of the object
    speck = (np.abs(YY - 50) < 2) & (XX >= 110) & (XX < 112)
    assert join_across_hand(left | speck, left, hand, 50.0) is None


def test_click_proposals_contain_the_click_and_avoid_the_hand():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import click_proposals
    from easyhoi.perception.proposals import propose
    from easyhoi.perception.skin import skin_model

    # a cup: dark lid over a light body, next to a drawn hand
    obj = ((XX - 195) ** 2 / 30**2 + (YY - 65) ** 2 / 45**2) < 1
    img = canvas()
    img[obj & (YY < 45)] = (60, 20, 20)
    img[obj & (YY >= 45)] = (230, 200, 60)
    img, hand = finish(img)
    kp = det().keypoints2d
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(
        lab=lab, hand=hand, kp=kp, skin_d2=skin_model(lab, kp).d2(lab), other_hands=hand & False
    )
    props = propose(img, lab, hand, 150.0, 8, max_size=10.0 * scene.hand_area)
    masks = click_proposals(img, scene, np.array([195.0, 75.0]), props)
    assert masks and all(m[75, 195] and not (m & hand).any() for m in masks)
    assert max(iou(m, obj) for m in masks) > 0.9  # the whole cup is among them


def test_the_hands_rim_is_left_out_unless_the_click_is_skin_coloured():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import RIM, hand_rim
    from easyhoi.perception.skin import palm_length, skin_model

    kp = det().keypoints2d
    L = palm_length(kp)
    img = canvas()
    obj = (np.abs(XX - 195) < 25) & (np.abs(YY - 60) < 25)
    img[obj] = (40, 60, 170)
    img, drawn = finish(img)
    # the hand mask misses a band of skin along the drawn hand's side
    miss = drawn & (XX < XX[drawn].min() + 6)
    hand = drawn & ~miss
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(lab, hand, kp, skin_model(lab, kp).d2(lab), hand & False)
    rim = hand_rim(scene, np.array([195.0, 60.0]))  # a click on the blue object
    assert rim[miss].mean() > 0.9  # the unmasked skin next to the hand is the hand's rim
    assert not (rim & obj).any()  # the object is not skin
    dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
    assert not (rim & (dist >= RIM * L)).any()
    # a click on skin colour (a beige object) keeps everything
    beige = tuple(int(c) for c in img[hand][0])
    img2 = img.copy()
    img2[obj] = beige
    lab2 = cv2.cvtColor(img2, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene2 = ho.Scene(lab2, hand, kp, skin_model(lab2, kp).d2(lab2), hand & False)
    assert not hand_rim(scene2, np.array([195.0, 60.0])).any()


def test_object_pixels_under_a_too_wide_hand_mask_are_taken_back():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import take_back_from_hand
    from easyhoi.perception.skin import skin_model

    kp = det().keypoints2d
    img = canvas()
    img, drawn = finish(img)
    # an orange object pressed against the little finger's side; the hand mask runs up to
    # 12 px into it
    obj = (XX >= 140) & (XX < 210) & (YY >= 110) & (YY < 170) & ~drawn
    img[obj] = (235, 120, 40)
    dist = cv2.distanceTransform((~drawn).astype(np.uint8), cv2.DIST_L2, 5)
    hand = drawn | (obj & (dist <= 12))
    assert (hand & obj).sum() > 500  # the mask took a band of the object
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(lab, hand, kp, skin_model(lab, kp).d2(lab), hand & False)
    seen = obj & ~hand  # what a candidate outside the hand mask gives
    out = take_back_from_hand(seen, scene)
    assert np.array_equal(out & ~hand, seen)  # nothing outside the hand mask changes
    assert (out & hand & obj).sum() >= 0.95 * (hand & obj).sum()  # the band comes back
    assert not (out & drawn & ~obj).any()  # no skin pixel of the drawn hand
    assert iou(out, obj) > 0.97 > iou(seen, obj) + 0.05


def test_nothing_is_taken_back_from_a_hand_of_the_objects_colour_alone():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import take_back_from_hand
    from easyhoi.perception.skin import skin_model

    kp = det().keypoints2d
    img = canvas()
    obj = (np.abs(XX - 195) < 30) & (np.abs(YY - 60) < 40)
    img[obj] = (40, 60, 170)
    img, hand = finish(img)
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(lab, hand, kp, skin_model(lab, kp).d2(lab), hand & False)
    seen = obj & ~hand
    # the hand mask holds only skin here: the blue object's model claims none of it
    assert np.array_equal(take_back_from_hand(seen, scene), seen)


def test_inner_edges_mark_only_the_crop_sides_inside_the_photo():
    from easyhoi.perception.click import inner_edges

    assert not inner_edges((6, 8), None).any()
    e = inner_edges((6, 8), (True, False, False, True))  # photo goes on left and below
    assert e[:, 0].all() and e[-1, :].all()
    assert int(e.sum()) == 6 + 8 - 1
    assert not e[0, 1:].any() and not e[:-1, -1].any()


def test_the_frame_cue_counts_the_length_along_inner_crop_edges():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import candidate_cues, click_score, inner_edges
    from easyhoi.perception.skin import palm_length, skin_model

    kp = det().keypoints2d
    img, hand = finish(canvas())
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(lab, hand, kp, skin_model(lab, kp).d2(lab), hand & False)
    L = palm_length(kp)
    strip = (XX >= 200) & (YY >= 20) & (YY < 100)  # 40 x 80 px, on the right side
    codes = ho.colour_codes(lab)
    grad = np.zeros((S, S), np.float32)
    p = np.array([220.0, 60.0])
    photo = candidate_cues(strip, p, None, scene, hand, codes, grad, inner_edges((S, S), None))
    inner = candidate_cues(
        strip, p, None, scene, hand, codes, grad, inner_edges((S, S), (False, False, True, False))
    )
    assert photo["frame"] == 0.0  # the photo's own edge: the object may leave the photo
    assert abs(inner["frame"] - 80.0 / L) < 1e-9  # 80 px along the crop's inner right side
    # everything else equal, running out of the crop through the photo costs score
    assert click_score(inner) < click_score(photo)


def test_settle_moves_a_loose_outline_onto_the_objects_edge():
    from easyhoi.perception import held_object as ho
    from easyhoi.perception.click import settle
    from easyhoi.perception.skin import skin_model

    kp = det().keypoints2d
    img = canvas()
    obj = (XX - 200) ** 2 + (YY - 60) ** 2 < 28**2
    img[obj] = (40, 60, 170)
    img, hand = finish(img)
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    scene = ho.Scene(lab, hand, kp, skin_model(lab, kp).d2(lab), hand & False)
    # a superpixel-like outline: the disk's bounding square, background corners included
    loose = (np.abs(XX - 200) <= 28) & (np.abs(YY - 60) <= 28)
    assert iou(loose, obj) < 0.8
    out = settle(img, loose, scene, np.array([200.0, 60.0]), 5, 0)
    assert iou(out, obj) > 0.95
    assert not (out & hand).any()


def two_clicks(img: np.ndarray, first, second) -> tuple[np.ndarray, np.ndarray]:
    seg = ClassicalHOISegmenter(seed=0)
    one = seg.segment(img, det(), prompts=Prompts(object_points=(first,))).object_mask
    two = seg.segment(img, det(), prompts=Prompts(object_points=(first, second))).object_mask
    return one, two


def test_a_second_click_adds_the_part_it_marks_not_the_background_around_it():
    # a pale object on a dark panel, a dark button cut into its left edge (the panel's colour):
    # grown alone, the button's best region is the panel; the second click must add the button
    obj = (np.abs(XX - 195) < 32) & (np.abs(YY - 60) < 40)
    button = (XX - 166) ** 2 + (YY - 60) ** 2 < 9**2
    panel = (np.abs(XX - 185) < 52) & (np.abs(YY - 62) < 55)
    img = canvas()
    img[panel] = (35, 35, 40)
    img[obj] = (225, 225, 220)
    img[button] = (35, 35, 40)
    img, hand = finish(img)
    whole = obj | button
    assert not (whole & hand).any()
    one, two = two_clicks(img, (200.0, 60.0), (166.0, 60.0))
    assert iou(one, whole) > 0.85
    assert two[60, 166]  # the marked part is in
    assert iou(two, whole) > 0.9
    assert (two & panel & ~whole).sum() < 0.05 * whole.sum()  # the panel stays out


def test_a_second_click_inside_the_object_changes_nothing():
    obj = (np.abs(XX - 195) < 30) & (np.abs(YY - 60) < 35)
    img = canvas()
    img[obj] = (200, 40, 40)
    img, _ = finish(img)
    one, two = two_clicks(img, (195.0, 60.0), (210.0, 70.0))
    assert np.array_equal(one, two)


def test_the_first_object_point_picks_the_hand():
    from easyhoi.perception.chain import prompted_hand_order

    left = det(KP - [300.0, 0.0])
    right = det()
    far = (-200.0, 150.0)  # inside the left hand's keypoints' extent
    first_near_right = Prompts(object_points=((195.0, 60.0), far, far, far))
    # the mean of the points lies nearer the left hand; the first point decides
    mean = np.mean(first_near_right.object_points, axis=0)
    assert np.abs(KP - [300.0, 0.0] - mean).sum(1).min() < np.abs(KP - mean).sum(1).min()
    assert prompted_hand_order([left, right], first_near_right) == ([1], "object prompt")
    assert prompted_hand_order([left, right], Prompts(object_points=(far,)))[0] == [0]


def test_click_candidates_hold_the_clicked_mask_and_rank_by_score():
    """``click_candidates`` lists every finished candidate of the click, best score first: the
    first one, mapped to the photo, is the click's object mask, and the best of them is at
    least as good as it."""
    obj = ((XX - 195) ** 2 / 30**2 + (YY - 65) ** 2 / 45**2) < 1  # the two-coloured cup
    img = canvas()
    img[obj & (YY < 45)] = (60, 20, 20)
    img[obj & (YY >= 45)] = (230, 200, 60)
    img, _ = finish(img)
    seg = ClassicalHOISegmenter(seed=0)
    (x0, y0, x1, y1), cands = seg.click_candidates(img, det(), (195.0, 75.0))
    assert len(cands) > 3
    scores = [s for _, s in cands]
    assert scores == sorted(scores, reverse=True)

    def full(m):
        out = np.zeros(obj.shape, bool)
        out[y0:y1, x0:x1] = (
            cv2.resize(m.astype(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST) > 0
        )
        return out

    clicked = click(img, 195.0, 75.0)
    assert np.array_equal(full(cands[0][0]), clicked)
    ious = [iou(full(m), obj) for m, _ in cands]
    assert max(ious) >= iou(clicked, obj) > 0.8
    assert min(ious) < 0.8  # the list holds worse candidates too (it is not one mask repeated)
