"""The held-object cues of ``grasp_cues`` on drawn scenes with known answers.

The hand is the palm-side right hand of ``test_perception_masks`` (fingers up, wrist at the
bottom) drawn 13 px wide; regions are label maps painted around it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from easyhoi.perception import grasp_cues as gc
from easyhoi.perception import held_object as ho
from easyhoi.perception.proposals import Proposals, membership
from easyhoi.perception.skin import draw_skeleton
from tests.test_perception_masks import KP

S = 240


def hand() -> np.ndarray:
    return draw_skeleton((S, S), KP, 13, palm=True)


def cues_of(labels: np.ndarray, regions: list[set[int]]) -> np.ndarray:
    """(len(regions), len(gc.EXTRA)) cues of the regions (sets of labels) of a label map."""
    n = int(labels.max()) + 1
    props = Proposals(
        labels=labels,
        regions=tuple(frozenset(r) for r in regions),
        sizes=np.bincount(labels[labels >= 0], minlength=n).astype(float),
    )
    table = gc.segment_table(labels, labels < 0, KP, n)
    return gc.region_cues(membership(props), table)


def col(name: str) -> int:
    return gc.EXTRA.index(name)


def test_cross_sections_find_the_region_on_both_sides_of_every_finger():
    h = hand()
    labels = np.where(h, -1, 0)
    pairs = gc.cross_sections(labels, KP)
    # 14 bones (3 per finger, 2 of the thumb), sampled every 2 px: dozens of sections
    assert len(pairs) > 60 and (pairs == 0).all()
    # one background everywhere: every section has it on both sides
    assert cues_of(labels, [{0}])[0, col("cross")] == pytest.approx(1.0)


def test_cross_is_zero_for_regions_that_stop_at_the_fingers():
    h = hand()
    xx = np.mgrid[0:S, 0:S][1]
    # split between the index (x ~ 100, sides at ~93 and ~107) and the middle finger (x = 117,
    # sides at ~110 and ~124): no finger has the two labels on its two sides
    labels = np.where(h, -1, (xx >= 109).astype(int))
    c = cues_of(labels, [{0}, {1}, {0, 1}])[:, col("cross")]
    assert c[0] > 0.2 and c[1] > 0.2
    # each section lies on one side of the split, but for the few near the palm whose sides are
    # found far from the bone
    assert 0.9 < c[0] + c[1] <= 1.0
    assert c[2] == pytest.approx(1.0)
    # a region on one side of the middle finger only: its sections all end in another label
    strip = np.where(h, -1, 0)
    strip[100:130, 124:128] = 1
    strip = np.where(h, -1, strip)
    assert cues_of(strip, [{1}])[0, col("cross")] == 0.0


def test_flanks_find_the_surface_on_both_sides_of_the_palm():
    h = hand()
    yy, xx = np.mgrid[0:S, 0:S]
    disk = (xx - 88) ** 2 + (yy - 128) ** 2 < 22**2  # in the grasp, beyond the thumb side
    labels = np.where(h, -1, np.where(disk, 1, 0))
    c = cues_of(labels, [{0}, {1}])[:, col("flanks")]
    # the background is on both sides of the palm along its whole length; the grasped disk
    # lies on one side at most
    assert c[0] == pytest.approx(1.0) and c[1] == 0.0
    # a surface on the thumb side only (left of the wrist-middle MCP axis, x = 117-120)
    half = np.where(h, -1, (xx < 118).astype(int))
    assert cues_of(half, [{1}])[0, col("flanks")] == 0.0


def test_sides_counts_the_crop_edges_a_region_touches():
    labels = np.zeros((S, S), int)
    labels[:60, :60] = 1  # top-left corner: 2 sides
    labels[100:140, 100:140] = 2  # inside: no side
    labels[:, 200:] = 3  # right strip: top, bottom, right
    c = cues_of(labels, [{1}, {2}, {3}, {0, 1, 2, 3}])[:, col("sides")]
    assert c.tolist() == [2.0, 0.0, 3.0, 4.0]


def test_wrap_and_spread_separate_a_surround_from_an_object_on_one_side():
    h = hand()
    yy, xx = np.mgrid[0:S, 0:S]
    disk = (xx - 88) ** 2 + (yy - 128) ** 2 < 22**2  # between the thumb and the fingers
    labels = np.where(h, -1, np.where(disk, 1, 0))
    c = cues_of(labels, [{0}, {1}])
    # the background around the hand borders most of its outline, in every direction
    assert c[0, col("wrap")] > 0.8 and c[0, col("spread")] == pytest.approx(1.0)
    assert c[1, col("wrap")] < 0.25 and c[1, col("spread")] <= 4 / gc.SECTORS
    assert c[0, col("wrap")] + c[1, col("wrap")] == pytest.approx(1.0)


def test_back_is_contact_at_the_wrist_end_only():
    h = hand()
    labels = np.where(h, -1, 0)
    labels[200:S, :] = np.where(h[200:S, :], -1, 1)  # below the wrist (y = 210)
    labels[:105, :] = np.where(h[:105, :], -1, 2)  # above the fingertips
    c = cues_of(labels, [{1}, {2}])[:, col("back")]
    assert c[0] > 0.3 and c[1] == 0.0


def test_pinch_is_the_share_of_the_grip_lines_covered():
    h = hand()
    yy, xx = np.mgrid[0:S, 0:S]
    disk = (xx - 88) ** 2 + (yy - 128) ** 2 < 22**2
    labels = np.where(h, -1, np.where(disk, 1, 0))
    c = cues_of(labels, [{1}, {0}, {0, 1}])[:, col("pinch")]
    assert c[0] > 0.5 and c[2] == pytest.approx(1.0)
    assert c[0] + c[1] == pytest.approx(1.0)
    far = np.where(h, -1, 0)
    far[10:40, 180:230] = 1
    assert cues_of(far, [{1}])[0, col("pinch")] == 0.0


def test_amodal_solidity_counts_the_fingers_in_front_of_an_object():
    yy, xx = np.mgrid[0:S, 0:S]
    disk = (xx - 120) ** 2 + (yy - 120) ** 2 < 50**2
    bar = (np.abs(xx - 120) < 12) | (np.abs(yy - 120) < 12)  # two fingers across the disk
    visible = disk & ~bar
    assert ho.solidity(visible) < 0.75
    assert gc.amodal_solidity(visible, bar) > 0.9
    assert gc.amodal_solidity(disk, np.zeros_like(bar)) == pytest.approx(ho.solidity(disk))
    assert gc.amodal_solidity(np.zeros_like(bar), bar) == 0.0


def test_every_hypothesis_gets_the_extra_cues_in_describe():
    h = hand()
    labels = np.where(h, -1, 0)
    labels[:60, :60] = np.where(h[:60, :60], -1, 1)
    props = Proposals(
        labels=labels,
        regions=(frozenset({0}), frozenset({1}), frozenset({0, 1})),
        sizes=np.bincount(labels[labels >= 0]).astype(float),
    )
    scene = ho.Scene(
        lab=np.zeros((S, S, 3)),
        hand=h,
        kp=KP,
        skin_d2=np.full((S, S), 100.0),
        other_hands=np.zeros((S, S), bool),
    )
    cues = ho.describe(props, scene)
    extra = cues[:, len(ho.CUES) - len(gc.EXTRA) : -1]  # amodal (last) needs the mask drawn
    assert np.allclose(extra, cues_of(labels, [{0}, {1}, {0, 1}])[:, :-1])


def test_ranker_score_is_the_hand_set_score_plus_the_weighted_features():
    from easyhoi.perception import ranker

    rng = np.random.default_rng(0)
    cues = rng.uniform(0.0, 1.0, (6, len(ho.CUES)))
    cues[:, ho.CUES.index("area")] = [0.05, 0.2, 1.0, 2.0, 4.0, 9.0]
    only_score = dict.fromkeys(ranker.FEATURES, 0.0) | {"score": 1.0}
    assert np.allclose(ranker.ranker_score(cues, only_score), ho.score(cues))
    only_area = dict.fromkeys(ranker.FEATURES, 0.0) | {"log_area": 1.0}
    assert np.allclose(ranker.ranker_score(cues, only_area), np.log(cues[:, ho.CUES.index("area")]))
    # the grasp cues count through the same object-likeness gate as in the hand-set score
    only_grasp = dict.fromkeys(ranker.FEATURES, 0.0) | {"grasp": 1.0}
    c = {k: cues[:, j] for j, k in enumerate(ho.CUES)}
    gate = (0.25 + 0.75 * c["contrast"]) * (0.25 + 0.75 * c["solidity"])
    assert np.allclose(ranker.ranker_score(cues, only_grasp), gate * c["grasp"])
    w = np.array([ranker.RANKER_WEIGHTS[k] for k in ranker.FEATURES])
    assert np.allclose(ranker.ranker_score(cues), ranker.ranker_features(cues) @ w)


def test_stored_ranker_weights_keep_the_signs_of_their_reasons():
    from easyhoi.perception import ranker
    from tests.helpers import load_script

    fit = load_script("benchmarks/fit_ranker.py")
    assert ranker.RANKER_WEIGHTS["score"] == 1.0
    for k, v in ranker.RANKER_WEIGHTS.items():
        if k != "score":
            assert v * fit.SIGNS[k] >= 0.0, k


def _plain_solidities(mask, hand) -> tuple[float, float]:
    """Solidity and amodal solidity, each from its own hull of the mask's pixels."""
    vv, uu = np.nonzero(mask)
    if len(vv) < 3:
        return 0.0, 0.0
    hull = cv2.convexHull(np.stack([uu, vv], 1).astype(np.int32))
    hull_area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True)
    canvas = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(canvas, hull, 1)
    area = len(vv) + float((hand & canvas.astype(bool) & ~mask).sum())
    return float(min(1.0, len(vv) / max(1.0, hull_area))), float(
        min(1.0, area / max(1.0, hull_area))
    )


def test_solidities_from_one_pixel_hull_equal_the_plain_ones():
    """drawn_cues computes a mask's pixel hull once for both solidities: the same values as
    each computing its own."""
    rng = np.random.default_rng(3)
    hand = np.zeros((70, 90), bool)
    hand[20:50, 30:45] = True
    for i in range(30):
        m = np.zeros((70, 90), np.uint8)
        for _ in range(1 + i % 4):
            c = tuple(int(t) for t in rng.integers(5, 85, 2))
            cv2.ellipse(m, c, tuple(int(t) for t in rng.integers(1, 20, 2)), 0, 0, 360, 1, -1)
        m = m.astype(bool)
        if i == 0:
            m[:] = False
            m[3, 4] = m[5, 6] = True  # under 3 pixels: no hull
        hull = gc.pixel_hull(m)
        want = _plain_solidities(m, hand)
        assert (ho.solidity(m, hull), gc.amodal_solidity(m, hand, hull)) == want
        assert (ho.solidity(m), gc.amodal_solidity(m, hand)) == want
