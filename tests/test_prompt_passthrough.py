"""Prompts through the perception chain: the hand point picks the hand, object prompts reach a
segmenter that takes them, and a segmenter that does not is refused by name."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from easyhoi.config import EasyHOIConfig
from easyhoi.errors import InvalidInputError, NoObjectError
from easyhoi.perception import base
from easyhoi.perception.base import HandDetection, Segmentation
from easyhoi.perception.chain import nearest_hand, perceive
from easyhoi.perception.prompts import Prompts

IMAGE = np.zeros((100, 200, 3), np.uint8)


def hand_at(u: float, v: float, side: str) -> HandDetection:
    """21 keypoints on a 20 px circle around (u, v)."""
    a = np.linspace(0, 2 * np.pi, 21)
    k = np.stack([u + 20 * np.cos(a), v + 20 * np.sin(a)], 1)
    return HandDetection(k, None, side, 0.9)


class TwoHands:
    def detect(self, image):
        return [hand_at(40, 50, "left"), hand_at(160, 50, "right")]


class Recording:
    """A segmenter that records its calls and finds no object (so perceive stops there)."""

    calls: list = []

    def segment(self, image, hand, prompts=None):
        Recording.calls.append((hand.side, prompts))
        m = np.zeros(image.shape[:2], bool)
        return Segmentation(m, m, False)


class Unprompted:
    def segment(self, image, hand):
        m = np.zeros(image.shape[:2], bool)
        return Segmentation(m, m, False)


@pytest.fixture
def config(monkeypatch):
    monkeypatch.setitem(base._REGISTRY["hand"], "two-hands", TwoHands)
    monkeypatch.setitem(base._REGISTRY["segmenter"], "recording", Recording)
    monkeypatch.setitem(base._REGISTRY["segmenter"], "unprompted", Unprompted)
    Recording.calls = []
    cfg = EasyHOIConfig()
    return replace(cfg, perception=replace(cfg.perception, hand="two-hands",
                                           segmenter="recording"))  # fmt: skip


def test_nearest_hand():
    hands = TwoHands().detect(IMAGE)
    assert nearest_hand(hands, (10, 90)) == 0
    assert nearest_hand(hands, (125, 5)) == 1
    assert nearest_hand(hands, (100, 50)) in (0, 1)


def test_without_prompts_every_hand_is_tried_in_order(config):
    with pytest.raises(NoObjectError, match="found 2 hand"):
        perceive(IMAGE, config)
    assert Recording.calls == [("left", None), ("right", None)]


def test_hand_point_segments_only_the_pointed_hand(config):
    with pytest.raises(NoObjectError, match=r"nearest the hand point \(hand 1, right\)"):
        perceive(IMAGE, config, prompts=Prompts(hand_point=(150.0, 80.0)))
    assert Recording.calls == [("right", None)]  # no object prompt: the segmenter gets none


def test_object_prompts_reach_the_segmenter_of_the_nearest_hand(config):
    prompts = Prompts(object_points=((30.0, 40.0), (70.0, 40.0)), object_box=(150, 10, 199, 90))
    # the user says an object is there: the error says nothing was found where they pointed
    with pytest.raises(NoObjectError, match=r"at the object prompt \(for hand 0, left\)"):
        perceive(IMAGE, config, prompts=prompts)
    assert Recording.calls == [("left", prompts)]  # the points' mean (50, 40) is at the left hand
    Recording.calls = []
    boxed = Prompts(object_box=(150.0, 10.0, 199.0, 90.0))  # centre (174.5, 50): right hand
    with pytest.raises(NoObjectError, match=r"hand 1, right"):
        perceive(IMAGE, config, prompts=boxed)
    assert Recording.calls == [("right", boxed)]


def test_prompts_outside_the_image_and_unprompted_segmenters_are_refused(config):
    with pytest.raises(InvalidInputError, match="outside the 200x100 photo"):
        perceive(IMAGE, config, prompts=Prompts(object_points=((250.0, 10.0),)))
    unprompted = replace(config, perception=replace(config.perception, segmenter="unprompted"))
    with pytest.raises(InvalidInputError, match="segmenter 'unprompted' takes no object prompts"):
        perceive(IMAGE, unprompted, prompts=Prompts(object_points=((25.0, 10.0),)))
    # a hand point needs nothing from the segmenter
    with pytest.raises(NoObjectError):
        perceive(IMAGE, unprompted, prompts=Prompts(hand_point=(25.0, 10.0)))
    assert Recording.calls == []


def right_hand_holds(confidence=None):
    """A segmenter class whose right hand holds an object (box at x 120-170, the hand beside
    it), reporting ``confidence`` (mask name -> MaskConfidence) when given."""

    class Rated:
        def segment(self, image, hand, prompts=None):
            obj = np.zeros(image.shape[:2], bool)
            obj[30:70, 120:170] = True
            hand_mask = np.zeros_like(obj)
            hand_mask[30:70, 140:180] = True
            hand_mask &= ~obj
            return Segmentation(hand_mask, obj, hand.side == "right",
                                confidence=dict(confidence or {}))  # fmt: skip

    return Rated


def test_the_segmenters_confidence_reaches_the_report(config, monkeypatch):
    from easyhoi.perception.confidence import MaskConfidence

    conf = {"hand": MaskConfidence(0.8), "object": MaskConfidence(0.3, ("faint edge",))}
    monkeypatch.setitem(base._REGISTRY["segmenter"], "rated", right_hand_holds(conf))
    rated = replace(config, perception=replace(config.perception, segmenter="rated"))
    img = np.random.default_rng(0).integers(0, 255, (100, 200, 3), dtype=np.uint8)
    inp, report = perceive(img, rated)
    assert report.hand_index == 1 and report.side == "right"
    assert report.low_confidence == ["object"]
    assert inp.meta["perception"]["confidence"]["object"] == {
        "score": 0.3, "low": True, "reasons": ["faint edge"]
    }  # fmt: skip
    assert inp.meta["perception"]["notes"][0] == "hand 0 (left) holds no object"
    # an imported object mask replaces the segmenter's object mask and its confidence
    from easyhoi.perception.chain import Provided

    given = np.zeros((100, 200), bool)
    given[40:60, 130:160] = True
    _, report = perceive(img, rated, provided=Provided(object_mask=given))
    assert set(report.confidence) == {"hand"}


def test_the_detectors_keypoint_confidence_reaches_the_input(config, monkeypatch):
    class SureOfSome(TwoHands):
        asked: list = []

        def keypoint_confidence(self, image, hand):
            SureOfSome.asked.append(float(hand.keypoints2d[:, 0].mean()))
            return np.linspace(0.05, 1.0, 21)

    monkeypatch.setitem(base._REGISTRY["segmenter"], "rated", right_hand_holds())
    monkeypatch.setitem(base._REGISTRY["hand"], "sure-of-some", SureOfSome)
    rated = replace(config, perception=replace(config.perception, segmenter="rated"))
    img = np.random.default_rng(0).integers(0, 255, (100, 200, 3), dtype=np.uint8)
    inp, _ = perceive(img, rated)  # TwoHands: no confidence measure
    assert "keypoints2d_confidence" not in inp.meta
    sure = replace(rated, perception=replace(rated.perception, hand="sure-of-some"))
    inp, report = perceive(img, sure)
    # asked once, for the chosen hand (the right one, at u = 160)
    assert SureOfSome.asked == [pytest.approx(160.0, abs=2.0)]
    np.testing.assert_allclose(inp.meta["keypoints2d_confidence"], np.linspace(0.05, 1.0, 21))
    assert "keypoint confidence" in report.timings
    # ... and the hand's keypoints as a whole get a confidence of their own (their median)
    kc = inp.meta["perception"]["confidence"]["keypoints"]
    assert kc["score"] == pytest.approx(np.median(np.linspace(0.05, 1.0, 21)), abs=1e-4)
    assert not kc["low"] and kc["reasons"] == [
        "10 of 21 keypoints move when the detector's crop moves"
    ]
    # a detector that cannot measure it (it loses the hand around its own keypoints): the
    # keypoints are reported as unsure, and the optimizer weighs the joints alike
    monkeypatch.setattr(SureOfSome, "keypoint_confidence", lambda self, image, hand: None)
    inp, report = perceive(img, sure)
    assert "keypoints2d_confidence" not in inp.meta
    assert report.confidence["keypoints"].score == 0.0 and report.low_confidence == ["keypoints"]


def test_an_unsure_skeleton_is_replaced_by_a_steadier_mirrored_look(config, monkeypatch):
    """Keypoints the detector is unsure of (median confidence < 0.5) get a second look at the
    mirrored photo; the steadier skeleton is what the hand is fitted to, the masks stay the
    first look's."""
    seen = []

    def holds(image, hand, prompts=None):
        seen.append(float(hand.keypoints2d[:, 1].mean()))
        return right_hand_holds()().segment(image, hand, prompts)

    class Unsure(TwoHands):
        conf = np.full(21, 0.2)
        look_conf = np.full(21, 0.9)
        looks: list = []

        def keypoint_confidence(self, image, hand):
            return Unsure.conf

        def mirrored_look(self, image, hand):
            Unsure.looks.append(hand.side)
            moved = hand_at(160, 60, "right")  # the same hand, its skeleton 10 px lower
            return (moved, Unsure.look_conf) if Unsure.look_conf is not None else None

    class Segmenter:
        def segment(self, image, hand, prompts=None):
            return holds(image, hand, prompts)

    monkeypatch.setitem(base._REGISTRY["segmenter"], "holds", Segmenter)
    monkeypatch.setitem(base._REGISTRY["hand"], "unsure", Unsure)
    cfg = replace(config, perception=replace(config.perception, hand="unsure", segmenter="holds"))
    img = np.random.default_rng(0).integers(0, 255, (100, 200, 3), dtype=np.uint8)
    inp, report = perceive(img, cfg)
    assert Unsure.looks == ["right"]  # only the chosen hand is looked at again
    assert seen == [pytest.approx(50.0, abs=1)] * 2  # both hands, segmented once each
    np.testing.assert_allclose(inp.meta["keypoints2d"], hand_at(160, 60, "right").keypoints2d)
    np.testing.assert_allclose(inp.meta["keypoints2d_confidence"], 0.9)
    assert report.confidence["keypoints"].score == pytest.approx(0.9)
    assert "second look (mirrored photo)" in report.timings
    assert any(n.startswith("hand keypoints from the mirrored photo") and "0.20 in the photo"
               in n and "0.90 mirrored" in n for n in report.notes)  # fmt: skip
    # a look no steadier than the photo's skeleton, or none at all: the photo's is kept
    for look in (np.full(21, 0.2), None):
        Unsure.look_conf, Unsure.looks, seen[:] = look, [], []
        inp, report = perceive(img, cfg)
        assert Unsure.looks == ["right"] and len(seen) == 2
        np.testing.assert_allclose(inp.meta["keypoints2d"], hand_at(160, 50, "right").keypoints2d)
        assert report.confidence["keypoints"].score == pytest.approx(0.2)
    # keypoints the detector is sure of: no second look
    Unsure.conf, Unsure.look_conf, Unsure.looks = np.full(21, 0.6), np.full(21, 0.9), []
    perceive(img, cfg)
    assert Unsure.looks == []


