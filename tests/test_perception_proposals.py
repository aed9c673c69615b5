"""Region proposals of the automatic path: base segments, grouping, pooled scales, cue sums.

Each function is checked against a naive reference written here (a per-pixel or per-region loop)
or on drawn images with a known answer.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from easyhoi.perception import held_object as ho
from easyhoi.perception import proposals as pp
from easyhoi.perception.skin import SKIN_D2
from tests.test_perception_held_object import S, canvas, det, finish, scene_cues
from tests.test_perception_masks import BLUE, KP, iou


def _lab(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)


def _naive_group(labels: np.ndarray, lab: np.ndarray, max_size: float | None = None):
    """Selective-search grouping written plainly: scan every pair for the most similar merge."""
    n = int(labels.max()) + 1
    total = float((labels >= 0).sum())
    hist = list(pp._histograms(lab, labels, n))
    size = [float((labels == i).sum()) for i in range(n)]
    box = []
    for i in range(n):
        yy, xx = np.nonzero(labels == i)
        box.append((xx.min(), yy.min(), xx.max(), yy.max()))
    regions = [frozenset((i,)) for i in range(n)]
    neigh = {i: set() for i in range(n)}
    for a, b in pp.adjacency(pp.fill_excluded(labels)):
        neigh[a].add(b)
        neigh[b].add(a)

    def sim(a, b):
        colour = float(np.minimum(hist[a], hist[b]).sum()) / 3.0
        small = 1.0 - (size[a] + size[b]) / total
        bw = max(box[a][2], box[b][2]) - min(box[a][0], box[b][0]) + 1
        bh = max(box[a][3], box[b][3]) - min(box[a][1], box[b][1]) + 1
        fill = 1.0 - (bw * bh - size[a] - size[b]) / total
        return colour + small + fill

    pairs = {(a, b): sim(a, b) for a in neigh for b in neigh[a] if a < b}
    while pairs:
        (a, b), _ = max(pairs.items(), key=lambda kv: (kv[1], -kv[0][0], -kv[0][1]))
        del pairs[(a, b)]
        if max_size is not None and size[a] + size[b] > max_size:
            continue
        new = len(regions)
        regions.append(regions[a] | regions[b])
        hist.append((hist[a] * size[a] + hist[b] * size[b]) / (size[a] + size[b]))
        size.append(size[a] + size[b])
        box.append(tuple(f(box[a][k], box[b][k]) for k, f in enumerate((min, min, max, max))))
        nb = (neigh[a] | neigh[b]) - {a, b}
        for k in (a, b):
            for j in neigh.pop(k):
                pairs.pop((min(j, k), max(j, k)), None)
                if j in neigh:
                    neigh[j].discard(k)
        neigh[new] = nb
        for j in nb:
            neigh[j].add(new)
            pairs[(j, new)] = sim(j, new)
    return tuple(regions)


def _photo_like(seed: int) -> np.ndarray:
    """Smoothed coloured noise: many segments of irregular shapes."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (12, 12, 3)).astype(np.uint8)
    img = cv2.resize(small, (96, 96), interpolation=cv2.INTER_NEAREST).astype(np.float64)
    return np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [0, 1])
def test_heap_grouping_equals_the_naive_grouping(seed):
    img = _photo_like(seed)
    exclude = np.zeros(img.shape[:2], bool)
    exclude[40:56, 10:80] = True  # a "finger" across the picture
    labels = pp.base_segments(img, exclude, 100, 10)
    assert labels.max() > 20
    for max_size in (None, 1500.0):
        regions, sizes = pp.group(labels, _lab(img), max_size)
        assert regions == _naive_group(labels, _lab(img), max_size)
        assert sizes.sum() == (~exclude).sum()


