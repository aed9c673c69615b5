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
    # the synthetic photo's truth is known, and the demo says how the result compares with it
    assert "against the scene's truth: hand mask IoU" in out and "px off" in out


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


# ----------------------------------------------------------------------------------------------
# prompts, confidence warnings, --strict
# ----------------------------------------------------------------------------------------------

FAST = ["--set", "optim.camera.max_iters=10", "--set", "optim.contact.max_iters=10",
        "--set", "optim.refine.max_iters=5"]  # fmt: skip


@pytest.fixture(scope="module")
def scene_photo(tmp_path_factory):
    """A synthetic scene (128 px) and its photo saved as PNG."""
    from PIL import Image

    from easyhoi.synth import make_scene

    scene = make_scene(1, image_size=128)
    path = tmp_path_factory.mktemp("scene") / "scene.png"
    Image.fromarray(scene.image).save(path)
    return scene, path


@pytest.fixture
def fake_perception(scene_photo, monkeypatch):
    """Perception replaced by the scene's own masks; the report's confidence is settable.

    Records the prompts and the photo size that reached perception in ``calls``.
    """
    from easyhoi.perception import chain
    from easyhoi.perception.confidence import MaskConfidence

    scene, _ = scene_photo
    state = {"calls": [], "confidence": {}, "hand_index": 0, "notes": []}

    def perceive(image, config=None, progress=None, seed=0, provided=None, prompts=None):
        state["calls"].append({"shape": image.shape, "prompts": prompts})
        inp = scene.to_hoi_input("none")
        report = chain.PerceptionReport(hands_found=2, side="right", has_object=True)
        report.confidence = {k: MaskConfidence(*v) for k, v in state["confidence"].items()}
        report.hand_index = state["hand_index"]
        report.hand_choice = "first holding an object"
        report.notes = list(state["notes"])
        inp.meta["perception"] = report.to_dict()
        return inp, report

    monkeypatch.setattr(chain, "perceive", perceive)
    return state


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--object-point", "12"], "--object-point expects X,Y (pixels), got '12'"),
        (["--object-point", "a,b"], "--object-point expects X,Y"),
        (["--object-point", "nan,3"], "--object-point expects X,Y"),
        (["--object-box", "1,2,3"], "--object-box expects X0,Y0,X1,Y1"),
        (["--object-box", "30,2,10,40"], "must have x0 < x1 and y0 < y1"),
        (["--hand-point", "1,2,3"], "--hand-point expects X,Y"),
        (["--background-point", "1;2"], "--background-point expects X,Y"),
    ],
)
def test_malformed_prompts_exit_2_before_any_work(tmp_path, capsys, monkeypatch, flags, message):
    from easyhoi import pipeline

    monkeypatch.setattr(pipeline, "reconstruct_photo", lambda *a, **k: pytest.fail("ran"))
    rc = main(["reconstruct", str(tmp_path / "any.png"), "--out", str(tmp_path / "o"), *flags])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("error: InvalidInputError: ") and message in err
    assert "Traceback" not in err and not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--object-point", "128,5"], "--object-point 128,5 lies outside the 128x128 photo"),
        (["--object-point", "5,5", "--object-point=-1,5"], "--object-point -1,5 lies outside"),
        (["--hand-point", "3,200"], "--hand-point 3,200 lies outside the 128x128 photo"),
        (["--object-box", "130,0,200,50"], "does not overlap the 128x128 photo"),
        (["--background-point", "5,128"], "--background-point 5,128 lies outside the 128x128"),
    ],
)
def test_prompts_outside_the_photo_are_refused_before_perception(
    scene_photo, fake_perception, tmp_path, capsys, flags, message
):
    _, path = scene_photo
    rc = main(["reconstruct", str(path), "--out", str(tmp_path / "o"), *flags])
    assert rc == 2
    err = capsys.readouterr().err
    assert "InvalidInputError" in err and message in err and "Traceback" not in err
    assert fake_perception["calls"] == [] and not (tmp_path / "o").exists()


def test_prompts_need_one_photo(scene_photo, tmp_path, capsys):
    _, path = scene_photo
    rc = main(["reconstruct", str(path), str(path), "--out", str(tmp_path / "o"),
               "--object-point", "5,5"])  # fmt: skip
    assert rc == 2
    assert "need exactly one photo" in capsys.readouterr().err


