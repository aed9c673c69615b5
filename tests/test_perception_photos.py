"""The offline perception chain on the 9 shared photos (slow; outcomes asserted, timing not).

Achieved with the default backends: a hand on all 9 photos; the held object found with IoU >= 0.5
against the hand-drawn reference masks (``tests/data/perception_refs``) on the airplane, the game
controller, the can and the phone, automatically and with one click on the object.
"""

from __future__ import annotations

import numpy as np
import pytest

from easyhoi.io.image import load_image
from tests.helpers import load_script

pytestmark = pytest.mark.slow


def _chain_module():
    return load_script("scripts/perception_contact_sheet.py")


@pytest.fixture(scope="module")
def results():
    from tests.conftest import SHARED_DATA

    if not SHARED_DATA.is_dir():
        pytest.skip("shared photos not available")
    from easyhoi.perception.amodal import ClassicalAmodalSegmenter
    from easyhoi.perception.inpaint import OpenCVInpainter
    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.mediapipe_hand import MediaPipeHands

    chain = _chain_module()
    parts = (
        MediaPipeHands(),
        ClassicalHOISegmenter(),
        OpenCVInpainter(),
        ClassicalAmodalSegmenter(),
    )
    out = {}
    for f in sorted((SHARED_DATA / "images").iterdir()):
        rgb = load_image(f).rgb
        out[f.name] = (rgb, chain.run_chain(rgb, *parts))
    return out


def test_a_hand_is_found_on_every_photo(results):
    assert len(results) == 9
    for name, (rgb, res) in results.items():
        assert res["hands"], name
        for h in res["hands"]:
            assert h.keypoints2d.shape == (21, 2) and h.keypoints3d.shape == (21, 3)
            assert h.side in ("left", "right") and 0 < h.score <= 1
            lo, hi = h.keypoints2d.min(0), h.keypoints2d.max(0)
            assert lo.min() > -0.2 * max(rgb.shape) and hi[0] < 1.2 * rgb.shape[1], name


def test_handedness_is_unmirrored(results):
    # the reusable cup is held by a left hand, the paper cup and the soda can by right hands
    assert results["easyhoi-coffee-2.jpg"][1]["hands"][0].side == "left"
    assert results["easyhoi-coffee-1.png"][1]["hands"][0].side == "right"
    assert results["hort-can.png"][1]["hands"][0].side == "right"


def test_world_landmarks_are_camera_aligned(results):
    """x right / y down: the 3D points' xy fit the 2D keypoints by a positive scale + shift."""
    checked = 0
    for name, (_, res) in results.items():
        for h in res["hands"]:
            if h.meta["pass"] != "palm":
                continue
            p3 = h.keypoints3d[:, :2] - h.keypoints3d[:, :2].mean(0)
            p2 = h.keypoints2d - h.keypoints2d.mean(0)
            s = float((p3 * p2).sum() / (p3 * p3).sum())
            resid = np.linalg.norm(p2 - s * p3) / np.linalg.norm(p2)
            assert s > 0 and resid < 0.5, (name, s, resid)
            # z grows away from the camera, as MediaPipe's relative image depth does
            z_img = np.asarray(h.meta["relative_z"])
            assert np.corrcoef(z_img, h.keypoints3d[:, 2])[0, 1] > 0.2, name
            checked += 1
    assert checked >= 6


#: Photos whose held object the automatic segmenter finds (IoU >= 0.5 with the reference).
FOUND = ("easyhoi-airplane.jpg", "easyhoi-game-controller.jpg", "hort-can.png", "hort-phone.png")


def _reference(name: str):
    from tests import perception_refs as pr

    try:
        ref = pr.load_ref(f"images__{name.rsplit('.', 1)[0]}")
    except FileNotFoundError:
        pytest.skip(f"no reference outline for {name}")
    return pr.held_object_mask(ref), pr.object_point(ref), pr.mask_iou


@pytest.mark.parametrize("name", FOUND)
def test_held_object_matches_the_reference(results, name):
    from easyhoi.perception.chain import segment_hands
    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.prompts import Prompts

    ref, point, mask_iou = _reference(name)
    rgb, res = results[name]
    if ref.shape != rgb.shape[:2]:
        pytest.skip("photo resampled by the loader")
    segmenter = ClassicalHOISegmenter()
    _, seg, _, _ = segment_hands(rgb, res["hands"], segmenter)
    assert seg is not None and seg.has_object, name
    assert mask_iou(seg.object_mask, ref) >= 0.5, name
    assert not (seg.object_mask & seg.hand_mask).any()
    _, seg1, _, _ = segment_hands(rgb, res["hands"], segmenter, Prompts(object_points=(point,)))
    assert mask_iou(seg1.object_mask, ref) >= 0.5, name


def test_pinched_cardboard_airplane_is_a_thin_slab():
    """The whole chain on the cardboard airplane: the thumb and the index finger pinch it front
    to back, so the object is a slab as thin as the pinch (not an inflated pillow)."""
    from tests.conftest import SHARED_DATA

    photo = SHARED_DATA / "images" / "easyhoi-airplane.jpg"
    if not photo.is_file():
        pytest.skip("shared photos not available")
    from easyhoi.perception.chain import perceive

    inp, _ = perceive(load_image(photo).rgb)
    shape = inp.meta["object_shape"]
    assert shape["shape"] == "slab" and shape["flat_by_grip"]
    assert shape["depth_cue_from"] == "pinch"
    md = inp.object_mesh.metadata["easyhoi"]
    thickness_m = float(np.sort(inp.object_mesh.extents)[0]) * md["meters_per_unit"]
    assert 0.002 < thickness_m < 0.015