@pytest.mark.parametrize("use_opencv", [True, False])
def test_base_segments_are_connected_pieces_outside_the_exclusion(use_opencv, monkeypatch):
    if not use_opencv:
        monkeypatch.delattr(cv2, "ximgproc", raising=False)
    elif not hasattr(cv2, "ximgproc"):
        pytest.skip("OpenCV without ximgproc")
    img = _photo_like(3)
    exclude = np.zeros(img.shape[:2], bool)
    exclude[:, 45:50] = True
    labels = pp.base_segments(img, exclude, 150, 10)
    assert (labels[exclude] == -1).all() and (labels[~exclude] >= 0).all()
    n = int(labels.max()) + 1
    assert set(np.unique(labels[labels >= 0])) == set(range(n))  # numbered 0..n-1
    for i in range(n):  # every label is one 4-connected piece, never across the exclusion
        k, _ = cv2.connectedComponents((labels == i).astype(np.uint8), connectivity=4)
        assert k == 2
    assert not set(np.unique(labels[:, :45])) & set(np.unique(labels[:, 50:])) - {-1}


def test_overlay_is_the_common_refinement():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 4, (30, 30))
    b = rng.integers(0, 3, (30, 30))
    a[:5] = b[:5] = -1
    labels, (pa, pb) = pp.overlay([a, b])
    assert (labels[:5] == -1).all()
    # naive: one piece per distinct (a, b) pair
    pairs = sorted({(int(x), int(y)) for x, y in zip(a[5:].ravel(), b[5:].ravel(), strict=True)})
    assert labels.max() + 1 == len(pairs)
    for piece in range(labels.max() + 1):
        m = labels == piece
        assert (a[m] == pa[piece]).all() and (b[m] == pb[piece]).all()


def test_membership_cue_sums_equal_per_region_masks():
    """The sparse per-hypothesis sums equal the cues measured on each drawn mask."""
    img = canvas()
    yy, xx = np.mgrid[0:S, 0:S]
    img[(xx - 88) ** 2 + (yy - 128) ** 2 < 22**2] = BLUE
    img[200:, :] = (90, 90, 90)
    img, hand = finish(img)
    scene = scene_cues(img, hand)
    props = pp.propose_scales(img, _lab(img), hand, (100.0, 400.0), 20)
    cues = ho.describe(props, scene)
    L = scene.palm
    fd = ho.finger_distances(hand.shape, KP)
    hand_dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
    rng = np.random.default_rng(0)
    for i in rng.choice(len(props.regions), 25, replace=False):
        m = props.mask(props.regions[i])
        touch = fd[:, m].min(1) <= ho.TOUCH * L
        ring = np.zeros_like(m)
        ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = True
        want = {
            "fingers": touch.sum(),
            "thumb": float(touch[0]),
            "skin": (scene.skin_d2[m] < SKIN_D2).mean(),
            "border": (m & ring).sum() / L,
            "area": m.sum() / scene.hand_area,
            "far": (hand_dist[m] > 2 * L).mean(),
        }
        for k, v in want.items():
            assert cues[i, ho.CUES.index(k)] == pytest.approx(v, abs=1e-9), k


