"""Chamfer distance / F-score against analytic answers (docs/method.md section 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.metrics.object import aggregate_fscore, align_points, chamfer_fscore
from tests.helpers import assert_close


def _plane(size: float = 0.1, z: float = 0.0) -> trimesh.Trimesh:
    """A size x size square in the plane z (metres), two triangles."""
    h = size / 2
    v = np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], dtype=np.float64)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def _shifted(mesh: trimesh.Trimesh, offset) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices + np.asarray(offset), mesh.faces, process=False)


def test_identical_meshes_give_zero_and_perfect_fscore():
    m = trimesh.creation.icosphere(3, radius=0.05)
    for align in ("none", "translation_scale", "rigid"):
        r = chamfer_fscore(m, m, n_samples=5000, align=align)
        assert r.chamfer == pytest.approx(0.0, abs=1e-12)
        assert r.f_at(5) == 1.0 and r.f_at(10) == 1.0


def test_plane_shifted_along_normal_gives_two_d_squared():
    # Two parallel 10 cm squares d = 1 cm apart: every nearest distance is d. Both meshes are
    # sampled with the same seed and have the same triangle areas, so the in-plane positions
    # coincide and raw C.D. = d^2 + d^2 up to rounding.
    d_cm = 1.0
    gt = _plane()
    pred = _shifted(gt, [0, 0, d_cm / 100])
    raw = chamfer_fscore(pred, gt, align="none", convention="raw")
    assert raw.chamfer == pytest.approx(2 * d_cm**2, rel=1e-9)
    # independent samples add the in-plane nearest-sample offset, E[r^2] = 1 / (pi * density)
    # (the same square triangulated along the other diagonal gives independent samples)
    other_diag = trimesh.Trimesh(gt.vertices, [[0, 1, 3], [1, 2, 3]], process=False)
    other = chamfer_fscore(pred, other_diag, align="none", convention="raw")
    lateral = 2 / (math.pi * 30000 / 100.0)  # cm^2, both directions: 0.0021
    assert other.chamfer - 2 * d_cm**2 == pytest.approx(lateral, abs=3e-4)
    moho = chamfer_fscore(pred, gt, align="none", convention="moho")
    assert moho.chamfer == pytest.approx(raw.chamfer / 10, rel=1e-12)
    assert moho.alignment.mode == "none" and moho.n_samples == 30000


def test_sphere_shifted_matches_analytic_value():
    # Concentric spheres of radii R and R + d: every nearest distance is d -> raw C.D. = 2 d^2.
    gt = trimesh.creation.icosphere(5, radius=0.05)
    pred = trimesh.Trimesh(gt.vertices * (0.055 / 0.05), gt.faces, process=False)
    r = chamfer_fscore(pred, gt, n_samples=20000, align="none", convention="raw")
    assert r.chamfer == pytest.approx(2 * 0.5**2, rel=0.03)


def test_alignment_recovers_scaled_and_shifted_copy():
    gt = trimesh.creation.capsule(height=0.08, radius=0.03, count=[16, 16])
    pred = trimesh.Trimesh(gt.vertices * 1.7 + [0.2, -0.1, 0.05], gt.faces, process=False)
    none = chamfer_fscore(pred, gt, n_samples=8000, align="none")
    aligned = chamfer_fscore(pred, gt, n_samples=8000, align="translation_scale")
    assert none.chamfer > 10.0
    assert aligned.chamfer < 1e-8
    assert aligned.alignment.scale == pytest.approx(1 / 1.7, rel=1e-6)
    assert_close(aligned.alignment.translation, -np.array([0.2, -0.1, 0.05]) / 1.7, atol=1e-6)
    assert aligned.f_at(5) == pytest.approx(1.0)


def test_icp_refines_beyond_moment_matching():
    # A sphere with a bump: centroid / RMS matching alone is biased; ICP must fix the scale.
    rng = np.random.default_rng(0)
    target = rng.normal(size=(3000, 3))
    target /= np.linalg.norm(target, axis=1, keepdims=True)
    source = (target[:2000] - 0.3) / 2.0  # partial, shifted, scaled copy
    a = align_points(source, target, "translation_scale")
    moved = a.apply(source)
    assert a.scale == pytest.approx(2.0, rel=1e-3)
    assert np.abs(moved - target[:2000]).max() < 1e-3


def test_rigid_alignment_recovers_rotation():
    gt = trimesh.creation.box((0.1, 0.06, 0.03))
    angle = np.radians(10)
    R = trimesh.transformations.rotation_matrix(angle, [0, 0, 1])[:3, :3]
    pred = trimesh.Trimesh(gt.vertices @ R.T + [0.01, 0.0, 0.0], gt.faces, process=False)
    r = chamfer_fscore(pred, gt, n_samples=5000, align="rigid")
    assert r.chamfer < 1e-6
    assert_close(r.alignment.rotation, R.T, atol=1e-5)


def test_fscore_thresholds():
    gt = _plane()
    near = chamfer_fscore(_shifted(gt, [0, 0, 0.003]), gt, align="none")
    far = chamfer_fscore(_shifted(gt, [0, 0, 0.012]), gt, align="none")
    assert near.f_at(5) > 0.99 and near.f_at(10) > 0.99
    assert near.precision[5.0] > 0.99 and near.recall[5.0] > 0.99
    assert far.f_at(5) == 0.0 and far.f_at(10) < 0.01
    with pytest.raises(InvalidInputError, match="available"):
        near.f_at(7)


def test_aggregate_fscore_with_and_without_skipping():
    s = aggregate_fscore([0.0, 0.5, 0.25, 0.0])
    assert s.mean_all == pytest.approx(0.1875)
    assert s.mean_skip_zero == pytest.approx(0.375)
    assert (s.n_total, s.n_skipped) == (4, 2)
    gt = _plane()
    res = [chamfer_fscore(_shifted(gt, [0, 0, z]), gt, n_samples=2000, align="none") for z in
           (0.0, 0.02)]  # fmt: skip
    s2 = aggregate_fscore(res, threshold_mm=5)
    assert (s2.mean_all, s2.mean_skip_zero, s2.n_skipped) == (0.5, 1.0, 1)
    assert math.isnan(aggregate_fscore([0.0]).mean_skip_zero)


def test_bad_input_raises_named_errors():
    good = trimesh.creation.box((0.1, 0.1, 0.1))
    with pytest.raises(InvalidInputError, match="empty"):
        chamfer_fscore((np.zeros((0, 3)), np.zeros((0, 3), int)), good)
    bad = good.vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        chamfer_fscore((bad, good.faces), good)
    with pytest.raises(InvalidInputError, match="degenerate"):
        chamfer_fscore((np.zeros((3, 3)), [[0, 1, 2]]), good)
    with pytest.raises(InvalidInputError, match="align"):
        chamfer_fscore(good, good, align="affine")
    with pytest.raises(InvalidInputError, match="convention"):
        chamfer_fscore(good, good, convention="cm")
    with pytest.raises(InvalidInputError, match="at least one"):
        aggregate_fscore([])
