"""The ROI search finds a hand at any angle and at any size in the frame: the upside-down photo
and the photo cut to the hand give the keypoints of the photo as taken."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from easyhoi.io.image import load_image  # noqa: E402
from easyhoi.perception import mediapipe_hand as mph  # noqa: E402


def test_roi_windows_cover_every_quarter_turn():
    turns = sorted(round(r / (np.pi / 2)) % 4 for r in mph._ROI_ROTATIONS)
    assert turns == [0, 1, 2, 3]


@pytest.fixture(scope="module")
def controller():
    """The grey-scale controller photo, the detector and its upright detection: the palm
    detector misses this hand, only the ROI search finds it."""
    from tests.conftest import SHARED_DATA

    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data not found at {SHARED_DATA}")
    rgb = load_image(SHARED_DATA / "images" / "easyhoi-game-controller.jpg").rgb
    detector = mph.MediaPipeHands(mirror_pass=False)
    upright = detector.detect(rgb)
    assert upright and upright[0].meta["pass"] == "roi_search"
    return rgb, detector, upright[0].keypoints2d


def _assert_same_skeleton(found, ref):
    """``found`` (21, 2) lies on ``ref``: median within 3 %, every keypoint within 15 % of the
    hand's size."""
    size = float(np.ptp(ref, axis=0).max())
    err = np.linalg.norm(found - ref, axis=1)
    assert np.median(err) < 0.03 * size and err.max() < 0.15 * size, (err, size)


def test_upside_down_hand_found_by_roi_search(controller):
    rgb, detector, ref = controller
    h, w = rgb.shape[:2]
    turned = detector.detect(np.ascontiguousarray(rgb[::-1, ::-1]))
    assert turned and turned[0].meta["pass"] == "roi_search"
    # the turned keypoints mapped back onto the upright photo (pixel centres at half-integers,
    # as ``mph.unmirror`` maps x; with the upright and both sideways windows alone the ROI search
    # finds a skeleton 6 % of the hand off at the median and 48 % at the worst keypoint)
    _assert_same_skeleton(np.array([w, h]) - turned[0].keypoints2d, ref)


def test_hand_filling_the_frame_found_by_roi_search(controller):
    rgb, detector, ref = controller
    # the photo cut to the hand's keypoints, grown by a fifth: the hand fills the frame, and no
    # window smaller than the whole photo contains it (the two smaller sizes alone find nothing)
    lo, hi = ref.min(0), ref.max(0)
    c, half = (lo + hi) / 2, 0.6 * (hi - lo)
    x0, y0 = np.maximum(0, np.floor(c - half)).astype(int)
    x1, y1 = np.minimum([rgb.shape[1], rgb.shape[0]], np.ceil(c + half)).astype(int)
    found = detector.detect(np.ascontiguousarray(rgb[y0:y1, x0:x1]))
    assert found and found[0].meta["pass"] == "roi_search"
    _assert_same_skeleton(found[0].keypoints2d + [x0, y0], ref)
