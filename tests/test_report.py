"""The HTML report and the all-or-nothing result folder."""

from __future__ import annotations

import base64
import io
import json
import re

import numpy as np
import pytest
import trimesh
from PIL import Image

import easyhoi.viz.report as report_mod
import easyhoi.viz.views as views_mod
from easyhoi.errors import InvalidInputError
from easyhoi.result_folder import RESULT_FILES, write_result_folder
from easyhoi.testing.hoi_scene import METRIC_SCALE, H, W, hand_model, make_input, make_result
from easyhoi.viz.report import fmt, report_html


@pytest.fixture(scope="module")
def scene():
    return make_result(), make_input()


@pytest.fixture(scope="module")
def folder(scene, tmp_path_factory):
    """One complete folder, written over a stale folder of the same name."""
    result, inp = scene
    out = tmp_path_factory.mktemp("out")
    stale = out / "photo_01"
    stale.mkdir()
    (stale / "old.txt").write_text("stale")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(views_mod, "VIEW_SIZE", 64)
        paths = write_result_folder(
            result, inp, out / "photo_01", hand_model=hand_model(), title="photo_01.jpg"
        )
    return out, paths


def test_folder_contents(folder, scene):
    out, paths = folder
    result, _ = scene
    assert [p.name for p in paths] == list(RESULT_FILES)
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths)
    d = out / "photo_01"
    assert sorted(x.name for x in d.iterdir()) == sorted(RESULT_FILES)  # stale file gone
    assert sorted(x.name for x in out.iterdir()) == ["photo_01"]  # no temp leftovers
    hand = trimesh.load(d / "hand.ply", process=False)
    np.testing.assert_allclose(hand.vertices, result.hand_vertices * METRIC_SCALE, atol=1e-12)
    doc = json.loads((d / "result.json").read_text())
    assert doc["units"] == "metres" and len(doc["hand"]["pose"]) == 45
    overlay = Image.open(d / "overlay.png")
    assert overlay.size == (W, H)
    assert len(trimesh.load(d / "scene.glb").geometry) == 2


