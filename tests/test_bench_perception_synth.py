"""The synthetic perception benchmark: its references are the scene's own masks, its click the
mask's deepest pixel, and a run scores the product's masks against them."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from easyhoi.synth import make_scene
from tests.perception_refs import deepest_point

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_perception_synth as bps  # noqa: E402


def test_deepest_point_against_a_brute_force_distance():
    mask = np.zeros((40, 60), bool)
    mask[5:25, 10:50] = True  # a 20 x 40 bar: its ridge runs along the middle row
    mask[25:35, 12:20] = True
    x, y = deepest_point(mask)
    depth = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    assert depth[y, x] == pytest.approx(depth.max(), abs=1.0)
    # of the tied ridge pixels, the one nearest the ridge's middle
    assert 28 <= x <= 31 and 14 <= y <= 15
    assert deepest_point(np.zeros((5, 5), bool)) is None


def test_scene_reference_is_the_scene_itself():
    scene = make_scene(4, image_size=128)
    ref = bps.scene_reference(scene)
    assert np.array_equal(ref["object"], scene.object_mask)
    assert np.array_equal(ref["hand"][0], scene.hand_mask) and ref["holds"] == [True]
    x, y = ref["point"]
    assert scene.object_mask[y, x]


@pytest.mark.slow
def test_a_run_scores_the_products_masks(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert bps.main(["--seeds", "4", "5", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    row = data["rows"][0]
    assert data["summary"]["photos"] == 1 and row["seed"] == 4 and row["kind"] == "sphere"
    # the striped ball of seed 4 (make demo's scene) is found automatically and with a box
    assert row["iou"] >= 0.5 and row["iou_box"] >= 0.5 and 0.0 <= row["iou_point"] <= 1.0
    assert data["summary"]["iou_ge_0.5"] == 1.0 and data["summary"]["box_iou_ge_0.5"] == 1.0