def test_grounded_sam_gets_both_model_folders(monkeypatch, tmp_path):
    from easyhoi.cli import _config_from_args, build_parser
    from easyhoi.config import PerceptionConfig
    from easyhoi.perception import chain

    seen = {}

    def fake_create(role, name, **kw):
        seen.update(role=role, name=name, **kw)
        return object()

    monkeypatch.setattr(chain, "create", fake_create)
    pc = PerceptionConfig(segmenter="grounded-sam", detector_dir="/m/owl", sam_dir="/m/sam")
    chain._backend(pc, "segmenter", "grounded-sam", 3)
    assert seen == {"role": "segmenter", "name": "grounded-sam", "detector_dir": "/m/owl",
                    "sam_dir": "/m/sam", "device": "cpu"}  # fmt: skip
    flags = ["--detector-dir", "/m/owl", "--sam-dir", "/m/sam"]
    args = build_parser().parse_args(["reconstruct", "x.jpg", "--out", str(tmp_path), *flags])
    pc = _config_from_args(args).perception
    assert (pc.segmenter, pc.detector_dir, pc.amodal, pc.sam_dir) == (
        "grounded-sam", "/m/owl", "sam", "/m/sam")  # fmt: skip


class TwoHandsOneUnsteady(TwoHands):
    """The left skeleton is not found again in moved crops (confidence None); the right one is.
    ``steady`` (hand side -> bool) says which are; it records which hands were measured."""

    steady = {"left": False, "right": True}
    measured: list = []

    def keypoint_confidence(self, image, detection):
        TwoHandsOneUnsteady.measured.append(detection.side)
        return np.full(21, 0.8) if self.steady[detection.side] else None