def test_pooled_scales_hold_every_hypothesis_of_each_scale_once():
    """The pool is the union of the single-scale hierarchies (the same pixel sets), without
    duplicates, and finds a small object in the grasp and a textured one beside it."""
    rng = np.random.default_rng(1)
    img = canvas()
    yy, xx = np.mgrid[0:S, 0:S]
    small = (np.abs(xx - 88) < 5) & (np.abs(yy - 128) < 16)  # a short stick in the grasp
    img[small] = (170, 175, 185)  # close to the grey background
    tex = (xx > 150) & (xx < 225) & (yy > 150) & (yy < 225)
    img[tex] = (40, 90, 160)
    img[((xx // 6 + yy // 6) % 2 == 0) & tex] = (230, 200, 40)  # a checker pattern
    img, hand = finish(img + rng.normal(0, 2, img.shape))
    lab = _lab(img)
    scales = (100.0, 600.0)
    pooled = pp.propose_scales(img, lab, hand, scales, 8)
    assert len(set(pooled.regions)) == len(pooled.regions)
    pooled_masks = {np.packbits(pooled.mask(r)).tobytes() for r in pooled.regions}
    assert len(pooled_masks) == len(pooled.regions)
    n_single = 0
    for sc in scales:
        single = pp.propose(img, lab, hand, sc, 8)
        masks = {np.packbits(single.mask(r)).tobytes() for r in single.regions}
        assert masks <= pooled_masks
        n_single += len(masks)
    assert len(pooled_masks) < n_single  # the single segments shared by both appear once
    for obj in (small, tex):
        assert max(iou(pooled.mask(r), obj) for r in pooled.regions) > 0.8


def test_the_automatic_path_finds_the_grasped_object_with_pooled_proposals():
    from easyhoi.perception.masks import ClassicalHOISegmenter

    yy, xx = np.mgrid[0:S, 0:S]
    disk = (xx - 88) ** 2 + (yy - 128) ** 2 < 22**2
    img = canvas()
    img[disk] = BLUE
    img, hand = finish(img)
    seg = ClassicalHOISegmenter(seed=0)
    out = seg.segment(img, det())
    assert out.has_object and iou(out.object_mask, disk & ~out.hand_mask) > 0.8
    crop, props = seg.automatic_hypotheses(img, det())
    assert crop[2] > crop[0] and crop[3] > crop[1] and len(props.regions) > props.n_base / 2


@pytest.mark.slow
def test_dev_photos_best_hypothesis_and_automatic_choice():
    """On the 39 development photos (shared data; skipped without it): the best automatic
    hypothesis reaches IoU >= 0.5 with the hand-drawn held object on at least 60 % of the photos
    with an object (68 % measured), the automatic choice on at least 28 % (32 % measured), and
    the photo where nothing is held gets a low object confidence."""
    from pathlib import Path

    from tests.conftest import SHARED_DATA
    from tests.helpers import load_script

    if not SHARED_DATA.is_dir():
        pytest.skip("shared photos not available")
    from easyhoi.io.image import load_image
    from easyhoi.perception.chain import segment_hands
    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.mediapipe_hand import MediaPipeHands

    bench = load_script("benchmarks/bench_perception.py")
    detector, seg = MediaPipeHands(), ClassicalHOISegmenter()
    best, chosen, nothing_held = [], [], []
    for f in sorted((Path(__file__).parent / "data" / "perception_refs").glob("*.json")):
        ref = bench.reference(f)
        rgb = load_image(SHARED_DATA / ref["image"]).rgb
        ref = bench.fit_to(ref, rgb.shape[:2])
        hands = detector.detect(rgb)
        _, out, _, _ = segment_hands(rgb, hands, seg) if hands else (None, None, [], None)
        if ref["object"] is None:
            conf = out.confidence["object"] if out is not None else None
            nothing_held.append(conf is None or conf.low)
            continue
        chosen.append(bench.iou(out.object_mask if out is not None else None, ref["object"]))
        best.append(bench.best_hypothesis_iou(rgb, hands, seg, ref["object"]))
    assert len(best) == 38 and nothing_held == [True]
    assert np.mean(np.array(best) >= 0.5) >= 0.6
    assert np.mean(np.array(chosen) >= 0.5) >= 0.28


def test_segment_minima_equal_scipy_minimum():
    """Per-segment minima of several maps, pixels labelled -1 or beyond the segments ignored, a
    segment without pixels 0: the values of scipy.ndimage.minimum on each map."""
    from scipy.ndimage import minimum

    rng = np.random.default_rng(5)
    for n, shape in ((1, (9, 7)), (40, (60, 80)), (300, (120, 90))):
        labels = rng.integers(-1, n + 3, shape)  # labels n.. are not segments: ignored
        labels[labels == n // 2] = -1  # a segment without pixels
        values = (rng.random((5, *shape)) * 50).astype(np.float32)
        values[:, ::7] = np.round(values[:, ::7])  # ties
        got = pp.segment_minima(labels, values, n)
        assert got.dtype == np.float32
        for v, row in zip(values, got, strict=True):
            np.testing.assert_array_equal(row, minimum(v, labels + 1, np.arange(1, n + 1)))
        assert (got[:, n // 2] == 0).all()
