"""OpenHand: mesh quality, proportions, rig consistency, gradients, semantics, mirroring."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand import openhand as oh
from easyhoi.hand.base import mirror_params, mirror_points
from easyhoi.hand.openhand import OpenHand, build_openhand_arrays, openhand_arrays
from easyhoi.structures import HandParams
from tests.helpers import assert_close


@pytest.fixture(scope="module")
def model() -> OpenHand:
    return OpenHand(dtype=torch.float64)


def _params(B=1, seed=0, scale=0.3, dtype=torch.float64, side="right") -> HandParams:
    g = torch.Generator().manual_seed(seed)
    r = lambda n, s: (torch.rand(B, n, generator=g, dtype=torch.float64) * 2 - 1) * s  # noqa: E731
    return HandParams(r(3, 1.0), r(3, 0.1), r(45, scale), r(10, 1.0), side).to(dtype)


def _mesh(verts: torch.Tensor, faces: torch.Tensor) -> trimesh.Trimesh:
    return trimesh.Trimesh(verts.detach().double().numpy(), faces.numpy(), process=False)


def test_mesh_is_closed_oriented_and_hand_sized(model):
    mesh = _mesh(model.v_template, model.faces)
    assert 1000 <= len(mesh.vertices) <= 3000
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 2  # one closed genus-0 surface
    assert 300e-6 <= mesh.volume <= 450e-6
    # Every face normal points away from the interior: a point just outside is not contained.
    c = mesh.triangles_center[::37] + 1e-4 * mesh.face_normals[::37]
    assert not mesh.contains(c).any()


def test_rest_proportions(model):
    v, j = model.shaped(torch.zeros(1, 10, dtype=torch.float64))
    tips = v[0, model.tip_vertex_ids]
    length = (tips[2] - j[0, 0]).norm().item()  # wrist to middle fingertip
    assert 0.18 <= length <= 0.19
    # MANO frame: fingers along -x, palm towards -y, thumb towards +z.
    assert (tips[1:, 0] < -0.14).all() and tips[0, 2] > 0.07
    knuckles = _mesh(model.v_template, model.faces).section([1, 0, 0], [-0.08, 0, 0]).vertices
    width = np.ptp(knuckles[knuckles[:, 2] < 0.045, 2])
    assert 0.078 <= width <= 0.086


def test_build_is_deterministic():
    a, b = build_openhand_arrays(), openhand_arrays()
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_disk_cache_round_trip(tmp_path, monkeypatch):
    monkeypatch.setenv("EASYHOI_CACHE", str(tmp_path))
    saved = openhand_arrays()
    oh.openhand_arrays.cache_clear()
    try:
        path = tmp_path / f"openhand-{oh.cache_key()}.npz"
        np.savez(path, **saved)
        loaded = openhand_arrays()
        for k in saved:
            np.testing.assert_array_equal(loaded[k], saved[k])
    finally:
        oh.openhand_arrays.cache_clear()


def test_zero_pose_gives_rest_mesh(model):
    out = model(HandParams.zeros(1, dtype=torch.float64))
    assert_close(out.vertices[0], model.v_template, atol=1e-12)
    _, j = model.shaped(torch.zeros(1, 10, dtype=torch.float64))
    assert_close(out.joints, j, atol=1e-12)
    assert out.keypoints.shape == (1, 21, 3)


def test_skin_weights_and_joints(model):
    w = model.skin_weights
    assert (w >= 0).all()
    assert_close(w.sum(1), torch.ones(len(w), dtype=w.dtype), atol=1e-12)
    assert (w.argmax(1).bincount(minlength=16) > 10).all()  # every bone drives some skin
    for k in (0, 1, 2, 3, 4, 5):
        for s in (-2.0, 2.0):
            betas = torch.zeros(1, 10, dtype=torch.float64)
            betas[0, k] = s
            v, j = model.shaped(betas)
            mesh = _mesh(v[0], model.faces)
            assert mesh.contains(j[0].numpy()).all(), (k, s)


def test_shape_directions(model):
    def shaped(k, s):
        b = torch.zeros(1, 10, dtype=torch.float64)
        b[0, k] = s
        v, j = model.shaped(b)
        return v[0], j[0]

    v0, j0 = shaped(0, 0.0)
    tip = model.tip_vertex_ids[2]
    v, j = shaped(0, 1.0)  # size: +5 % everywhere about the wrist
    assert_close(v, 1.05 * v0, atol=1e-12)
    assert_close(j, 1.05 * j0, atol=1e-12)
    v, j = shaped(1, 1.0)  # digits +5 % long, palm unchanged
    finger = (v0[tip] - j0[4]).norm()
    assert_close((v[tip] - j[4]).norm(), 1.05 * finger, atol=2e-4)
    assert_close(j[[0, 1, 4, 7, 10]], j0[[0, 1, 4, 7, 10]], atol=1e-4)
    v, _ = shaped(2, 1.0)  # palm wider
    assert (v[:, 2].max() - v[:, 2].min()) > (v0[:, 2].max() - v0[:, 2].min())
    assert (v[:, 0] - v0[:, 0]).abs().max() < 1e-12
    v, j = shaped(3, 1.0)  # fingers thicker: the middle finger's radius grows ~5 %
    dist = lambda vv, jj: (vv[tip - 0] - jj[6]).norm()  # noqa: E731
    assert dist(v, j) > dist(v0, j0)
    for k in range(6, 10):
        assert_close(shaped(k, 1.0)[0], v0, atol=0.0)


def test_gradients_match_finite_differences(model):
    p = _params(seed=1)
    sub = torch.arange(0, model.num_vertices, 97)

    def f(go, tr, pose, betas):
        out = model(HandParams(go, tr, pose, betas))
        return torch.cat([out.vertices[:, sub], out.joints], dim=1)

    inputs = tuple(t.clone().requires_grad_(True) for t in p.tensors().values())
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_index_flexion_moves_tip_to_palm_side(model):
    pose = torch.zeros(1, 45, dtype=torch.float64)
    pose[0, 2] = 0.6  # index1, +z
    rest = model(HandParams.zeros(1, dtype=torch.float64))
    bent = model(HandParams(torch.zeros(1, 3), torch.zeros(1, 3), pose).to(torch.float64))
    tip = model.tip_vertex_ids[1]
    dy = (bent.vertices[0, tip, 1] - rest.vertices[0, tip, 1]).item()
    assert dy < -0.02  # towards -y, the palm side
    others = [model.tip_vertex_ids[i] for i in (0, 2, 3, 4)]
    assert_close(bent.vertices[0, others], rest.vertices[0, others], atol=1e-9)


def test_flexing_90_degrees_keeps_the_mesh_intact(model):
    pose = torch.zeros(1, 45, dtype=torch.float64)
    for j in range(12):
        pose[0, 3 * j + 2] = np.pi / 2  # every finger joint flexed 90 degrees
    out = model(HandParams(torch.zeros(1, 3), torch.zeros(1, 3), pose).to(torch.float64))
    e = model.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    rest_len = (model.v_template[e[:, 0]] - model.v_template[e[:, 1]]).norm(dim=1)
    posed_len = (out.vertices[0, e[:, 0]] - out.vertices[0, e[:, 1]]).norm(dim=1)
    assert (posed_len / rest_len).max() < 2.5  # no torn (stretched) triangles
    vol0 = _mesh(model.v_template, model.faces).volume
    assert abs(_mesh(out.vertices[0], model.faces).volume / vol0 - 1) < 0.1


def test_global_orient_rotates_about_wrist(model):
    go = torch.tensor([[0.4, -1.1, 0.7]], dtype=torch.float64)
    z = torch.zeros(1, 3, dtype=torch.float64)
    out = model(HandParams(go, z, torch.zeros(1, 45, dtype=torch.float64)))
    assert_close(out.joints[0, 0], torch.zeros(3, dtype=torch.float64), atol=1e-12)
    R = axis_angle_to_matrix(go)[0]
    assert_close(out.vertices[0], model.v_template @ R.T, atol=1e-12)


def test_left_hand_is_mirrored_right_hand(model):
    left = _params(seed=3, side="left")
    out_l = model(left)
    out_r = model(mirror_params(left))
    assert_close(out_l.vertices, mirror_points(out_r.vertices), atol=1e-12)
    assert_close(out_l.keypoints, mirror_points(out_r.keypoints), atol=1e-12)
    assert _mesh(out_l.vertices[0], out_l.faces).volume > 0
    assert _mesh(out_r.vertices[0], out_r.faces).volume > 0


def test_batch_and_dtypes(model):
    p = _params(B=3, seed=4)
    out = model(p)
    for b in range(3):
        single = HandParams(*(t[b : b + 1] for t in p.tensors().values()))
        assert_close(out.vertices[b], model(single).vertices[0], atol=1e-12)
    out32 = OpenHand(dtype=torch.float32)(p.to(torch.float32))
    assert out32.vertices.dtype == torch.float32
    assert_close(out32.vertices, out.vertices, atol=1e-5)


def test_bad_input():
    with pytest.raises(InvalidInputError):
        OpenHand(dtype=torch.int64)
    with pytest.raises(InvalidInputError):
        OpenHand().shaped(torch.zeros(1, 7))
