"""ICP: round trips for every mode, point-to-plane, partial overlap, trimming, normal filter."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.icp import align_translation_scale, icp
from easyhoi.geometry.sampling import sample_surface
from easyhoi.geometry.transforms import axis_angle_to_matrix
from tests.helpers import assert_close

R_TRUE = axis_angle_to_matrix(torch.tensor([0.1, -0.12, 0.08], dtype=torch.float64)).numpy()
T_TRUE = np.array([0.05, -0.08, 0.06])
S_TRUE = 1.1


def _l_shape():
    """Asymmetric L-shaped solid (two boxes), about 1 unit across."""
    a = trimesh.creation.box(extents=[1.0, 0.4, 0.3])
    b = trimesh.creation.box(extents=[0.3, 1.0, 0.2])
    b.apply_translation([0.35, 0.3, 0.05])
    return trimesh.util.concatenate([a, b])


@pytest.fixture(scope="module")
def cloud():
    pts, _, nrm = sample_surface(_l_shape(), 6000, seed=0)
    center = pts.mean(axis=0)
    return pts - center, nrm


def _source_for(tgt, mode, sub):
    R = R_TRUE if "rigid" in mode else np.eye(3)
    s = S_TRUE if "scale" in mode else 1.0
    return ((tgt[sub] - T_TRUE) @ R) / s, R, s


@pytest.mark.parametrize("mode", ["translation", "translation_scale", "rigid", "rigid_scale"])
def test_round_trip_every_mode(cloud, mode):
    tgt, _ = cloud
    sub = np.random.default_rng(1).choice(len(tgt), 2000, replace=False)
    src, R, s = _source_for(tgt, mode, sub)
    res = icp(src, tgt, mode=mode, max_iters=200, tol=1e-12)
    assert res.converged
    assert_close(res.R, R, atol=1e-8)
    assert_close(res.t, T_TRUE, atol=1e-8)
    assert abs(res.s - s) < 1e-8
    assert_close(res.transformed, tgt[sub], atol=1e-8)
    assert_close(res.apply(src), res.transformed, atol=1e-12)
    assert res.rmse[0] > 0.02 and res.rmse[-1] < 1e-8
    assert len(res.rmse) == res.iterations + 1
    # the modes without rotation leave R untouched, the modes without scale leave s at 1
    if "rigid" not in mode:
        assert np.array_equal(res.R, np.eye(3))
    if "scale" not in mode:
        assert res.s == 1.0


def test_round_trip_on_scanned_object(shared_data):
    mesh = trimesh.load(shared_data / "objects" / "plastic_banana.obj", force="mesh")
    tgt, _, _ = sample_surface(mesh, 5000, seed=0)
    tgt = (tgt - tgt.mean(axis=0)) / 0.1
    sub = np.random.default_rng(0).choice(len(tgt), 1500, replace=False)
    src, R, s = _source_for(tgt, "rigid_scale", sub)
    res = icp(src, tgt, mode="rigid_scale", max_iters=300, tol=1e-12)
    assert_close(res.R, R, atol=1e-7)
    assert abs(res.s - s) < 1e-7


@pytest.mark.parametrize("mode", ["translation", "rigid"])
def test_point_to_plane_recovers_transform_from_a_dense_surface(mode):
    mesh = trimesh.creation.icosphere(subdivisions=4)
    mesh.vertices *= [1.0, 0.6, 0.35]
    tgt = np.asarray(mesh.vertices)
    R = R_TRUE if mode == "rigid" else np.eye(3)
    src = (tgt - T_TRUE) @ R
    res = icp(
        src, tgt, mode=mode, point_to_plane=True, target_normals=mesh.vertex_normals, tol=1e-14
    )
    assert_close(res.R, R, atol=1e-9)
    assert_close(res.t, T_TRUE, atol=1e-9)
    # point-to-point on the same smooth, regularly sampled shape stalls short of the answer
    p2p = icp(src, tgt, mode=mode, tol=1e-14)
    assert np.abs(p2p.t - T_TRUE).max() > 1e-3


def test_partial_overlap_iterative_icp_beats_one_centroid_shift(cloud):
    """Source covers one end of the target: matching centroids is wrong, ICP is right."""
    tgt, _ = cloud
    part = tgt[tgt[:, 0] < -0.2]
    offset = np.array([0.04, -0.03, 0.02])
    src = part - offset
    centroid_shift = tgt.mean(axis=0) - src.mean(axis=0)
    assert np.linalg.norm(centroid_shift - offset) > 0.2
    res = icp(src, tgt, mode="translation", tol=1e-12)
    assert_close(res.t, offset, atol=1e-9)
    # the first iteration alone (one nearest-neighbour shift) is not the answer either
    one = icp(src, tgt, mode="translation", max_iters=1)
    assert np.linalg.norm(one.t - offset) > 1e-3
    assert res.iterations > 1


def test_trimming_rejects_outliers(cloud):
    tgt, _ = cloud
    rng = np.random.default_rng(2)
    sub = rng.choice(len(tgt), 1600, replace=False)
    src = tgt[sub] - T_TRUE
    junk = rng.uniform(-3.0, 3.0, size=(400, 3))
    src_noisy = np.concatenate([src, junk])
    plain = icp(src_noisy, tgt, mode="translation", tol=1e-12)
    trimmed = icp(src_noisy, tgt, mode="translation", tol=1e-12, trim_fraction=0.3)
    assert np.abs(plain.t - T_TRUE).max() > 1e-2
    assert_close(trimmed.t, T_TRUE, atol=1e-8)


def test_normal_filter_picks_the_right_side_of_a_thin_plate():
    g = np.linspace(-0.2, 0.2, 41)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    top = np.c_[xy, np.full(len(xy), 0.01)]
    bottom = np.c_[xy, np.full(len(xy), -0.01)]
    tgt = np.concatenate([top, bottom])
    tn = np.concatenate([np.tile([0, 0, 1.0], (len(xy), 1)), np.tile([0, 0, -1.0], (len(xy), 1))])
    inner = np.abs(xy).max(axis=1) < 0.15
    src = top[inner] + [0.0, 0.0, -0.012]  # now nearer the bottom sheet than its own
    sn = np.tile([0, 0, 1.0], (len(src), 1))
    wrong = icp(src, tgt, mode="translation", tol=1e-12)
    right = icp(
        src,
        tgt,
        mode="translation",
        tol=1e-12,
        source_normals=sn,
        target_normals=tn,
        normal_max_angle=np.deg2rad(60),
    )
    assert abs(wrong.t[2] - (-0.008)) < 1e-9  # snapped onto the wrong (bottom) sheet
    assert abs(right.t[2] - 0.012) < 1e-9


def test_align_translation_scale_recovers_similarity_without_rotation(cloud):
    gt, _ = cloud
    pred = (gt[::3] - T_TRUE) / S_TRUE * 1.0 + 0.5  # shifted and shrunk copy
    res = align_translation_scale(pred, gt)
    assert np.array_equal(res.R, np.eye(3))
    assert_close(res.transformed, gt[::3], atol=1e-8)
    assert abs(res.s - S_TRUE) < 1e-8


def test_icp_accepts_torch_and_validates_input(cloud):
    tgt, _ = cloud
    res = icp(torch.as_tensor(tgt[:100]), torch.as_tensor(tgt), mode="translation")
    assert res.rmse[0] == 0.0 and res.converged
    with pytest.raises(InvalidInputError, match=r"\(N, 3\)"):
        icp(tgt[:, :2], tgt)
    with pytest.raises(InvalidInputError, match="mode"):
        icp(tgt, tgt, mode="affine")
    with pytest.raises(InvalidInputError, match="point_to_plane"):
        icp(tgt, tgt, mode="rigid_scale", point_to_plane=True, target_normals=tgt)
    with pytest.raises(InvalidInputError, match="target_normals"):
        icp(tgt, tgt, mode="rigid", point_to_plane=True)
    with pytest.raises(InvalidInputError, match="trim_fraction"):
        icp(tgt, tgt, trim_fraction=1.0)
    with pytest.raises(InvalidInputError, match="NaN"):
        icp(np.full((3, 3), np.nan), tgt)
