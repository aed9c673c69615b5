"""The reference 2D hand keypoints: format, and agreement with the perception references."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tests.keypoint_refs import (
    FINGERS,
    KEYPOINT_NAMES,
    keypoint_ref_keys,
    load_keypoint_ref,
    load_keypoint_refs,
    parse_keypoint_ref,
)
from tests.perception_refs import load_ref, rasterize

KEYS = keypoint_ref_keys()


def _side_mask(key: str, side: str):
    ref = load_ref(f"photos-dev__{key}")
    polys = [p for h in ref.hands if h.side == side for p in h.polygons]
    return ref, rasterize(polys, ref.height, ref.width)


def test_keypoint_order_is_openpose():
    assert len(KEYPOINT_NAMES) == 21
    assert KEYPOINT_NAMES[:5] == ("wrist", "thumb1", "thumb2", "thumb3", "thumb4")
    assert FINGERS["index"] == (5, 6, 7, 8) and FINGERS["little"] == (17, 18, 19, 20)


def test_parse_rejects_bad_keypoints():
    good = {"image": "x.png", "hand_side": "left", "keypoints": [[1.0, 2.0, 1]] * 21}
    assert parse_keypoint_ref(good, "ok").xy.shape == (21, 2)
    for bad in (
        {**good, "hand_side": "both"},
        {**good, "keypoints": [[1.0, 2.0, 1]] * 20},
        {**good, "keypoints": [[1.0, 2.0, 2]] * 21},
    ):
        with pytest.raises(ValueError):
            parse_keypoint_ref(json.loads(json.dumps(bad)), "bad")


def test_there_are_keypoint_references():
    assert len(KEYS) >= 4
    assert [r.key for r in load_keypoint_refs()] == KEYS


@pytest.mark.parametrize("key", KEYS)
def test_keypoints_agree_with_the_hand_outline(key):
    kp = load_keypoint_ref(key)
    assert kp.image.startswith("photos-dev/") and kp.image.rsplit(".", 1)[0].endswith(key)
    ref, mask = _side_mask(key, kp.hand_side)
    assert mask.any(), f"{key}: the perception reference has no {kp.hand_side} hand"
    xy = kp.xy
    assert (xy[:, 0] >= 0).all() and (xy[:, 0] <= ref.width - 1).all()
    assert (xy[:, 1] >= 0).all() and (xy[:, 1] <= ref.height - 1).all()
    assert kp.visible.sum() >= 8
    assert kp.visible[[4, 8, 12, 16, 20]].any(), "at least one fingertip is visible"
    for chain in FINGERS.values():
        pts = xy[[0, *chain]]
        assert (np.linalg.norm(np.diff(pts, axis=0), axis=1) > 0.5).all(), key
    # Every visible keypoint lies on the independently drawn hand outline, up to the blur of
    # the outline: 5% of the hand's size (at least 4 px).
    ys, xs = np.nonzero(mask)
    tol = max(4.0, 0.05 * float(np.hypot(np.ptp(xs), np.ptp(ys))))
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
    for i in np.flatnonzero(kp.visible):
        x, y = np.round(xy[i]).astype(int)
        assert outside[y, x] <= tol, f"{key}: {KEYPOINT_NAMES[i]} is {outside[y, x]:.1f} px off"


@pytest.mark.parametrize("key", KEYS)
def test_keypoint_photo_exists(key, shared_data):
    kp = load_keypoint_ref(key)
    assert (shared_data / kp.image).is_file()
