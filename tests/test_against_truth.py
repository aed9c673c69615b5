"""A reconstruction against its synthetic scene: the truth itself scores perfectly, and a
changed input scores what a direct count says."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from easyhoi.synth.against_truth import against_truth, truth_line
from easyhoi.synth.evaluate import gt_hand_state
from easyhoi.synth.scene import make_scene


@pytest.fixture(scope="module")
def scene_and_input():
    scene = make_scene(4, "box", "power", image_size=96, photo=False)
    inp = scene.to_hoi_input("none")
    return scene, inp


def _gt_result(scene, inp):
    params, m, cam = gt_hand_state(scene, inp)
    return SimpleNamespace(hand_params=params, camera=cam, metric_scale=m)


def test_the_truth_scores_perfectly(scene_and_input):
    scene, inp = scene_and_input
    inp = replace(inp, hand_mask=scene.hand_mask, object_mask=scene.object_mask,
                  amodal_mask=scene.object_amodal | scene.object_mask,
                  meta={**inp.meta, "keypoints2d": scene.keypoints_2d.tolist()})  # fmt: skip
    model = scene.hand_model
    got = against_truth(scene, inp, _gt_result(scene, inp), model)
    assert got["hand_mask_iou"] == 1.0 and got["object_mask_iou"] == 1.0
    assert got["amodal_mask_iou"] == 1.0
    assert got["detector_px"] == 0.0
    assert got["result_px"] < 1e-6  # the true hand through the true camera: the true keypoints
    assert "object mask IoU 1.00" in truth_line(got)


def test_a_changed_input_scores_what_a_count_says(scene_and_input):
    scene, inp = scene_and_input
    obj = scene.object_mask.copy()
    rows = np.nonzero(obj.any(1))[0]
    obj[rows[: len(rows) // 2]] = False  # the object's upper half missed
    shift = scene.keypoints_2d + np.array([3.0, 4.0])  # every keypoint 5 px off
    inp = replace(inp, hand_mask=scene.hand_mask, object_mask=obj,
                  meta={**inp.meta, "keypoints2d": shift.tolist()})  # fmt: skip
    model = scene.hand_model
    got = against_truth(scene, inp, _gt_result(scene, inp), model)
    assert got["object_mask_iou"] == pytest.approx(obj.sum() / scene.object_mask.sum())
    assert got["detector_px"] == pytest.approx(5.0)
    line = truth_line(got)
    assert "the detector's 5.0 px" in line
