"""Per-keypoint confidence of the MediaPipe detector: the spread of each keypoint over re-run
crops, against a plain computation, and on a real photo."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from easyhoi.perception import mediapipe_hand as mph  # noqa: E402
from easyhoi.perception.base import HandDetection  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _hand(w=200.0, h=160.0):
    """21 keypoints of an upright open hand in a w x h image."""
    rng = np.random.default_rng(3)
    kp = np.zeros((21, 2))
    kp[0] = (w / 2, h * 0.8)
    for f in range(5):
        base = np.array([w / 2 + (f - 2) * 12.0, h * 0.55])
        for j in range(4):
            kp[1 + 4 * f + j] = base + (0.0, -12.0 * j)
    return kp + rng.normal(0, 0.5, kp.shape)


def _fake_model(outputs):
    """A ``_run_roi`` that answers the calls in order with the given (21, 2) arrays (None: the
    model finds no hand), recording the ROIs it was asked for."""
    calls = []

    def run(image, roi):
        calls.append(roi)
        kp = outputs[len(calls) - 1]
        if kp is None:
            return None
        h, w = image.shape[:2]
        marks = [SimpleNamespace(x=x / w, y=y / h) for x, y in kp]
        return SimpleNamespace(landmarks=SimpleNamespace(landmark=marks))

    return run, calls


def test_spread_and_confidence_match_a_plain_computation(monkeypatch):
    image = np.zeros((160, 200, 3), np.uint8)
    kp = _hand()
    det = HandDetection(kp, None, "right", 1.0)
    rng = np.random.default_rng(0)
    n = len(mph.CONFIDENCE_CROPS)
    outputs = []
    for i in range(n):
        moved = kp.copy()
        moved[0] += rng.normal(0, 8.0, 2)  # the wrist wanders from crop to crop
        moved[8] += (0.0, 0.5 * i)  # the index tip drifts a little
        outputs.append(moved)
    outputs[2] = None  # one crop loses the hand
    run, calls = _fake_model(outputs)
    hands = mph.MediaPipeHands()
    monkeypatch.setattr(hands, "_run_roi", run)
    spread = hands.keypoint_spread(image, det)

    members = [kp] + [o for o in outputs if o is not None]
    size = float(np.ptp(kp, axis=0).max())
    expect = np.empty(21)
    for j in range(21):
        pts = np.array([m[j] for m in members])
        centre = np.array([np.median(pts[:, 0]), np.median(pts[:, 1])])
        expect[j] = np.median([math.dist(p, centre) for p in pts]) / size
    np.testing.assert_allclose(spread, expect, rtol=1e-9, atol=1e-12)
    assert spread[0] > 5 * spread[12] and spread[8] > spread[12]
    # one call per crop, each a perturbation of MediaPipe's own crop around the hand
    assert len(calls) == n
    x, y, rw, rh, rot = mph.roi_from_keypoints(kp, 200, 160)
    for (d_rot, scale, dx, dy), roi in zip(mph.CONFIDENCE_CROPS, calls, strict=True):
        expected = (x + dx * rw, y + dy * rh, rw * scale, rh * scale, rot + d_rot)
        np.testing.assert_allclose(roi, expected, rtol=1e-12)

    monkeypatch.setattr(hands, "_run_roi", _fake_model(outputs)[0])
    conf = hands.keypoint_confidence(image, det)
    np.testing.assert_allclose(conf, 1.0 / (1.0 + (expect / mph.SPREAD_SCALE) ** 2), rtol=1e-9)
    assert conf.argmin() == 0 and 0 < conf.min() < conf.max() <= 1


def test_no_spread_when_the_model_loses_the_hand(monkeypatch):
    image = np.zeros((160, 200, 3), np.uint8)
    kp = _hand()
    det = HandDetection(kp, None, "right", 1.0)
    n = len(mph.CONFIDENCE_CROPS)
    keep = mph.MIN_CONFIDENCE_CROPS - 1
    outputs = [kp.copy() if i < keep else None for i in range(n)]
    hands = mph.MediaPipeHands()
    monkeypatch.setattr(hands, "_run_roi", _fake_model(outputs)[0])
    assert hands.keypoint_confidence(image, det) is None
    outputs[keep] = kp.copy()  # one more crop finds it: measured, and all agree
    monkeypatch.setattr(hands, "_run_roi", _fake_model(outputs)[0])
    np.testing.assert_allclose(hands.keypoint_confidence(image, det), 1.0)
    # a detection without usable keypoints has no spread
    flat = HandDetection(np.zeros((21, 2)), None, "right", 1.0)
    assert hands.keypoint_spread(image, flat) is None


def test_confidence_on_a_photo(shared_data):
    from easyhoi.io.image import load_image

    image = load_image(shared_data / "images" / "hort-can.png").rgb
    hands = mph.MediaPipeHands()
    det = hands.detect(image)[0]
    conf = hands.keypoint_confidence(image, det)
    assert conf.shape == (21,) and np.isfinite(conf).all()
    assert (conf > 0).all() and (conf <= 1).all()
    # a clearly seen hand: most keypoints stay within the spread scale
    assert np.median(conf) > 0.5
    np.testing.assert_array_equal(conf, hands.keypoint_confidence(image, det))  # deterministic
    # no hand in the picture any more: the crops find nothing to measure
    grey = np.full_like(image, 128)
    assert hands.keypoint_confidence(grey, det) is None


def test_mirrored_look_maps_the_mirrored_hand_back(monkeypatch):
    """The hand found in the mirrored photo comes back with x -> W - x, its 3D x negated and
    its side swapped; the mirrored hand nearest the detection is taken, none beyond half the
    hand's size."""
    W = 200
    image = np.zeros((160, W, 3), np.uint8)
    kp = _hand()
    det = HandDetection(kp, None, "right", 1.0)
    k3 = np.random.default_rng(1).normal(0, 0.05, (21, 3))
    mirrored = kp.copy()
    mirrored[:, 0] = W - mirrored[:, 0]
    near = HandDetection(mirrored + 2.0, k3, "left", 0.8, meta={"pass": "palm"})
    far = HandDetection(mirrored + 60.0, None, "right", 0.9, meta={"pass": "palm"})
    hands = mph.MediaPipeHands(roi_search=False)
    got = []

    def palm(img):
        got.append(img.copy())
        return [far, near]

    monkeypatch.setattr(hands, "_palm_pass", palm)
    monkeypatch.setattr(hands, "keypoint_confidence", lambda img, d: np.full(21, 0.7))
    image[:, :50] = 255  # the detector is shown the photo mirrored
    back, conf = hands.mirrored_look(image, det)
    assert (got[0][:, -50:] == 255).all() and (got[0][:, :-50] == 0).all()
    want = mirrored + 2.0
    want[:, 0] = W - want[:, 0]
    np.testing.assert_allclose(back.keypoints2d, want)
    np.testing.assert_allclose(back.keypoints3d, k3 * [-1, 1, 1])
    assert back.side == "right" and back.meta["pass"] == "mirrored palm"
    np.testing.assert_allclose(conf, 0.7)
    monkeypatch.setattr(hands, "_palm_pass", lambda img: [far])
    assert hands.mirrored_look(image, det) is None


