"""benchmarks/bench_real_e2e.py: the usable-result rates over hand-made rows, and real photos (one
of them downscaled by the loader) through the whole pipeline scored against their reference
masks."""

from __future__ import annotations

import pytest

from tests.helpers import ROOT, load_script


def _script():
    return load_script("benchmarks/bench_real_e2e.py")


def _row(usable, warned, hand=0.8, obj=0.8, mask=0.8, contact=True, status="ok", present=True):
    return {"present": present, "status": status, "usable": usable, "warned": warned,
            "hand_iou": hand, "object_iou": obj, "input_object_iou": mask,
            "in_contact": contact, "cpu_seconds": 5.0}  # fmt: skip


def test_summary_rates_over_the_photos_with_a_held_object():
    be = _script()
    rows = [
        _row(True, False),
        _row(False, True, obj=0.2, mask=0.7),  # a right mask the optimizer lost, warned
        _row(False, False, obj=0.1, mask=0.1),  # wrong and silent
        {
            "present": True,
            "status": "NoObjectError",
            "usable": False,
            "warned": True,
            "cpu_seconds": 1.0,
        },  # fmt: skip
        _row(True, True, present=False),  # nothing held: not counted
    ]
    s = be.summary(rows)
    assert s["photos"] == 4
    assert s["finished"] == pytest.approx(0.75)
    assert s["usable"] == pytest.approx(0.25)
    assert s["unusable_warned"] == pytest.approx(2 / 3, abs=1e-3)
    assert s["usable_warned"] == pytest.approx(0.0)
    assert s["object_iou_ge_0.5"] == pytest.approx(0.25)
    assert s["hand_iou_ge_0.5"] == pytest.approx(0.75)
    assert s["in_contact"] == pytest.approx(0.75)
    assert s["mask_lost"] == 1
    assert s["mean_object_iou"] == pytest.approx((0.8 + 0.2 + 0.1) / 3, abs=1e-3)
    assert s["median_cpu_seconds"] == pytest.approx(5.0)


def test_hidden_share_counts_the_object_mask_under_the_rendered_hand():
    import numpy as np

    be = _script()
    obj = np.zeros((10, 10), bool)
    obj[2:6, 2:7] = True  # 20 pixels
    hand = np.zeros((10, 10), bool)
    hand[4:9, 5:9] = True  # over 2 rows x 2 columns of the object, and beyond it
    assert be._hidden_share(hand, obj) == pytest.approx(4 / 20)
    assert be._hidden_share(hand, np.zeros((10, 10), bool)) == 0.0
    rows = [dict(_row(True, False), object_hidden=h) for h in (0.0, 0.3)]
    assert be.summary(rows)["mean_object_hidden"] == pytest.approx(0.15)


@pytest.mark.slow
@pytest.mark.parametrize(
    "stem",
    [
        "images__hort-phone",
        # 4242 px, which the loader downscales to 1600: the click is in the stored photo's
        # pixels and the masks are compared on the loaded one
        "images__easyhoi-coffee-2",
    ],
)
def test_a_clicked_object_is_usable_against_its_reference(shared_data, stem):
    be = _script()
    ref = ROOT / "tests" / "data" / "perception_refs" / f"{stem}.json"
    row = be.run_one(str(ref), "point", str(shared_data))
    assert row["status"] == "ok", row
    # the rendered result, not perception's masks, against the hand-drawn reference
    assert row["hand_iou"] >= 0.5 and row["object_iou"] >= 0.5 and row["in_contact"]
    assert row["usable"]
    assert row["input_object_iou"] >= 0.5


def test_a_bad_override_is_an_argument_error(capsys):
    be = _script()
    with pytest.raises(SystemExit) as exc:
        be.main(["--set", "optim.camera.no_such_field=1"])
    assert exc.value.code == 2
    assert "no_such_field" in capsys.readouterr().err


def test_copies_are_resampled_and_saved_as_jpeg(shared_data, tmp_path):
    from PIL import Image

    be = _script()
    ref = ROOT / "tests" / "data" / "perception_refs" / "images__hort-phone.json"
    be.write_copies([str(ref)], shared_data, tmp_path, 0.5, 90)
    with Image.open(shared_data / "images" / "hort-phone.png") as im:
        w, h = im.size
    with Image.open(tmp_path / "images" / "hort-phone.png") as im:  # named as the original
        assert im.format == "JPEG" and im.size == (round(w * 0.5), round(h * 0.5))
    be.write_copies([str(ref)], shared_data, tmp_path, 1.0, None)
    with Image.open(tmp_path / "images" / "hort-phone.png") as im:
        assert im.format == "PNG" and im.size == (w, h)


@pytest.mark.slow
def test_a_click_on_a_resampled_copy_is_scaled_to_it(shared_data, tmp_path):
    be = _script()
    ref = ROOT / "tests" / "data" / "perception_refs" / "images__hort-phone.json"
    be.write_copies([str(ref)], shared_data, tmp_path, 0.7, None)
    row = be.run_one(str(ref), "point", str(tmp_path))
    assert row["status"] == "ok" and row["input_object_iou"] >= 0.5 and row["usable"]


def test_bad_copy_settings_are_argument_errors(capsys):
    be = _script()
    for args, msg in ((["--resample", "0"], "--resample must be > 0"),
                      (["--jpeg", "101"], "quality from 1 to 100")):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            be.main(args)
        assert exc.value.code == 2 and msg in capsys.readouterr().err
