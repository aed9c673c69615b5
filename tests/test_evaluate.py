import json

import numpy as np
import pytest
import trimesh

from easyhoi.cli import main
from easyhoi.errors import InvalidInputError
from easyhoi.evaluate import evaluate_result
from easyhoi.hand import load_hand_model
from easyhoi.structures import HandParams


@pytest.fixture(scope="module")
def result_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("res")
    hand = load_hand_model()(HandParams.zeros(1)).to_trimesh()
    box = trimesh.creation.box(extents=(0.05, 0.04, 0.08))
    box.apply_translation(hand.vertices.mean(0) + np.array([0.0, -0.08, 0.0]))
    hand.export(folder / "hand.ply")
    box.export(folder / "object.ply")
    info = {"camera": {"R": np.eye(3).tolist(), "t": [0, 0, 0.5]}, "metric_scale": 1.0}
    (folder / "result.json").write_text(json.dumps(info))
    return folder, hand, box


def test_against_ground_truth_known_answers(result_folder, tmp_path):
    folder, hand, box = result_folder
    gt_box = box.copy()
    gt_box.apply_scale(1.5)
    gt_box.apply_translation([0.3, 0.1, 0.0])
    moved = hand.copy()
    moved.apply_translation([0.01, 0.0, 0.0])  # 1 cm
    gt_box.export(tmp_path / "gt_object.ply")
    moved.export(tmp_path / "gt_hand.ply")
    res = evaluate_result(folder, tmp_path / "gt_object.ply", tmp_path / "gt_hand.ply",
                          simulate=False, n_samples=5000)  # fmt: skip
    assert res["object"]["chamfer_moho"] < 1e-3  # scale + translation aligned away
    assert res["object"]["f@5mm"] > 0.99
    assert res["hand"]["mpvpe_cm"] == pytest.approx(1.0, abs=1e-6)
    assert res["hand"]["mpvpe_root_cm"] == pytest.approx(0.0, abs=1e-6)
    assert res["penetration_depth_cm"] == pytest.approx(0.0, abs=1e-9)
    assert res["intersection_volume_cm3"]["solid"] == 0.0
    res_none = evaluate_result(folder, tmp_path / "gt_object.ply", simulate=False,
                               align="none", n_samples=5000)  # fmt: skip
    assert res_none["object"]["chamfer_moho"] > 10 * res["object"]["chamfer_moho"] + 1.0


def test_wrong_topology_and_missing_folder_are_named_errors(result_folder, tmp_path):
    folder, _, box = result_folder
    box.export(tmp_path / "not_a_hand.ply")
    with pytest.raises(InvalidInputError, match="same hand model"):
        evaluate_result(folder, gt_hand=tmp_path / "not_a_hand.ply", simulate=False)
    assert main(["eval", str(tmp_path / "nothing"), "--no-sim"]) == 2


def test_cli_eval_writes_json(result_folder, tmp_path, capsys):
    folder, _, _ = result_folder
    out = tmp_path / "m.json"
    assert main(["eval", str(folder), "--no-sim", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert rows[0]["in_contact_5mm"] is False  # the box is 8 cm below the hand centre
    assert "penetration_depth_cm" in capsys.readouterr().out
