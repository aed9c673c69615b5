import pytest
import trimesh

from easyhoi.cli import main
from easyhoi.errors import InvalidInputError


def test_demo_hand_writes_meshes_and_picture(tmp_path, capsys):
    rc = main(["demo-hand", "--out", str(tmp_path)])
    assert rc == 0
    rest = trimesh.load(tmp_path / "hand_rest.ply", process=False)
    grasp = trimesh.load(tmp_path / "hand_grasp.ply", process=False)
    assert len(rest.vertices) == len(grasp.vertices) > 1000
    assert rest.is_watertight
    # the grasp pose moved the fingertips
    assert abs(rest.vertices - grasp.vertices).max() > 0.02
    assert (tmp_path / "hand_regions.png").stat().st_size > 10_000
    assert "watertight=True" in capsys.readouterr().out


def test_doctor_lists_backends(capsys):
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    assert "mediapipe" in out and "silhouette" in out and "classical" in out


def test_missing_photo_is_a_named_error_with_exit_2(tmp_path, capsys):
    rc = main(["reconstruct", str(tmp_path / "nope.jpg"), "--out", str(tmp_path / "o")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "InvalidInputError" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_unknown_hand_model_choice_exits_2(tmp_path):
    import pytest

    with pytest.raises(SystemExit) as exc:
        main(["demo-hand", "--hand-model", "nope", "--out", str(tmp_path)])
    assert exc.value.code == 2


def test_mano_without_file_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("EASYHOI_MANO_DIR", raising=False)
    rc = main(["demo-hand", "--hand-model", "mano", "--mano-dir", str(tmp_path), "--out",
               str(tmp_path / "o")])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert "MANO" in err and "Traceback" not in err


@pytest.mark.slow
def test_example_reconstructs_a_synthetic_photo_end_to_end(tmp_path, capsys):
    import json

    rc = main(["example", "--seed", "3", "--size", "256", "--out", str(tmp_path)])
    assert rc == 0
    folder = tmp_path / "synthetic_3"
    for name in ("scene.glb", "hand.ply", "object.ply", "result.json", "overlay.png",
                 "report.html"):  # fmt: skip
        assert (folder / name).stat().st_size > 0, name
    res = json.loads((folder / "result.json").read_text())
    text = json.dumps(res)
    assert "penetration_depth_cm" in text and "hand_mask_iou" in text
    out = capsys.readouterr().out
    assert "results:" in out and "report.html" in out


def test_imported_masks_of_a_non_square_photo_and_of_the_full_size_photo(tmp_path):
    import numpy as np
    from PIL import Image

    from easyhoi.cli import _provided_from_args, build_parser

    photo = tmp_path / "wide.png"
    Image.fromarray(np.full((1000, 2000, 3), 128, np.uint8)).save(photo)  # downscaled to 1600
    full = np.zeros((1000, 2000), np.uint8)
    full[400:600, 800:1200] = 255
    Image.fromarray(full).save(tmp_path / "full.png")
    small = np.zeros((800, 1600), np.uint8)
    small[320:480, 640:960] = 255
    Image.fromarray(small).save(tmp_path / "small.png")
    args = build_parser().parse_args(["reconstruct", str(photo), "--out", str(tmp_path / "o"),
                                      "--hand-mask", str(tmp_path / "full.png"),
                                      "--object-mask", str(tmp_path / "small.png")])  # fmt: skip
    given = _provided_from_args(args)
    assert given.hand_mask.shape == given.object_mask.shape == (800, 1600)
    assert given.hand_mask.sum() == given.object_mask.sum() == 160 * 320
    Image.fromarray(small[:700]).save(tmp_path / "bad.png")
    args.hand_mask = str(tmp_path / "bad.png")
    with pytest.raises(InvalidInputError, match="is 700x1600 but the image is 800x1600"):
        _provided_from_args(args)
