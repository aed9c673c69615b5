"""The offline perception chain on the 9 shared photos (slow; counts asserted, timing not).

Achieved with the default backends: a hand on all 9 photos; a held-object mask on the 6 photos
with a compact object (airplane, both coffee cups, game controller, can, phone) and none on the
gloved hand with shears and on the trumpet; no held object for any hand of the no-object photo.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from easyhoi.io.image import load_image

pytestmark = pytest.mark.slow

NO_OBJECT = "hamer-no-object.jpg"
HELD = (
    "easyhoi-airplane.jpg",
    "easyhoi-coffee-1.png",
    "easyhoi-coffee-2.jpg",
    "easyhoi-game-controller.jpg",
    "hort-can.png",
    "hort-phone.png",
)


def _chain_module():
    path = Path(__file__).resolve().parents[1] / "scripts" / "perception_contact_sheet.py"
    spec = importlib.util.spec_from_file_location("perception_contact_sheet", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


def test_held_objects_found_on_most_photos(results):
    found = [n for n, (_, r) in results.items() if n != NO_OBJECT and r["seg"].has_object]
    assert len(found) >= 6, found
    for name in found:
        rgb, res = results[name]
        seg = res["seg"]
        assert not (seg.object_mask & seg.hand_mask).any()
        assert (res["amodal"] | ~seg.object_mask).all()  # amodal contains the visible mask
        assert 0.001 < seg.object_mask.mean() < 0.6, name
    assert set(HELD) <= set(found), found
    for name in HELD:
        comps = results[name][1]["seg"].meta["components"]
        assert any(c["rejected"] is None for c in comps), name


def test_no_hand_of_the_no_object_photo_holds_an_object(results):
    """The face, shirt and arm touching the hands are rejected by the held-object cues."""
    from easyhoi.perception.masks import ClassicalHOISegmenter

    rgb, res = results[NO_OBJECT]
    assert len(res["hands"]) == 2
    segmenter = ClassicalHOISegmenter()
    big = []
    for hand in res["hands"]:
        seg = segmenter.segment(rgb, hand)
        assert not seg.has_object and not seg.object_mask.any()
        big += [c for c in seg.meta["components"] if c["area_ratio"] >= segmenter.min_object_area]
    # the face and the shirt are large touching regions; each is rejected by a cue
    assert len(big) >= 2 and all(c["rejected"] for c in big), big


def test_perceive_raises_no_object_on_the_no_object_photo(results):
    from easyhoi.errors import NoObjectError
    from easyhoi.perception.chain import perceive

    with pytest.raises(NoObjectError):
        perceive(results[NO_OBJECT][0])
