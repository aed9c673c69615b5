"""Importers: HaMeR outputs (npz/json/pkl, left hands), mask PNGs, object meshes."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from easyhoi.errors import InvalidInputError, UnsafeFileError
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand.base import HandModel
from easyhoi.perception.importers import (
    crop_to_full_translation,
    load_hamer_hand,
    load_mask_png,
    load_object_mesh,
)
from easyhoi.structures import Camera, HandParams
from tests.helpers import assert_close


class TinyHand(HandModel):
    """Random rest geometry with rigid per-joint skinning: enough to compare posed vertices."""

    def __init__(self):
        super().__init__()
        g = torch.Generator().manual_seed(3)
        joints = torch.randn(16, 3, generator=g, dtype=torch.float64) * 0.05
        verts = joints.repeat(3, 1) + torch.randn(48, 3, generator=g, dtype=torch.float64) * 0.01
        self.register_buffer("rest_v", verts)
        self.register_buffer("rest_j", joints)
        self.register_buffer("skin_weights", torch.eye(16, dtype=torch.float64).repeat(3, 1))
        self.register_buffer("faces", torch.tensor([[0, 1, 2]]))
        self.register_buffer("tip_vertex_ids", torch.arange(16, 21))

    def shaped(self, betas):
        B = betas.shape[0]
        return self.rest_v.expand(B, -1, -1), self.rest_j.expand(B, -1, -1)


def hamer_record(seed=0, is_right=1, W=640, H=480):
    g = torch.Generator().manual_seed(seed)
    aa_root = torch.randn(1, 3, generator=g, dtype=torch.float64)
    aa_pose = 0.4 * torch.randn(15, 3, generator=g, dtype=torch.float64)
    rec = {
        "global_orient": axis_angle_to_matrix(aa_root).numpy(),  # (1, 3, 3)
        "hand_pose": axis_angle_to_matrix(aa_pose).numpy(),  # (15, 3, 3)
        "betas": torch.randn(10, generator=g, dtype=torch.float64).numpy(),
        "pred_cam_t_full": np.array([0.05, -0.02, 0.9]),
        "is_right": np.array(float(is_right)),
    }
    return rec, aa_root, aa_pose


@pytest.mark.parametrize("fmt", ["npz", "json", "dict"])
def test_right_hand_rotations_recovered(tmp_path, fmt):
    rec, aa_root, aa_pose = hamer_record()
    if fmt == "npz":
        src = tmp_path / "hand.npz"
        np.savez(src, **rec)
    elif fmt == "json":
        src = tmp_path / "hand.json"
        nested = {"pred_mano_params": {k: rec[k].tolist() for k in ("global_orient",
                  "hand_pose", "betas")}, "cam_t": rec["pred_cam_t_full"].tolist(),
                  "right": 1}  # fmt: skip
        src.write_text(json.dumps(nested))
    else:
        src = rec
    params, cam = load_hamer_hand(src, (640, 480))
    assert params.side == "right" and params.pose.dtype == torch.float32
    assert_close(params.global_orient[0], aa_root[0], atol=1e-5)
    assert_close(params.pose[0], aa_pose.reshape(45), atol=1e-5)
    assert_close(params.betas[0], rec["betas"], atol=1e-6)
    assert_close(params.transl[0], rec["pred_cam_t_full"], atol=1e-7)
    assert_close(cam.K, Camera.hamer_convention(640, 480).K)
    assert float(cam.fx) == pytest.approx(5000 / 256 * 640)
    assert_close(cam.R, torch.eye(3)) and float(cam.t.abs().max()) == 0


def test_batched_file_and_axis_angle_layout(tmp_path):
    recs = [hamer_record(seed=s, is_right=s % 2) for s in range(3)]
    batch = {k: np.stack([r[0][k] for r in recs]) for k in recs[0][0]}
    batch["img_size"] = np.array([[640, 480]] * 3)
    np.savez(tmp_path / "b.npz", **batch)
    p, _ = load_hamer_hand(tmp_path / "b.npz", index=2)  # image size from the file
    assert p.side == "left" and p.batch_size == 1
    flip = torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64)
    assert_close(p.global_orient[0], recs[2][1][0] * flip, atol=1e-5)
    # axis-angle input (B, 45) is accepted as well
    aa = {"global_orient": recs[0][1].numpy(), "hand_pose": recs[0][2].reshape(1, 45).numpy(),
          "betas": np.zeros(10), "cam_t": np.ones(3)}  # fmt: skip
    p0, _ = load_hamer_hand(aa, (10, 10))
    assert_close(p0.pose[0], recs[0][2].reshape(45), atol=1e-6)
    with pytest.raises(InvalidInputError, match="out of range"):
        load_hamer_hand(tmp_path / "b.npz", index=5)
    with pytest.raises(InvalidInputError, match="differs"):
        load_hamer_hand(tmp_path / "b.npz", (100, 100))


def test_left_hand_matches_mirrored_hamer_vertices():
    """hand(left params) == mirror_x(right hand(HaMeR rotations, transl 0)) + cam_t."""
    rec, aa_root, aa_pose = hamer_record(seed=5, is_right=0)
    params, _ = load_hamer_hand(rec, (640, 480))
    assert params.side == "left"
    model = TinyHand()
    ours = model(params.to(torch.float64)).vertices[0]
    right = HandParams(aa_root, torch.zeros(1, 3, dtype=torch.float64), aa_pose.reshape(1, 45),
                       torch.as_tensor(rec["betas"])[None])  # fmt: skip
    hamer = model(right).vertices[0] * torch.tensor([-1.0, 1, 1], dtype=torch.float64)
    hamer = hamer + torch.as_tensor(rec["pred_cam_t_full"])
    assert_close(ours, hamer, atol=1e-5)
    # and the same record as a right hand is NOT that
    rec["is_right"] = np.array(1.0)
    pr, _ = load_hamer_hand(rec, (640, 480))
    assert (model(pr.to(torch.float64)).vertices[0] - hamer).abs().max() > 1e-2


def test_crop_camera_converted_to_full_image():
    """A point projected with the derived full camera lands where the crop camera puts it."""
    W, H, f = 640, 480, 5000 / 256 * 640
    s, tx, ty, cx, cy, b = 0.8, 0.1, -0.05, 400.0, 200.0, 180.0
    t = crop_to_full_translation(np.array([s, tx, ty]), np.array([cx, cy]), b, (W, H), f)
    X = np.array([0.0, 0.0, 0.0])  # the MANO origin
    u_full = f * (X[0] + t[0]) / (X[2] + t[2]) + W / 2
    v_full = f * (X[1] + t[1]) / (X[2] + t[2]) + H / 2
    u_crop = cx + b / 2 * s * (X[0] + tx)
    v_crop = cy + b / 2 * s * (X[1] + ty)
    assert u_full == pytest.approx(u_crop) and v_full == pytest.approx(v_crop)
    rec, _, _ = hamer_record()
    del rec["pred_cam_t_full"]
    rec.update(pred_cam=np.array([s, tx, ty]), box_center=np.array([cx, cy]), box_size=b)
    p, _ = load_hamer_hand(rec, (W, H))
    assert_close(p.transl[0], t, atol=1e-6, rtol=1e-6)


def test_missing_and_bad_keys(tmp_path):
    rec, _, _ = hamer_record()
    for key in ("hand_pose", "betas", "global_orient"):
        bad = {k: v for k, v in rec.items() if k != key}
        with pytest.raises(InvalidInputError, match=key):
            load_hamer_hand(bad, (64, 64))
    no_cam = {k: v for k, v in rec.items() if k != "pred_cam_t_full"}
    with pytest.raises(InvalidInputError, match="camera translation"):
        load_hamer_hand(no_cam, (64, 64))
    with pytest.raises(InvalidInputError, match="image_size"):
        load_hamer_hand(rec)
    skew = dict(rec, global_orient=rec["global_orient"] * 2)
    with pytest.raises(InvalidInputError, match="not rotations"):
        load_hamer_hand(skew, (64, 64))
    nan = dict(rec, betas=np.full(10, np.nan))
    with pytest.raises(InvalidInputError, match="NaN"):
        load_hamer_hand(nan, (64, 64))
    with pytest.raises(InvalidInputError, match="not found"):
        load_hamer_hand(tmp_path / "nope.npz", (64, 64))
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(InvalidInputError, match="unsupported"):
        load_hamer_hand(tmp_path / "x.txt", (64, 64))


class _Evil:
    def __reduce__(self):
        import os

        return (os.system, ("echo pwned > /dev/null",))


def test_pickle_safe_load_and_refusal(tmp_path):
    rec, aa_root, _ = hamer_record()
    good = tmp_path / "hand.pkl"
    good.write_bytes(pickle.dumps(rec))
    p, _ = load_hamer_hand(good, (640, 480))
    assert_close(p.global_orient[0], aa_root[0], atol=1e-5)
    evil = tmp_path / "evil.pkl"
    evil.write_bytes(pickle.dumps(dict(rec, betas=_Evil())))
    with pytest.raises(UnsafeFileError, match="system"):
        load_hamer_hand(evil, (640, 480))
    # object arrays in an npz need pickle: refused
    np.savez(tmp_path / "obj.npz", betas=np.array([{"a": 1}], dtype=object))
    with pytest.raises(UnsafeFileError):
        load_hamer_hand(tmp_path / "obj.npz", (640, 480))


@pytest.mark.parametrize("style", ["0_255", "0_1", "inverted"])
def test_mask_png_polarity(tmp_path, style):
    m = np.zeros((40, 60), bool)
    m[10:30, 20:45] = True
    arr = {"0_255": m * 255, "0_1": m * 1, "inverted": (~m) * 255}[style].astype(np.uint8)
    Image.fromarray(arr).save(tmp_path / "m.png")
    out = load_mask_png(tmp_path / "m.png", size=(60, 40))
    np.testing.assert_array_equal(out, m)
    with pytest.raises(InvalidInputError):
        load_mask_png(tmp_path / "m.png", size=(40, 60))


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
def test_object_mesh_round_trip(tmp_path, suffix):
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    path = tmp_path / f"obj{suffix}"
    box.export(path)
    mesh = load_object_mesh(path)
    info = mesh.metadata["easyhoi"]
    assert mesh.volume == pytest.approx(0.006, rel=1e-6)
    np.testing.assert_allclose(mesh.extents, [0.1, 0.2, 0.3], atol=1e-7)
    assert info["num_faces"] == 12
    if suffix != ".obj":  # OBJ export may split vertices per face normal
        assert info["watertight"]


def test_object_mesh_scene_merged_and_open_reported(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.icosphere(subdivisions=1)
    b.apply_translation([3, 0, 0])
    scene = trimesh.Scene([a, b])
    scene.export(tmp_path / "s.glb")
    mesh = load_object_mesh(tmp_path / "s.glb")
    assert len(mesh.faces) == 12 + len(b.faces)
    assert mesh.bounds[1][0] == pytest.approx(4.0, abs=1e-6)
    open_box = trimesh.Trimesh(a.vertices, a.faces[:-1])
    open_box.export(tmp_path / "open.ply")
    assert load_object_mesh(tmp_path / "open.ply").metadata["easyhoi"]["watertight"] is False
    with pytest.raises(InvalidInputError):
        load_object_mesh(tmp_path / "missing.obj")


def test_object_mesh_limits(tmp_path, monkeypatch):
    import easyhoi.perception.importers as imp

    path = tmp_path / "ball.ply"
    trimesh.creation.icosphere(subdivisions=2).export(path)  # 320 faces
    assert len(load_object_mesh(path).faces) == 320
    monkeypatch.setattr(imp, "MAX_OBJECT_FACES", 319)
    with pytest.raises(InvalidInputError, match="320 faces; at most 319"):
        load_object_mesh(path)
    monkeypatch.setattr(imp, "MAX_OBJECT_FILE_BYTES", path.stat().st_size - 1)
    with pytest.raises(InvalidInputError, match="decimate"):
        load_object_mesh(path)
