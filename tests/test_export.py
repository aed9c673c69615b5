"""GLB / PLY / result.json exports: metric units, glTF camera, MANO layout."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.io.export import (
    camera_gltf,
    export_glb,
    export_ply,
    glb_bytes,
    metric_camera,
    result_json,
    write_result_json,
)
from easyhoi.structures import Camera
from easyhoi.testing.hoi_scene import METRIC_SCALE, make_result


@pytest.fixture(scope="module")
def result():
    return make_result()


def test_glb_round_trip_metric_meshes(result, tmp_path):
    path = export_glb(result, tmp_path / "scene.glb")
    scene = trimesh.load(path, process=False)
    assert set(scene.geometry) == {"hand", "object"}
    dumped = {}
    for node in scene.graph.nodes_geometry:
        T, geom = scene.graph[node]
        g = scene.geometry[geom]
        dumped[geom] = trimesh.transform_points(g.vertices, T)
    hand, obj = dumped["hand"], dumped["object"]
    assert hand.shape == result.hand_vertices.shape
    assert obj.shape == result.object_mesh.vertices.shape
    np.testing.assert_allclose(hand, result.hand_vertices * METRIC_SCALE, atol=1e-6)
    np.testing.assert_allclose(obj, result.object_mesh.vertices * METRIC_SCALE, atol=1e-6)
    # the box is 7 cm wide in metres
    np.testing.assert_allclose(np.ptp(obj, axis=0), [0.07, 0.04, 0.06], atol=1e-6)
    # hand in skin colour
    colors = scene.geometry["hand"].visual.vertex_colors
    assert tuple(colors[0][:3]) == (236, 178, 140)


def test_glb_camera_node(result):
    import io

    scene = trimesh.load(io.BytesIO(glb_bytes(result)), file_type="glb")
    assert scene.has_camera
    K = result.camera.K.double()
    yfov = math.degrees(2 * math.atan(result.camera.height / (2 * float(K[1, 1]))))
    xfov = math.degrees(2 * math.atan(result.camera.width / (2 * float(K[0, 0]))))
    assert scene.camera.fov[1] == pytest.approx(yfov, rel=1e-6)
    # trimesh reads fov_x as aspect * yfov (an approximation); check the glTF aspect directly
    _, pose = camera_gltf(metric_camera(result))
    np.testing.assert_allclose(scene.camera_transform, pose, atol=1e-6)
    # project a hand vertex with the glTF camera (look down -z, y up) and with OpenCV
    x = result.hand_vertices[100] * METRIC_SCALE
    pc = np.linalg.inv(scene.camera_transform) @ np.append(x, 1.0)
    assert pc[2] < 0  # in front of a glTF camera
    f = result.camera.height / 2 / math.tan(math.radians(yfov) / 2)
    u = result.camera.width / 2 + f * pc[0] / -pc[2]
    v = result.camera.height / 2 - f * pc[1] / -pc[2]
    uv, _ = result.camera.project(torch.tensor(result.hand_vertices[100]))
    np.testing.assert_allclose([u, v], uv.numpy(), atol=1e-4)
    assert xfov > yfov  # landscape image


def test_camera_gltf_pose_and_aspect():
    cam = Camera.look_at([0.0, 0.0, -2.0], [0.0, 0.0, 0.0], focal=(300.0), width=200, height=100)
    cam = Camera(torch.tensor([[300.0, 0, 100], [0, 250.0, 50], [0, 0, 1]]), cam.R, cam.t, 200, 100)
    g, pose = camera_gltf(cam)
    p = g["perspective"]
    assert p["yfov"] == pytest.approx(2 * math.atan(100 / 500))
    # horizontal half-angle from the aspect ratio equals atan(W / 2 fx)
    assert math.atan(p["aspectRatio"] * math.tan(p["yfov"] / 2)) == pytest.approx(
        math.atan(200 / 600)
    )
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.0, -2.0], atol=1e-6)
    # glTF looks down -z: the camera's -z axis points at the origin (+z world)
    np.testing.assert_allclose(-pose[:3, 2], [0.0, 0.0, 1.0], atol=1e-6)
    # look_at default up is world -y; glTF +y is image up
    np.testing.assert_allclose(pose[:3, 1], [0.0, -1.0, 0.0], atol=1e-6)


def test_export_ply_exact(result, tmp_path):
    mesh = result.object_mesh_metric()
    path = export_ply(mesh, tmp_path / "object.ply")
    back = trimesh.load(path, process=False)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    with pytest.raises(InvalidInputError):
        export_ply("not a mesh", tmp_path / "x.ply")


def test_result_json_layout(result, tmp_path):
    d = result_json(result)
    assert d["units"] == "metres"
    assert d["metric_scale"] == METRIC_SCALE
    hand = d["hand"]
    assert [len(hand[k]) for k in ("global_orient", "transl", "pose", "betas")] == [3, 3, 45, 10]
    assert hand["side"] == "right"
    np.testing.assert_allclose(hand["transl"], [0.004, 0.003, 0.0], atol=1e-12)
    np.testing.assert_allclose(d["camera"]["K"], result.camera.K.double().numpy(), atol=1e-9)
    np.testing.assert_allclose(
        d["camera"]["t"], result.camera.t.double().numpy() * METRIC_SCALE, atol=1e-12
    )
    np.testing.assert_allclose(d["camera_object_units"]["t"], result.camera.t.numpy(), atol=1e-9)
    assert "opencv" in d["camera"]["convention"]
    assert d["plausibility"]["contact_ratio"] == 0.8125
    assert d["timings"]["total"] == 6.75
    assert set(d["versions"]) >= {"easyhoi", "torch", "numpy", "python"}
    assert d["seed"] == 7 and d["config"]["preset"] == "fast"
    assert [s["name"] for s in d["stages"]] == ["initial", "camera", "contact", "refine"]
    text = write_result_json(result, tmp_path / "result.json").read_text()
    assert json.loads(text)["hand"]["pose"] == hand["pose"]


def test_result_json_nan_becomes_null(tmp_path):
    r = make_result(plausibility={"penetration": float("nan"), "ok": 1.5})
    d = json.loads(write_result_json(r, tmp_path / "r.json").read_text())
    assert d["plausibility"] == {"penetration": None, "ok": 1.5}


def test_exports_reject_non_results(tmp_path):
    with pytest.raises(InvalidInputError):
        export_glb(object(), tmp_path / "a.glb")
    with pytest.raises(InvalidInputError):
        result_json({"hand": 1})


def test_pictures_of_a_large_photo_are_drawn_at_picture_size():
    import torch

    from easyhoi.testing.hoi_scene import make_input
    from easyhoi.viz.report import picture_scale

    big_h, big_w = 1200, 1600
    result = make_result(height=big_h, width=big_w)
    inp = make_input(result, height=big_h, width=big_w)
    r2, i2 = picture_scale(result, inp, max_side=800)
    assert i2.image.shape == (600, 800, 3) and i2.hand_mask.shape == (600, 800)
    assert (r2.camera.height, r2.camera.width) == (600, 800)
    assert all(s.camera is None or s.camera.width == 800 for s in r2.stages)
    pts = torch.tensor(result.object_mesh.vertices[:5], dtype=r2.camera.K.dtype)
    uv_big, _ = result.camera.project(pts)
    uv_small, _ = r2.camera.project(pts)
    assert torch.allclose(uv_small, uv_big * 0.5, atol=1e-4)
    assert abs(int(i2.hand_mask.sum()) - int(inp.hand_mask.sum()) / 4) < 0.05 * inp.hand_mask.sum()
    r3, i3 = picture_scale(result, inp, max_side=2000)
    assert r3 is result and i3 is inp


def test_result_json_records_the_refinements_gap_closing(result):
    from dataclasses import replace

    note = {"gap_before": 0.05, "moved": False,
            "meet": {"moved": True, "distance_cm": 1.2, "shift_px": float("nan")}}  # fmt: skip
    stages = [replace(st, extra={**(st.extra or {}), "close_gap": note})
              if st.name == "refine" else st for st in result.stages]  # fmt: skip
    d = result_json(replace(result, stages=tuple(stages)))
    by_name = {s["name"]: s for s in d["stages"]}
    assert by_name["refine"]["close_gap"]["meet"] == {
        "moved": True,
        "distance_cm": 1.2,
        "shift_px": None,
    }
    assert all("close_gap" not in s for n, s in by_name.items() if n != "refine")