def test_a_hand_the_palm_pass_misses_is_found_in_the_mirrored_photo(monkeypatch):
    """Fewer hands than ``max_hands``: the palm pipeline runs on the mirrored photo too, and
    what it finds that the first run did not is added, mapped back."""
    W = 200
    image = np.zeros((160, W, 3), np.uint8)
    image[:, :50] = 255
    a = HandDetection(_hand(), None, "right", 0.9, meta={"pass": "palm"})
    b_kp = _hand() + (60.0, 0.0)  # a second hand, 60 px to the right
    mirror = lambda k: np.column_stack([W - k[:, 0], k[:, 1]])  # noqa: E731
    a_again = HandDetection(mirror(a.keypoints2d) + 1.0, None, "left", 0.95, meta={"pass": "palm"})
    b_m = HandDetection(mirror(b_kp), None, "right", 0.7, meta={"pass": "palm"})
    calls = []

    def palm(img):
        calls.append(bool((img[:, -50:] == 255).all()))  # True: the mirrored photo
        return [a] if not calls[-1] else [a_again, b_m]

    hands = mph.MediaPipeHands(roi_search=False)
    monkeypatch.setattr(hands, "_palm_pass", palm)
    out = hands.detect(image)
    assert calls == [False, True]
    assert len(out) == 2 and out[0] is a  # the first run's hand, then the new one
    np.testing.assert_allclose(out[1].keypoints2d, b_kp)
    assert out[1].side == "left" and out[1].meta["pass"] == "mirrored palm"
    # two hands found already (max_hands): no mirrored run
    calls.clear()
    monkeypatch.setattr(hands, "_palm_pass", lambda img: calls.append(1) or [a, b_m])
    assert len(hands.detect(image)) == 2 and calls == [1]
    # switched off: the first run alone
    calls.clear()
    off = mph.MediaPipeHands(roi_search=False, mirror_pass=False)
    monkeypatch.setattr(off, "_palm_pass", palm)
    assert off.detect(image) == [a] and calls == [False]


def test_mirrored_look_steadies_a_swapped_skeleton(shared_data):
    """The photo where the detector swaps the thumb and the fingers (median confidence 0.2): in
    the mirrored photo it finds the hand with the thumb on its side, and is sure of it."""
    import json

    from easyhoi.io.image import load_image
    from easyhoi.perception.chain import second_look

    ref = json.loads((ROOT / "tests/data/keypoint_refs/ihoi-demo_07.json").read_text())
    truth = np.array(ref["keypoints"], float)[:, :2]
    image = load_image(shared_data / ref["image"]).rgb
    hands = mph.MediaPipeHands()
    det = min(
        hands.detect(image), key=lambda d: np.linalg.norm(d.keypoints2d - truth, axis=1).mean()
    )
    conf = hands.keypoint_confidence(image, det)
    err = np.linalg.norm(det.keypoints2d - truth, axis=1).mean()
    look = second_look(hands, image, det, conf)
    assert np.median(conf) < 0.5 and look is not None
    back, look_conf = look
    err_back = np.linalg.norm(back.keypoints2d - truth, axis=1).mean()
    assert np.median(look_conf) > 0.8 and err_back < 0.6 * err
    # the thumb's tip ends on the side of the hand where the reference has it
    assert np.linalg.norm(back.keypoints2d[4] - truth[4]) < 0.5 * np.linalg.norm(
        det.keypoints2d[4] - truth[4]
    )
