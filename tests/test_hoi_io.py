"""HOIInput / HOIResult validation, folder round trips, atomic writes, corrupt folders."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
import trimesh

import easyhoi.io.atomic as atomic
from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIInput, HOIResult, StageResult, as_bool_mask
from easyhoi.io.atomic import atomic_write_bytes, atomic_write_text
from easyhoi.io.hoi_io import (
    load_hoi_input,
    load_hoi_result,
    mesh_from_ply_bytes,
    mesh_to_ply_bytes,
    save_hoi_input,
    save_hoi_result,
)
from easyhoi.structures import Camera, HandParams

H, W = 24, 32


def _params(dtype=torch.float32, seed=0):
    g = torch.Generator().manual_seed(seed)
    r = lambda n: torch.randn(1, n, generator=g, dtype=dtype)  # noqa: E731
    return HandParams(r(3), r(3), r(45), r(10))


def _mesh(colors=False):
    m = trimesh.creation.icosphere(subdivisions=1)
    m.vertices = m.vertices * np.pi + np.array([0.1, -0.2, 0.3])
    if colors:
        rng = np.random.default_rng(0)
        m.visual.vertex_colors = rng.integers(0, 256, (len(m.vertices), 4), dtype=np.uint8)
    return m


def _box(top, left, h, w):
    m = np.zeros((H, W), bool)
    m[top : top + h, left : left + w] = True
    return m


def _input(**kw):
    rng = np.random.default_rng(1)
    args = dict(
        image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
        hand_mask=_box(2, 2, 8, 10),
        object_mask=_box(10, 12, 8, 10),
        amodal_mask=_box(8, 10, 12, 14),
        object_mesh=_mesh(colors=True),
        hand_params=_params(),
        hand_camera=Camera.hamer_convention(W, H),
        hand_model="open",
        meta={"source": "test", "n": 3},
    )
    args.update(kw)
    return HOIInput(**args)


def _result(dtype=torch.float64):
    cam = Camera.look_at((0, 0, -4.5), (0, 0, 0), focal=100.0, width=W, height=H, dtype=dtype)
    hand = _mesh()
    stages = (
        StageResult(
            "camera", None, cam, [{"iter": 0, "iou": 0.5}, {"iter": 1, "iou": 0.25}], 1.5, 2
        ),
        StageResult(
            "refine", _params(dtype, 1), cam, [{"iter": 0, "total": 1.0}], 0.5, 1, 0.07, "max_iters"
        ),
    )
    return HOIResult(
        hand_params=_params(dtype, 2),
        camera=cam,
        hand_vertices=hand.vertices,
        hand_faces=hand.faces,
        object_mesh=_mesh(),
        metric_scale=0.0734,
        stages=stages,
        timings={"total": 2.0},
        seed=7,
        config={"optim": {"seed": 7}},
        plausibility={"max_penetration_cm": 0.3},
        meta={"image": "a.png"},
    )


def _params_equal(a: HandParams, b: HandParams, atol=1e-7):
    for k, v in a.tensors().items():
        assert v.dtype == b.tensors()[k].dtype
        torch.testing.assert_close(v, b.tensors()[k], atol=atol, rtol=0)
    assert a.side == b.side


# ----------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------


def test_hoi_input_normalises_masks_and_is_read_only():
    inp = _input(
        hand_mask=_box(2, 2, 8, 10).astype(np.uint8) * 255, object_mask=_box(10, 12, 8, 10) * 1.0
    )
    assert inp.hand_mask.dtype == bool and inp.object_mask.dtype == bool
    assert inp.hand_mask.sum() == 80 and inp.size == (H, W)
    with pytest.raises(ValueError):
        inp.image[0, 0, 0] = 1


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(hand_mask=np.ones((H + 1, W), bool)), "hand mask is 25x32 but the image is 24x32"),
        (dict(amodal_mask=np.zeros((H, W), bool)), "amodal object mask is empty"),
        (dict(object_mask=np.full((H, W), 0.5)), "not a binary mask"),
        (dict(object_mask=np.ones((H, W, 1), bool)), r"must be an \(H, W\) mask"),
        (dict(image=np.zeros((H, W, 3), np.float32)), "image must be uint8"),
        (dict(image=np.zeros((H, W), np.uint8)), r"\(H, W, 3\)"),
        (dict(inpainted_image=np.zeros((H, W + 2, 3), np.uint8)), "inpainted image is 24x34"),
        (dict(complete_hand_mask=np.ones((H, W - 1), bool)), "complete hand mask is 24x31"),
        (dict(object_mesh=trimesh.Trimesh()), "object mesh is empty"),
        (dict(object_mesh="mesh.obj"), "must be a trimesh.Trimesh"),
        (dict(hand_camera=Camera.hamer_convention(W * 2, H * 2)), "hand camera is 48x64"),
        (dict(hand_params=HandParams.zeros(batch=2)), "one hand"),
        (dict(hand_model="smplx"), "hand_model must be one of"),
        (dict(meta={"x": object()}), "JSON-serialisable"),
    ],
)
def test_hoi_input_rejects_bad_input(kw, message):
    with pytest.raises(InvalidInputError, match=message):
        _input(**kw)


def test_mesh_checks():
    m = _mesh()
    bad = trimesh.Trimesh(m.vertices.copy(), m.faces.copy(), process=False)
    bad.vertices[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        _input(object_mesh=bad)
    bad = trimesh.Trimesh(m.vertices.copy(), m.faces.copy(), process=False)
    bad.faces[0, 0] = len(m.vertices) + 5
    with pytest.raises(InvalidInputError, match="faces index vertices"):
        _input(object_mesh=bad)


def test_as_bool_mask():
    assert as_bool_mask(np.array([[0, 255]], np.uint8), "m").tolist() == [[False, True]]
    with pytest.raises(InvalidInputError, match="values 0, 3"):
        as_bool_mask(np.array([[0, 3]]), "m")
    with pytest.raises(InvalidInputError, match="dtype"):
        as_bool_mask(np.array([["a"]]), "m")


def test_hoi_result_validation_and_helpers():
    res = _result()
    assert res.stage("refine").metric_scale == 0.07
    p = res.hand_params
    grad = HandParams(p.global_orient.clone().requires_grad_(True), p.transl, p.pose, p.betas)
    det = HOIResult(grad, res.camera, res.hand_vertices, res.hand_faces, res.object_mesh, 1.0)
    assert (
        grad.global_orient.requires_grad
        and not det.detach().hand_params.global_orient.requires_grad
    )
    with pytest.raises(InvalidInputError, match="stages: camera, refine"):
        res.stage("contact")
    extent = res.object_mesh_metric().extents
    np.testing.assert_allclose(extent, res.object_mesh.extents * 0.0734, rtol=1e-12)
    assert res.hand_mesh().vertices.shape == res.hand_vertices.shape
    with pytest.raises(InvalidInputError, match="metric_scale"):
        HOIResult(res.hand_params, res.camera, res.hand_vertices, res.hand_faces, _mesh(), 0.0)
    with pytest.raises(InvalidInputError, match="hand_faces index"):
        HOIResult(
            res.hand_params, res.camera, res.hand_vertices, res.hand_faces + 1000, _mesh(), 1.0
        )


# ----------------------------------------------------------------------------------------------
# round trips
# ----------------------------------------------------------------------------------------------


def test_ply_is_exact_and_keeps_colours():
    m = _mesh(colors=True)
    back = mesh_from_ply_bytes(mesh_to_ply_bytes(m))
    assert np.array_equal(back.vertices, m.vertices) and np.array_equal(back.faces, m.faces)
    assert np.array_equal(back.visual.vertex_colors, m.visual.vertex_colors)
    with pytest.raises(InvalidInputError, match="x.ply is not a readable PLY"):
        mesh_from_ply_bytes(b"ply\ngarbage", "x.ply")


@pytest.mark.parametrize("optional", [False, True])
def test_hoi_input_round_trip(tmp_path, optional):
    extra = {}
    if optional:
        rng = np.random.default_rng(5)
        extra = dict(
            inpainted_image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
            complete_hand_mask=_box(1, 1, 12, 14),
            hand_params=_params(torch.float64, 3),
            hand_model="mano",
        )
    inp = _input(**extra)
    save_hoi_input(inp, tmp_path / "in")
    back = load_hoi_input(tmp_path / "in")
    for k in ("image", "hand_mask", "object_mask", "amodal_mask"):
        assert np.array_equal(getattr(back, k), getattr(inp, k)), k
        assert getattr(back, k).dtype == getattr(inp, k).dtype
    for k in ("inpainted_image", "complete_hand_mask"):
        a, b = getattr(inp, k), getattr(back, k)
        assert (a is None and b is None) or np.array_equal(a, b)
    _params_equal(back.hand_params, inp.hand_params)
    torch.testing.assert_close(back.hand_camera.K, inp.hand_camera.K, atol=1e-7, rtol=0)
    assert (back.hand_camera.width, back.hand_camera.height) == (W, H)
    assert np.array_equal(back.object_mesh.vertices, inp.object_mesh.vertices)
    assert np.array_equal(back.object_mesh.faces, inp.object_mesh.faces)
    assert back.meta == inp.meta and back.hand_model == inp.hand_model
    leftovers = [p.name for p in (tmp_path / "in").iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_hoi_input_accepts_obj(tmp_path):
    inp = _input()
    save_hoi_input(inp, tmp_path)
    os.remove(tmp_path / "object.ply")
    (tmp_path / "object.obj").write_text(trimesh.exchange.obj.export_obj(_mesh(), digits=17))
    back = load_hoi_input(tmp_path)
    np.testing.assert_allclose(back.object_mesh.vertices, _mesh().vertices, atol=1e-12)


def test_hoi_result_round_trip(tmp_path):
    res = _result()
    save_hoi_result(res, tmp_path / "out")
    back = load_hoi_result(tmp_path / "out")
    _params_equal(back.hand_params, res.hand_params)
    torch.testing.assert_close(back.camera.K, res.camera.K, atol=1e-7, rtol=0)
    torch.testing.assert_close(back.camera.R, res.camera.R, atol=1e-7, rtol=0)
    torch.testing.assert_close(back.camera.t, res.camera.t, atol=1e-7, rtol=0)
    assert np.array_equal(back.hand_vertices, res.hand_vertices)
    assert np.array_equal(back.hand_faces, res.hand_faces)
    assert np.array_equal(back.object_mesh.vertices, res.object_mesh.vertices)
    assert back.metric_scale == res.metric_scale and back.seed == 7
    assert (back.timings, back.config, back.plausibility, back.meta) == (
        res.timings,
        res.config,
        res.plausibility,
        res.meta,
    )
    assert [s.name for s in back.stages] == ["camera", "refine"]
    s0, s1 = back.stages
    assert s0.hand_params is None and s0.losses == res.stages[0].losses and s0.iterations == 2
    _params_equal(s1.hand_params, res.stages[1].hand_params)
    assert (s1.metric_scale, s1.stop_reason, s1.seconds) == (0.07, "max_iters", 0.5)


# ----------------------------------------------------------------------------------------------
# corrupt / missing files
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda p: os.remove(p / "hand_mask.png"), "hand_mask.png is missing"),
        (lambda p: (p / "image.png").write_bytes(b"\x89PNG\r\n broken"), "image.png is not a"),
        (lambda p: os.remove(p / "object.ply"), "object.ply is missing"),
        (lambda p: (p / "object.ply").write_bytes(b"ply\nformat ascii 1.0\nend"), "object.ply"),
        (lambda p: (p / "input.json").write_text("{not json"), "input.json is not valid JSON"),
        (lambda p: os.remove(p / "input.json"), "input.json is missing"),
        (lambda p: _edit_json(p / "input.json", version=99), "schema version 99"),
        (lambda p: _edit_json(p / "input.json", schema="other"), "not an easyhoi.hoi_input"),
        (lambda p: _edit_json(p / "input.json", hand_params={"pose": []}), "input.json"),
        (lambda p: _edit_json(p / "input.json", hand_camera=None), "input.json"),
    ],
)
def test_load_hoi_input_names_the_bad_file(tmp_path, damage, message):
    save_hoi_input(_input(), tmp_path)
    damage(tmp_path)
    with pytest.raises(InvalidInputError, match=message):
        load_hoi_input(tmp_path)


def _edit_json(path, **changes):
    d = json.loads(path.read_text())
    d.update(changes)
    path.write_text(json.dumps(d))


def test_load_hoi_result_names_the_bad_file(tmp_path):
    save_hoi_result(_result(), tmp_path)
    os.remove(tmp_path / "hand.ply")
    with pytest.raises(InvalidInputError, match="hand.ply is missing"):
        load_hoi_result(tmp_path)
    save_hoi_result(_result(), tmp_path)
    _edit_json(tmp_path / "result.json", stages=[{"name": "x"}])
    with pytest.raises(InvalidInputError, match="result.json"):
        load_hoi_result(tmp_path)
    with pytest.raises(InvalidInputError, match="does not exist"):
        load_hoi_result(tmp_path / "nope")


# ----------------------------------------------------------------------------------------------
# atomic writes
# ----------------------------------------------------------------------------------------------


def test_atomic_write_replaces_and_leaves_no_temp(tmp_path):
    p = tmp_path / "a.txt"
    atomic_write_text(p, "old")
    atomic_write_bytes(p, b"new" * 1000)
    assert p.read_bytes() == b"new" * 1000
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


class _FailingFile:
    """Wraps a real file; the second write raises after the first chunk reached the disk."""

    def __init__(self, f):
        self.f, self.writes = f, 0

    def write(self, data):
        self.writes += 1
        if self.writes == 2:
            raise OSError("disk full (simulated)")
        n = self.f.write(data)
        self.f.flush()
        return n

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def test_failed_write_leaves_no_partial_file(tmp_path, monkeypatch):
    p = tmp_path / "big.bin"
    atomic_write_text(p, "previous complete content")
    data = bytes(range(256)) * 10000  # 2.56 MB: three chunks
    real_fdopen = os.fdopen
    opened = []

    def failing_fdopen(fd, *a, **k):
        opened.append(_FailingFile(real_fdopen(fd, *a, **k)))
        return opened[-1]

    monkeypatch.setattr(atomic.os, "fdopen", failing_fdopen)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(p, data)
    assert opened and opened[0].writes == 2  # the failure happened mid-write
    assert p.read_text() == "previous complete content"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["big.bin"]
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(tmp_path / "fresh.bin", data)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["big.bin"]


def test_failed_save_mid_folder_leaves_no_json(tmp_path, monkeypatch):
    import easyhoi.io.hoi_io as hoi_io

    def boom(mesh):
        raise RuntimeError("interrupted while encoding the mesh")

    monkeypatch.setattr(hoi_io, "mesh_to_ply_bytes", boom)
    with pytest.raises(RuntimeError, match="interrupted"):
        save_hoi_input(_input(), tmp_path)
    assert not (tmp_path / "input.json").exists()
    assert not any(x.name.startswith(".") for x in tmp_path.iterdir())
    with pytest.raises(InvalidInputError, match="input.json is missing"):
        load_hoi_input(tmp_path)