def test_prompts_reach_perception_scaled_to_the_working_photo(fake_perception, tmp_path, capsys):
    import numpy as np
    from PIL import Image

    from easyhoi.errors import LowConfidenceError

    # 3200x2000 photo: perception works on it downscaled by 1/2 (1600 px long side)
    big = tmp_path / "big.png"
    Image.fromarray(np.full((2000, 3200, 3), 90, np.uint8)).save(big)
    fake_perception["confidence"] = {"object": (0.1, ("outline has little contrast",))}
    rc = main(["reconstruct", str(big), "--out", str(tmp_path / "o"), "--strict",
               "--object-point", "1000,600", "--object-point", "3199,1999",
               "--object-box", "800,400,2400,1600", "--hand-point", "200,1800",
               "--background-point", "3000,100"])  # fmt: skip
    assert rc == LowConfidenceError.exit_code == 9
    (call,) = fake_perception["calls"]
    assert call["shape"] == (1000, 1600, 3)
    got = call["prompts"]
    assert got.object_points[0] == (500.0, 300.0)
    assert 1599 < got.object_points[1][0] < 1600 and 999 < got.object_points[1][1] < 1000
    assert got.object_box == (400.0, 200.0, 1200.0, 800.0)
    assert got.hand_point == (100.0, 900.0)
    assert got.background_points == ((1500.0, 50.0),)
    got.check(1600, 1000)  # inside the working photo


def test_strict_low_confidence_exits_9_and_writes_nothing(scene_photo, fake_perception, tmp_path,
                                                          capsys):  # fmt: skip
    _, path = scene_photo
    fake_perception["confidence"] = {
        "hand": (0.9, ()),
        "object": (0.3, ("region runs out of the frame", "no fingertip touches it")),
    }
    rc = main(["reconstruct", str(path), "--out", str(tmp_path / "o"), "--strict", *FAST])
    assert rc == 9
    err = capsys.readouterr().err
    assert err.startswith(
        "error: LowConfidenceError: low confidence in the object mask (score "
        "0.30; weak: region runs out of the frame; no fingertip touches it)"
    )
    assert "--object-point X,Y on the held object" in err and "Traceback" not in err
    assert "hand mask" not in err  # 0.9 is not low
    assert not (tmp_path / "o").exists()
    # a confident result passes --strict
    fake_perception["confidence"] = {"hand": (0.9, ()), "object": (0.5, ())}
    fake_perception["calls"].clear()
    rc = main(["reconstruct", str(path), "--out", str(tmp_path / "o"), "--strict", "-q", *FAST])
    assert rc == 0 and (tmp_path / "o" / "scene" / "result.json").is_file()
    assert capsys.readouterr().err == ""


def test_low_confidence_without_strict_writes_the_result_and_warns(
    scene_photo, fake_perception, tmp_path, capsys
):
    import json

    _, path = scene_photo
    fake_perception["confidence"] = {"hand": (0.2, ("few skin pixels",)), "object": (0.45, ())}
    fake_perception["hand_index"] = 1
    fake_perception["notes"] = ["hand 0 (left) holds no object"]
    rc = main(["reconstruct", str(path), "--out", str(tmp_path / "o"), "--object-point", "60,70",
               *FAST])  # fmt: skip
    assert rc == 0
    cap = capsys.readouterr()
    lines = cap.err.splitlines()
    assert lines[0] == (
        f"{path}: note: hand 0 (left) holds no object: the result uses hand 1 "
        "(right) of 2 detected (choose another with --hand-point X,Y)"
    )
    assert lines[1] == (f"{path}: warning: low confidence in the hand mask (score 0.20; weak: few "
                        "skin pixels): re-run with --hand-point X,Y on the hand that holds the "
                        "object")  # fmt: skip
    # the object was pointed at already: the advice is more points or a box
    assert lines[2].startswith(
        f"{path}: warning: low confidence in the object mask (score 0.45; "
        "weak: no cue stood out): add --object-point X,Y on parts"
    )
    assert "done in" in cap.out
    res = json.loads((tmp_path / "o" / "scene" / "result.json").read_text())
    assert res["meta"]["prompts"] == {"object_points": [[60.0, 70.0]], "object_box": None,
                                      "hand_point": None, "background_points": [],
                                      "object_choice": None}  # fmt: skip
    conf = res["meta"]["perception"]["confidence"]
    assert conf["hand"] == {"score": 0.2, "low": True, "reasons": ["few skin pixels"]}
    report = (tmp_path / "o" / "scene" / "report.html").read_text()
    section = report.split("<h2>Perception confidence</h2>", 1)[1].split("<h2>", 1)[0]
    assert "<td>hand</td>" in section and "<td>yes</td><td>few skin pixels</td>" in section
    assert "<td>object</td>" in section and "<td>no</td>" not in section  # 0.45 is low too
    assert "hand used: 1 (right) of 2 detected, first holding an object" in section
    assert "prompts (photo pixels): {&quot;object_points&quot;: [[60.0, 70.0]]}" in section


def test_help_lists_the_strict_exit_code(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "    9  --strict and a mask or the keypoints scored low (nothing written)" in out
    with pytest.raises(SystemExit):
        main(["reconstruct", "--help"])
    out = capsys.readouterr().out
    for flag in (
        "--object-point X,Y",
        "--object-box X0,Y0,X1,Y1",
        "--hand-point X,Y",
        "--strict",
        "--object-choice K",
    ):
        assert flag in out
