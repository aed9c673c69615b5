"""The object box (``--object-box``): what a box says about the object it is drawn round, and
the box path on drawn scenes with a known answer."""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.perception.masks import ClassicalHOISegmenter, _resample
from easyhoi.perception.prompted import box_grabcut, box_tightness, mask_hypothesis
from easyhoi.perception.prompts import Prompts
from easyhoi.perception.seg_confidence import BOX_AGREEMENT, object_confidence
from tests.test_perception_held_object import S, canvas, det, scene_cues, scene_of
from tests.test_perception_masks import BLUE, KP, RED, SKIN, iou


def rect(shape, u0, v0, u1, v1) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[v0:v1, u0:u1] = True
    return m


def tightness_reference(mask: np.ndarray, box) -> float:
    """Share of the mask inside the box times the IoU of the two rectangles as pixel sets."""
    ys, xs = np.nonzero(mask)
    bb = rect(mask.shape, xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
    bx = rect(mask.shape, *box)
    return (mask & bx).sum() / mask.sum() * (bb & bx).sum() / (bb | bx).sum()


def test_box_tightness_reads_the_bounding_box_not_the_area():
    shape = (120, 120)
    pen = np.zeros(shape, np.uint8)
    cv2.line(pen, (10, 10), (90, 90), 1, 3)
    pen = pen.astype(bool)
    box = (9, 9, 92, 92)
    # a diagonal pen fills a few per cent of its box and still spans it
    assert pen[9:92, 9:92].mean() < 0.1
    assert box_tightness(pen, box) > 0.9
    corner = rect(shape, 10, 10, 40, 40)  # a part of what the box holds
    assert box_tightness(corner, box) < 0.2
    spill = rect(shape, 0, 0, 120, 120)  # the box's surroundings as well
    assert box_tightness(spill, box) < 0.5
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = rng.random(shape) < 0.002
        m[rng.integers(0, 120), rng.integers(0, 120)] = True
        b = tuple(int(v) for v in np.sort(rng.integers(0, 121, 2))) * 2
        b = (b[0], b[2], max(b[1], b[0] + 1), max(b[3], b[2] + 1))
        assert abs(box_tightness(m, b) - tightness_reference(m, b)) < 1e-12
    assert box_tightness(np.zeros(shape, bool), box) == 0.0


def test_resample_takes_the_pixel_under_each_centre():
    rng = np.random.default_rng(0)
    src = (10, 20, 70, 60)  # a 60 x 40 photo window drawn at 30 x 20
    mask = rng.random((20, 30)) < 0.5
    assert np.array_equal(_resample(mask, src, src, (30, 20)), mask)
    dst, size = (0, 15, 40, 45), (16, 12)  # leaves the window on the left and the top
    out = _resample(mask, src, dst, size)
    for r in range(size[1]):
        for c in range(size[0]):
            x = dst[0] + (c + 0.5) * (dst[2] - dst[0]) / size[0]
            y = dst[1] + (r + 0.5) * (dst[3] - dst[1]) / size[1]
            u, v = int(np.floor((x - src[0]) / 2)), int(np.floor((y - src[1]) / 2))
            inside = 0 <= u < 30 and 0 <= v < 20
            assert out[r, c] == (inside and mask[v, u])


def small_hand_scene(obj: np.ndarray, colour) -> tuple[np.ndarray, np.ndarray]:
    """A hand at half the usual size in the lower left and ``obj`` painted in ``colour``."""
    from easyhoi.perception.skin import draw_skeleton

    kp = KP * 0.5 + [10, 110]
    img = canvas()
    img[obj] = colour
    hand = draw_skeleton((S, S), kp, 7, palm=True)
    img[hand] = SKIN
    return np.clip(img, 0, 255).astype(np.uint8), kp


def test_a_box_recovers_a_thin_diagonal_object_and_one_many_hands_large():
    # a pen lying diagonally: a few per cent of its box
    pen = np.zeros((S, S), np.uint8)
    cv2.line(pen, (150, 20), (225, 95), 1, 6)
    pen = pen.astype(bool)
    img, kp = small_hand_scene(pen, BLUE)
    seg = ClassicalHOISegmenter(seed=0).segment(
        img, det(kp), prompts=Prompts(object_box=(146.0, 16.0, 230.0, 100.0))
    )
    assert iou(seg.object_mask, pen) > 0.7
    # a two-coloured board about eight times the hand's area: the box says how large it is
    board = rect((S, S), 110, 10, 230, 120)
    img, kp = small_hand_scene(board, RED)
    img[65:120, 110:230] = BLUE
    hand_area = seg.hand_mask.sum()
    assert board.sum() > 6 * hand_area  # automatic paths take at most 4 hands
    seg = ClassicalHOISegmenter(seed=0).segment(
        img, det(kp), prompts=Prompts(object_box=(105.0, 5.0, 235.0, 125.0))
    )
    assert iou(seg.object_mask, board) > 0.85


def test_box_grabcut_sees_a_small_box_at_its_own_resolution():
    img = np.clip(canvas(1), 0, 255).astype(np.uint8)
    disk = np.zeros((S, S), np.uint8)
    cv2.circle(disk, (60, 60), 9, 1, -1)
    disk = disk.astype(bool)
    img[disk] = RED
    excl = rect((S, S), 40, 60, 60, 80)  # a hand over the disk's lower left
    box = (49.0, 49.0, 72.0, 72.0)
    win, m = box_grabcut(
        img, box, np.zeros((0, 2)), lambda w, size: _resample(excl, (0, 0, S, S), w, size),
        384, 5, 0,
    )  # fmt: skip
    assert win == (37, 37, 84, 84)  # the box grown by half its size on every side
    assert m.shape == (384, 384)  # the 47-px window seen at 384 px
    back = _resample(m, win, (0, 0, S, S), (S, S))
    assert iou(back, disk & ~excl) > 0.85
    assert not (back & excl).any()
    # the same with an object point: it stays object
    _, m2 = box_grabcut(
        img, box, np.array([[66.0, 60.0]]), lambda w, size: _resample(excl, (0, 0, S, S), w, size),
        384, 5, 0,
    )  # fmt: skip
    assert iou(_resample(m2, win, (0, 0, S, S), (S, S)), disk & ~excl) > 0.85


def test_a_box_outline_no_other_candidate_reaches_is_unsure():
    yy, xx = np.mgrid[0:S, 0:S]
    obj = ((xx - 190) ** 2) / 30**2 + ((yy - 60) ** 2) / 22**2 < 1
    img, hand = scene_of([(obj, RED)])
    hyp = mask_hypothesis(obj, scene_cues(img, hand))

    def conf(**kw):
        return object_confidence(hyp, 0, None, True, True, 1.0, **kw)

    sure, alone = conf(box_agreement=BOX_AGREEMENT), conf(box_agreement=BOX_AGREEMENT - 1)
    assert not sure.low and not sure.reasons
    assert alone.low and "box's other candidate outlines" in alone.reasons[-1]
    # a box says how large the object is: a region many hands large is no doubt with one
    big = mask_hypothesis(np.ones((S, S), bool) & ~hand, scene_cues(img, hand))
    boxed, pointed = (object_confidence(big, 0, None, True, True, 1.0, box_agreement=4),
                      object_confidence(big, 0, None, True, True, 1.0))  # fmt: skip
    assert not boxed.reasons and any("size" in r for r in pointed.reasons)  # with points it is
    assert pointed.score < boxed.score
    # on the drawn scene the box's candidates agree on the ellipse
    seg = ClassicalHOISegmenter(seed=0).segment(
        img, det(), prompts=Prompts(object_box=(150.0, 30.0, 230.0, 90.0))
    )
    assert iou(seg.object_mask, obj) > 0.8 and not seg.confidence["object"].low


def test_a_point_mask_that_runs_out_of_the_frame_on_every_side_is_unsure():
    yy, xx = np.mgrid[0:S, 0:S]
    obj = ((xx - 190) ** 2) / 30**2 + ((yy - 60) ** 2) / 22**2 < 1
    img, hand = scene_of([(obj, RED)])
    cues = scene_cues(img, hand)
    # thin bars across the whole frame: an ordinary size, but no outline inside the frame
    cross = np.zeros((S, S), bool)
    cross[58:64, :] = True
    cross[:, 188:194] = True
    cross &= ~hand
    ok = object_confidence(mask_hypothesis(obj, cues), 0, None, True, True, 1.0)
    across = mask_hypothesis(cross, cues)
    bad = object_confidence(across, 0, None, True, True, 1.0)
    assert not ok.low and not ok.reasons
    assert bad.low and any("every side of the frame" in r for r in bad.reasons)
    assert not any("size" in r for r in bad.reasons)  # the sides alone make it unsure
    # a box says how large the object is and where it ends: there the rule does not apply
    boxed = object_confidence(across, 0, None, True, True, 1.0, box_agreement=BOX_AGREEMENT)
    assert not any("every side" in r for r in boxed.reasons)


def test_a_clicked_skin_coloured_object_is_no_doubt_but_skin_beyond_the_click_is():
    from easyhoi.perception.held_object import CUES
    from easyhoi.perception.seg_confidence import SKIN_REASON

    yy, xx = np.mgrid[0:S, 0:S]
    obj = ((xx - 190) ** 2) / 30**2 + ((yy - 60) ** 2) / 22**2 < 1
    img, hand = scene_of([(obj, SKIN)])  # a beige object: the hand's own colour
    hyp = mask_hypothesis(obj, scene_cues(img, hand))
    share = float(hyp.cues[0][CUES.index("skin")])
    assert share > 0.9
    unpointed = object_confidence(hyp, 0, None, True, True, 1.0)
    on_skin = object_confidence(hyp, 0, None, True, True, 1.0, point_skin=1.0)
    off_skin = object_confidence(hyp, 0, None, True, True, 1.0, point_skin=0.0)
    # all of it has the hand's colour: unsure when nothing says that colour is the object's
    assert unpointed.low and "skin colour" in unpointed.reasons[0]
    assert off_skin.low and "where the point has 0%" in off_skin.reasons[0]
    # a point on that colour says it is the object's: no doubt, no reason given
    assert not on_skin.low and not on_skin.reasons
    # only the excess over the point's share counts: logistic(2.5 - 3 * excess)
    for at in (0.2, 0.5, 0.8):
        c = object_confidence(hyp, 0, None, True, True, 1.0, point_skin=at)
        excess = max(0.0, share - at)
        assert abs(c.score - 1.0 / (1.0 + np.exp(-(2.5 - 3.0 * excess)))) < 1e-9
        assert (excess > SKIN_REASON) == any("skin colour" in r for r in c.reasons)
    # through the segmenter: a click on the beige object finds it and trusts it
    seg = ClassicalHOISegmenter(seed=0).segment(
        img, det(), prompts=Prompts(object_points=((190.0, 60.0),))
    )
    assert iou(seg.object_mask, obj) > 0.8
    assert not any("skin colour" in r for r in seg.confidence["object"].reasons)


def test_a_point_mask_much_smaller_than_the_hand_is_unsure():
    from easyhoi.perception.held_object import CUES
    from easyhoi.perception.seg_confidence import CLICK_MARGIN_PENALTY, SMALL_POINT_MASK

    yy, xx = np.mgrid[0:S, 0:S]
    obj = ((xx - 190) ** 2) / 30**2 + ((yy - 60) ** 2) / 22**2 < 1
    img, hand = scene_of([(obj, RED)])
    cues = scene_cues(img, hand)
    whole = mask_hypothesis(obj, cues)
    part = mask_hypothesis(obj & (np.abs(xx - 190) < 5) & (np.abs(yy - 60) < 5), cues)
    a_whole, a_part = (float(h.cues[0][CUES.index("area")]) for h in (whole, part))
    assert a_part < SMALL_POINT_MASK <= a_whole
    ok = object_confidence(whole, 0, None, True, True, 1.0, point_skin=0.0)
    small = object_confidence(part, 0, None, True, True, 1.0, point_skin=0.0)
    assert not ok.low and not ok.reasons
    assert small.low and "small next to the hand" in small.reasons[-1]
    assert not any("unusual" in r for r in small.reasons)  # one reason for the size, not two
    # the same penalty as an unsure click, on the prompted logit (no skin colour here)
    skin = float(part.cues[0][CUES.index("skin")])
    z = 2.5 - 3.0 * skin - CLICK_MARGIN_PENALTY
    assert abs(small.score - 1.0 / (1.0 + np.exp(-z))) < 1e-9
    # a box says how large the object is, and a region picked from masks.png has no point
    boxed = object_confidence(part, 0, None, True, True, 1.0, box_agreement=BOX_AGREEMENT,
                              point_skin=0.0)  # fmt: skip
    picked = object_confidence(part, 0, None, True, True, 1.0)
    assert not any("small next to" in r for r in boxed.reasons + picked.reasons)