def test_an_object_prompt_passes_over_a_skeleton_the_detector_does_not_find_again(
    config, monkeypatch
):
    monkeypatch.setitem(base._REGISTRY["hand"], "unsteady", TwoHandsOneUnsteady)
    cfg = replace(config, perception=replace(config.perception, hand="unsteady"))
    TwoHandsOneUnsteady.measured = []
    near_left = Prompts(object_points=((60.0, 50.0),))  # 20 px from the left hand's circle
    with pytest.raises(NoObjectError, match=r"\(for hand 0, right\)"):
        perceive(IMAGE, cfg, prompts=near_left)
    assert Recording.calls == [("right", near_left)]
    assert TwoHandsOneUnsteady.measured == ["left", "right"]
    # both unsteady: the nearest is kept (no hand is better founded than another)
    Recording.calls, TwoHandsOneUnsteady.measured = [], []
    monkeypatch.setattr(TwoHandsOneUnsteady, "steady", {"left": False, "right": False})
    with pytest.raises(NoObjectError, match=r"\(for hand 0, left\)"):
        perceive(IMAGE, cfg, prompts=near_left)
    assert Recording.calls == [("left", near_left)]
    # a steady nearest hand is measured once and chosen; a hand point is never second-guessed
    Recording.calls, TwoHandsOneUnsteady.measured = [], []
    monkeypatch.setattr(TwoHandsOneUnsteady, "steady", {"left": True, "right": False})
    with pytest.raises(NoObjectError, match=r"\(for hand 0, left\)"):
        perceive(IMAGE, cfg, prompts=near_left)
    assert TwoHandsOneUnsteady.measured == ["left"]
    Recording.calls, TwoHandsOneUnsteady.measured = [], []
    monkeypatch.setattr(TwoHandsOneUnsteady, "steady", {"left": False, "right": True})
    with pytest.raises(NoObjectError, match=r"nearest the hand point \(hand 0, left\)"):
        perceive(IMAGE, cfg, prompts=Prompts(hand_point=(45.0, 50.0)))
    assert TwoHandsOneUnsteady.measured == []
    # the chain goes on with the hand it keeps: a confidence measured here (None included) is
    # not measured again for it
    monkeypatch.setitem(base._REGISTRY["segmenter"], "rated", right_hand_holds())
    rated = replace(cfg, perception=replace(cfg.perception, segmenter="rated"))
    monkeypatch.setattr(TwoHandsOneUnsteady, "steady", {"left": False, "right": False})
    TwoHandsOneUnsteady.measured = []
    img = np.random.default_rng(0).integers(0, 255, (100, 200, 3), dtype=np.uint8)
    inp, _ = perceive(img, rated, prompts=Prompts(object_points=((150.0, 50.0),)))
    assert TwoHandsOneUnsteady.measured[:2] == ["right", "left"]
    assert TwoHandsOneUnsteady.measured.count("right") == 1
    assert "keypoints2d_confidence" not in inp.meta
