"""MANOHand on synthetic MANO files: loading, schema errors, forward vs a naive reference,
gradients, the closed mesh, pose PCA and MANO_LEFT conversion."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.hand.mano import (
    FINGERTIP_CONVENTIONS,
    MANO_ENV_VAR,
    MANOHand,
    MANONotFoundError,
    find_mano_file,
)
from easyhoi.hand.safe_pickle import load_mano_pickle
from easyhoi.structures import JOINT_PARENTS, OPENPOSE_ORDER, HandParams
from easyhoi.testing.mano_synth import synthetic_mano_dict, write_mano_dict, write_synthetic_mano
from tests.helpers import assert_close


@pytest.fixture(scope="module")
def mano_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("mano")
    write_synthetic_mano(d, seed=0)
    return d


@pytest.fixture(scope="module")
def model(mano_dir):
    return MANOHand(mano_dir)


def random_params(B=2, seed=0, scale=0.6):
    g = torch.Generator().manual_seed(seed)
    r = lambda n, s: s * torch.randn(B, n, generator=g, dtype=torch.float64)  # noqa: E731
    return HandParams(r(3, 1.0), r(3, 0.1), r(45, scale), r(10, 1.0))


# ----------------------------------------------------------------------------------------------
# Naive reference MANO (numpy, loops)
# ----------------------------------------------------------------------------------------------


def rodrigues(aa):
    th = np.linalg.norm(aa)
    if th < 1e-12:
        return np.eye(3)
    k = aa / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.cos(th) * np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * np.outer(k, k)


def naive_mano(data, go, transl, pose, betas, tips=FINGERTIP_CONVENTIONS["smplx"]):
    V = data["v_template"].shape[0]
    Jreg = data["J_regressor"].toarray()
    v_shaped = np.array([data["v_template"][v] + data["shapedirs"][v] @ betas for v in range(V)])
    J = np.array([sum(Jreg[j, v] * v_shaped[v] for v in np.nonzero(Jreg[j])[0]) for j in range(16)])
    full = np.concatenate([go, pose]).reshape(16, 3)
    R = [rodrigues(a) for a in full]
    feat = np.concatenate([(R[j] - np.eye(3)).ravel() for j in range(1, 16)])
    v_posed = np.array([v_shaped[v] + data["posedirs"][v] @ feat for v in range(V)])
    G = [None] * 16
    for j in range(16):
        local = np.eye(4)
        local[:3, :3] = R[j]
        p = JOINT_PARENTS[j]
        local[:3, 3] = J[j] if p < 0 else J[j] - J[p]
        G[j] = local if p < 0 else G[p] @ local
    A = []
    for j in range(16):
        T = np.eye(4)
        T[:3, 3] = -J[j]
        A.append(G[j] @ T)
    verts = np.zeros((V, 3))
    for v in range(V):
        M = sum(data["weights"][v, j] * A[j] for j in range(16))
        verts[v] = (M @ np.r_[v_posed[v], 1.0])[:3] + transl
    joints = np.array([G[j][:3, 3] + transl for j in range(16)])
    kp = np.concatenate([joints, verts[list(tips)]])[list(OPENPOSE_ORDER)]
    return verts, joints, kp


def test_synthetic_file_loads_without_chumpy(mano_dir):
    assert "chumpy" not in sys.modules
    data = load_mano_pickle(mano_dir / "MANO_RIGHT.pkl")
    assert "chumpy" not in sys.modules
    assert isinstance(data["shapedirs"], np.ndarray) and data["shapedirs"].shape == (778, 3, 10)
    assert data["J_regressor"].shape == (16, 778) and data["J_regressor"].format == "csc"
    assert data["J"].shape == (16, 3) and data["bs_style"] == "lbs"
    ref = synthetic_mano_dict(seed=0)
    for k in ("v_template", "shapedirs", "posedirs", "weights", "hands_mean", "J"):
        np.testing.assert_array_equal(data[k], ref[k])


@pytest.mark.parametrize(
    "edit, word",
    [
        (lambda d: d.pop("posedirs"), "posedirs"),
        (lambda d: d.__setitem__("weights", d["weights"][:, :15]), "weights"),
        (lambda d: d.__setitem__("v_template", d["v_template"][:700]), "v_template"),
        (lambda d: d.__setitem__("hands_mean", "not an array"), "hands_mean"),
        (lambda d: d["kintree_table"].__setitem__((0, 5), 3), "kintree_table"),
    ],
)
def test_schema_errors_name_the_key(tmp_path, edit, word):
    data = synthetic_mano_dict(seed=1)
    edit(data)
    write_mano_dict(data, tmp_path / "MANO_RIGHT.pkl")
    with pytest.raises(InvalidInputError, match=word):
        MANOHand(tmp_path)


def test_missing_file_explains_the_fix(tmp_path, monkeypatch):
    with pytest.raises(MANONotFoundError, match="mano-dir") as exc:
        MANOHand(tmp_path / "nope" / "MANO_RIGHT.pkl")
    assert "mano.is.tue.mpg.de" in str(exc.value)
    with pytest.raises(MANONotFoundError, match="MANO_RIGHT.pkl"):
        MANOHand(tmp_path)  # an empty folder
    monkeypatch.delenv(MANO_ENV_VAR, raising=False)
    with pytest.raises(MANONotFoundError, match=MANO_ENV_VAR):
        MANOHand(None)
    with pytest.raises(InvalidInputError, match="not a readable"):
        (tmp_path / "MANO_RIGHT.pkl").write_bytes(b"garbage")
        MANOHand(tmp_path)


def test_env_var_and_models_subfolder(mano_dir, tmp_path, monkeypatch):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "MANO_RIGHT.pkl").write_bytes((mano_dir / "MANO_RIGHT.pkl").read_bytes())
    monkeypatch.setenv(MANO_ENV_VAR, str(tmp_path))
    assert find_mano_file() == tmp_path / "models" / "MANO_RIGHT.pkl"
    assert MANOHand().faces.shape == (1552, 3)


@pytest.mark.parametrize("flat", [True, False])
def test_forward_matches_naive_reference(mano_dir, flat):
    model = MANOHand(mano_dir, flat_hand_mean=flat)
    data = load_mano_pickle(mano_dir / "MANO_RIGHT.pkl")
    p = random_params(B=2, seed=3)
    out = model(p)
    for b in range(2):
        pose = p.pose[b].numpy() + (0 if flat else data["hands_mean"])
        args = [t[b].numpy() for t in (p.global_orient, p.transl)] + [pose, p.betas[b].numpy()]
        v, j, k = naive_mano(data, *args)
        assert_close(out.vertices[b], v, atol=1e-6)
        assert_close(out.joints[b], j, atol=1e-6)
        assert_close(out.keypoints[b], k, atol=1e-6)
    # float32 parameters give float32 output close to the float64 one
    out32 = model(p.to(torch.float32))
    assert out32.vertices.dtype == torch.float32
    assert_close(out32.vertices, out.vertices, atol=1e-5)


def test_gradcheck_vertices(model):
    p = random_params(B=1, seed=5)
    sub = torch.arange(0, 778, 97)
    inputs = tuple(t.clone().requires_grad_(True) for t in p.tensors().values())

    def f(go, transl, pose, betas):
        out = model(HandParams(go, transl, pose, betas))
        return out.vertices[:, sub], out.keypoints

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, fast_mode=True)
    # full Jacobian on three vertices (every input column checked)
    three = lambda *a: model(HandParams(*a)).vertices[:, [744, 10, 400]]  # noqa: E731
    assert torch.autograd.gradcheck(three, inputs, eps=1e-6, atol=1e-6)


def test_closed_mesh(model):
    assert model.faces.shape == (1552, 3) and model.faces_open.shape == (1538, 3)
    assert [len(loop) for loop in model.boundary_loops] == [16]
    assert torch.equal(model.faces[:1538], model.faces_open)
    out = model(random_params(B=1, seed=2, scale=0.2).to(torch.float64))
    mesh = out.to_trimesh()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    rest = trimesh.Trimesh(model.v_template.numpy(), model.faces.numpy(), process=False)
    assert rest.is_watertight and rest.volume > 0


def test_pca_round_trip(model):
    g = torch.Generator().manual_seed(0)
    pose = 0.5 * torch.randn(3, 45, generator=g, dtype=torch.float64)
    for side in ("right", "left"):
        coeffs = model.pca_from_pose(pose, 45, side=side)
        assert_close(model.pose_from_pca(coeffs, side=side), pose, atol=1e-10)
    c = torch.randn(2, 6, generator=g, dtype=torch.float64)
    expected = c @ model.hands_components[:6]
    assert_close(model.pose_from_pca(c), expected, atol=1e-12)
    assert_close(model.pca_from_pose(expected, 6), c, atol=1e-10)
    with pytest.raises(InvalidInputError):
        model.pose_from_pca(torch.zeros(2, 46))


def test_fingertip_conventions(mano_dir, model):
    assert model.tip_vertex_ids.tolist() == [744, 320, 443, 554, 671]
    alt = MANOHand(mano_dir, tips="alternate")
    assert alt.tip_vertex_ids.tolist() == [745, 317, 444, 556, 673]
    out = alt(random_params(B=1))
    assert_close(out.keypoints[0, [4, 8, 12, 16, 20]], out.vertices[0, [745, 317, 444, 556, 673]])
    with pytest.raises(InvalidInputError, match="fingertip"):
        MANOHand(mano_dir, tips="nope")
    with pytest.raises(InvalidInputError):
        MANOHand(mano_dir, tips=(1, 2, 3))


def make_left_dict(right: dict) -> dict:
    """A MANO_LEFT-like dictionary built entry by entry from a right one: the mirror image, with
    the released files' shapedirs (x sign not mirrored)."""
    left = dict(right)
    m = [-1.0, 1.0, 1.0]
    left["v_template"] = right["v_template"] * np.array(m)
    left["shapedirs"] = right["shapedirs"].copy()  # the known MANO_LEFT x-sign error
    P = np.empty_like(right["posedirs"])
    for c in range(3):
        for k in range(135):
            a, b = (k % 9) // 3, k % 3
            P[:, c, k] = m[c] * m[a] * m[b] * right["posedirs"][:, c, k]
    left["posedirs"] = P
    left["f"] = right["f"][:, ::-1].copy()
    flip = np.tile([1.0, -1.0, -1.0], 15)
    left["hands_components"] = right["hands_components"] * flip
    left["hands_mean"] = right["hands_mean"] * flip
    return left