def test_result_folder_reloads_as_hoi_result(folder, scene):
    from easyhoi.io.hoi_io import load_hoi_result

    result, _ = scene
    back = load_hoi_result(folder[0] / "photo_01")
    np.testing.assert_allclose(back.hand_vertices, result.hand_vertices, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(back.object_mesh.vertices, result.object_mesh.vertices,
                               rtol=1e-9, atol=1e-12)  # fmt: skip
    assert back.metric_scale == result.metric_scale
    np.testing.assert_allclose(back.camera.K.numpy(), result.camera.K.double().numpy())
    np.testing.assert_allclose(back.hand_params.pose.numpy(),
                               result.hand_params.pose.double().numpy(), atol=1e-7)  # fmt: skip
    assert [s.name for s in back.stages] == [s.name for s in result.stages]
    assert [s.iterations for s in back.stages] == [s.iterations for s in result.stages]
    assert back.plausibility == pytest.approx(result.plausibility, nan_ok=True)


def test_report_is_self_contained(folder, scene):
    result, inp = scene
    page = (folder[0] / "photo_01" / "report.html").read_text(encoding="utf-8")
    assert not re.search(r"(src|href)\s*=\s*[\"']?\s*(https?:|//)", page, re.I)
    # no address anywhere outside the embedded pictures (base64 may spell "http" by chance)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", page)
    assert "http" not in text.lower()
    assert "<script" not in page.lower() and "<link" not in page.lower()
    srcs = re.findall(r"<img[^>]*\ssrc=\"([^\"]+)\"", page)
    assert len(srcs) == len(re.findall(r"<img", page)) == 6
    for s in srcs:
        assert s.startswith("data:image/png;base64,")
        im = Image.open(io.BytesIO(base64.b64decode(s.split(",", 1)[1])))
        assert im.format == "PNG"
    # the embedded overlay is the file next to it
    overlay = (folder[0] / "photo_01" / "overlay.png").read_bytes()
    assert base64.b64encode(overlay).decode() in page
    for key, value in result.plausibility.items():
        assert f'<td>{key}</td><td class="num">{fmt(value)}</td>' in page
    for value in result.timings.values():
        assert f">{fmt(value)}<" in page
    assert "photo_01.jpg" in page
    assert 'mask IoU: object amodal</td><td class="num">1<' in page


def test_fmt():
    assert fmt(0.123456) == "0.1235"
    assert fmt(3) == "3"
    assert fmt(float("nan")) == "n/a"
    assert fmt(None) == "n/a"


def test_report_html_escapes_and_rejects(scene):
    result, inp = scene
    pics = {k: b"\x89PNG fake" for k in report_mod.PICTURES}
    page = report_html(result, inp, images=pics, title="<b>x</b>")
    assert "&lt;b&gt;x&lt;/b&gt;" in page and "<b>x</b>" not in page
    with pytest.raises(InvalidInputError):
        report_html(result, "not an input", images=pics)


def _boom(*args, **kwargs):
    raise RuntimeError("injected failure")


def test_failure_leaves_no_partial_folder(scene, tmp_path, monkeypatch):
    result, inp = scene
    monkeypatch.setattr(report_mod, "render_pictures", _boom)
    with pytest.raises(RuntimeError, match="injected"):
        write_result_folder(result, inp, tmp_path / "a")
    assert list(tmp_path.iterdir()) == []


def test_failure_keeps_existing_folder(scene, tmp_path, monkeypatch):
    result, inp = scene
    old = tmp_path / "a"
    old.mkdir()
    (old / "result.json").write_text('{"old": true}')
    monkeypatch.setattr(views_mod, "VIEW_SIZE", 32)
    monkeypatch.setattr(report_mod, "write_report", _boom)  # the very last file
    with pytest.raises(RuntimeError, match="injected"):
        write_result_folder(result, inp, tmp_path / "a")
    assert [p.name for p in tmp_path.iterdir()] == ["a"]
    assert [p.name for p in old.iterdir()] == ["result.json"]
    assert (old / "result.json").read_text() == '{"old": true}'


@pytest.mark.parametrize("name", ["..", ".hidden", "file", "file/x"])
def test_bad_folders_are_refused_before_any_work(scene, tmp_path, name, monkeypatch):
    result, inp = scene
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setattr(report_mod, "render_pictures", _boom)  # never reached
    with pytest.raises((InvalidInputError, NotADirectoryError, FileExistsError)):
        write_result_folder(result, inp, tmp_path / name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_perception_section_names_the_keypoints_row():
    meta = {
        "perception": {
            "confidence": {
                "hand": {"score": 0.9, "low": False, "reasons": []},
                "keypoints": {"score": 0.2, "low": True, "reasons": ["21 of 21 keypoints move"]},
            }
        }
    }
    section = report_mod._perception_html(meta)
    assert "<th>of</th>" in section
    assert "<td>hand</td>" in section
    assert "<td>hand keypoints</td>" in section and "<td>21 of 21 keypoints move</td>" in section
    assert "<td>keypoints</td>" not in section


def test_object_shape_section_says_where_the_thickness_came_from():
    scores = {
        "slab": {"iou": 0.99, "complexity": 0.02, "score": 0.97},
        "inflation": {"iou": 0.98, "complexity": 0.08, "score": 0.90, "depth_scaled": 0.3},
        "cuboid": {"iou": 0.9, "complexity": 0.06, "score": 0.86, "edge_bonus": 0.02},
    }
    meta = {"object_shape": {"shape": "slab", "scores": scores, "depth_cue_from": "pinch",
                             "depth_cue_confidence": 0.6, "flat_by_grip": True}}  # fmt: skip
    section = report_mod._shape_html(meta, np.array([12.0, 8.0, 0.5]))
    assert "<h2>Object shape</h2>" in section
    assert "chosen: slab" in section and "aperture of a pinch" in section
    assert "the grip says the object is flat" in section
    assert "12.0 x 8.0 x 0.5 cm" in section
    # every family, best score first, the winner marked, the score's parts named
    rows = re.findall(r"<tr><td>([^<]+)</td>", section)
    assert rows == ["slab (chosen)", "inflation", "cuboid"]
    assert "depth scaled by 0.3" in section and "edge bonus 0.02" in section
    # no grip cue: the thickness is said to be the family's assumption
    meta["object_shape"].update(depth_cue_from=None, flat_by_grip=False)
    assert "not measured" in report_mod._shape_html(meta)
    # the chosen family among several, and how to fit the one the user knows
    assert "the best of 3 families fitted" in section and "--object-shape NAME" in section
    one = {"object_shape": {"shape": "cuboid", "scores": {"cuboid": scores["cuboid"]}}}
    assert "chosen: cuboid, the one family fitted (--object-shape)" in report_mod._shape_html(one)
    assert "parts of the score" in section  # two of the three scores have parts
    plain = {k: {f: v[f] for f in ("iou", "complexity", "score")} for k, v in scores.items()}
    no_parts = report_mod._shape_html({"object_shape": {"shape": "slab", "scores": plain}})
    assert "parts of the score" not in no_parts and no_parts.count("<tr>") == 4
    # an imported mesh records no shape choice: no section
    assert report_mod._shape_html({}) == ""


def test_object_shape_section_names_a_runner_up_within_the_near_tie():
    scores = {
        "inflation": {"iou": 0.99, "complexity": 0.08, "score": 0.910},
        "slab": {"iou": 0.996, "complexity": 0.12, "score": 0.876},
        "cuboid": {"iou": 0.9, "complexity": 0.06, "score": 0.84},
    }
    meta = {"object_shape": {"shape": "inflation", "scores": scores}}
    section = report_mod._shape_html(meta)
    assert "near tie: slab scored 0.034 below inflation" in section
    assert "(--object-shape slab fits that family alone)" in section
    # a clear winner: no such line
    scores["slab"]["score"] = 0.910 - report_mod.NEAR_TIE - 0.001
    assert "near tie" not in report_mod._shape_html(meta)
    scores["slab"]["score"] = 0.910 - report_mod.NEAR_TIE + 0.001
    assert "near tie: slab scored 0.039 below inflation" in report_mod._shape_html(meta)
    # one family fitted (--object-shape): nothing to compare
    one = {"object_shape": {"shape": "slab", "scores": {"slab": scores["slab"]}}}
    assert "near tie" not in report_mod._shape_html(one)


def test_report_of_a_chain_result_has_the_object_shape(scene):
    result, inp = scene
    meta = dict(result.meta, object_shape={"shape": "revolution", "scores": {
        "revolution": {"iou": 0.95, "complexity": 0.0, "score": 0.95}}})  # fmt: skip
    from dataclasses import replace

    page = report_html(replace(result, meta=meta), inp)
    assert "<h2>Object shape</h2>" in page and "revolution (chosen)" in page
    assert re.search(r"size \(along its principal axes\): \d+\.\d x \d+\.\d x \d+\.\d cm", page)


def test_object_size_is_the_extent_along_the_principal_axes():
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    box = trimesh.creation.box(extents=(0.5, 0.2, 0.05))  # object units
    box.apply_transform(np.r_[np.c_[Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix(),
                                    [1.0, 2.0, 3.0]], [[0, 0, 0, 1]]])  # fmt: skip
    fake = SimpleNamespace(object_mesh=box, metric_scale=0.4)  # 0.4 m per unit
    sides = report_mod._object_sides_cm(fake)
    assert np.allclose(sides, [20.0, 8.0, 2.0], atol=1e-6)