def test_left_file_is_converted(tmp_path, mano_dir, model):
    right = load_mano_pickle(mano_dir / "MANO_RIGHT.pkl")
    left = make_left_dict(right)
    write_mano_dict(left, tmp_path / "MANO_LEFT.pkl")
    lm = MANOHand(tmp_path / "MANO_LEFT.pkl", flat_hand_mean=False)
    assert lm.source_side == "left"
    rm = MANOHand(mano_dir, flat_hand_mean=False)
    for name in ("v_template", "shapedirs", "posedirs", "hands_components", "hands_mean"):
        assert_close(getattr(lm, name), getattr(rm, name), atol=1e-12, msg=name)
    p = random_params(B=1, seed=8)
    assert_close(lm(p).vertices, rm(p).vertices, atol=1e-12)
    # the file itself is a true left model: naive MANO on it (x of shapedirs fixed) with
    # left-hand parameters equals the right model's left-hand output
    fixed = dict(left, shapedirs=left["shapedirs"] * np.array([-1.0, 1, 1])[:, None])
    lp = HandParams(p.global_orient, p.transl, p.pose, p.betas, side="left")
    args = [t[0].numpy() for t in (lp.global_orient, lp.transl)]
    v, _, _ = naive_mano(fixed, *args, lp.pose[0].numpy() + left["hands_mean"], lp.betas[0].numpy())
    assert_close(rm(lp).vertices[0], v, atol=1e-6)
