"""All-hit ray casting vs analytic spheres and a brute-force Moller-Trumbore reference."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.raycast import cast_rays_all_hits, cast_rays_first_hit
from tests.helpers import assert_close


def brute_force_hits(mesh, origins, dirs):
    """Every ray-triangle hit (Moller-Trumbore over all faces), depths sorted per ray."""
    tri = np.asarray(mesh.triangles)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = []
    for o, d in zip(origins, dirs / np.linalg.norm(dirs, axis=1, keepdims=True), strict=True):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - tri[:, 0]
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        out.append(np.sort(t[hit]))
    return out


def nested_spheres():
    outer = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    inner = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    inner.invert()
    return trimesh.util.concatenate([outer, inner])


def test_nested_spheres_give_four_sorted_hits_at_analytic_depths():
    mesh = nested_spheres()
    rng = np.random.default_rng(0)
    n = 200
    offsets = rng.uniform(-0.3, 0.3, (n, 2))  # rays parallel to z through the inner sphere
    origins = np.c_[offsets, np.full(n, -3.0)]
    dirs = np.tile([0.0, 0.0, 1.0], (n, 1))
    pts, fids, depth, valid = cast_rays_all_hits(mesh, origins, dirs, max_hits=6)
    assert valid[:, :4].all() and not valid[:, 4:].any()
    rho2 = (offsets**2).sum(1)
    want = np.stack(
        [
            3 - np.sqrt(1 - rho2),
            3 - np.sqrt(0.25 - rho2),
            3 + np.sqrt(0.25 - rho2),
            3 + np.sqrt(1 - rho2),
        ],
        axis=1,
    )
    # tessellated spheres: hits lie within the chord sagitta of the analytic sphere
    assert_close(depth[:, :4], want, atol=5e-3)
    assert (np.diff(depth[:, :4], axis=1) > 0).all()
    assert_close(pts[:, :4], origins[:, None] + depth[:, :4, None] * dirs[:, None], atol=1e-5)
    assert (fids[:, 4:] == -1).all() and np.isinf(depth[:, 4:]).all()


@pytest.mark.parametrize("backend", ["embree", "triangle"])
def test_matches_brute_force_reference(backend):
    box = trimesh.creation.box(extents=[0.8, 0.5, 0.4])
    box.apply_translation([0.6, 0.0, 0.0])
    mesh = trimesh.util.concatenate([nested_spheres(), box])
    rng = np.random.default_rng(1)
    origins = rng.uniform(-2, 2, (150, 3)) * [1, 1, 0] + [0, 0, -2.5]
    dirs = rng.uniform(-0.8, 0.8, (150, 3)) - origins  # aimed at the objects
    _, _, depth, valid = cast_rays_all_hits(mesh, origins, dirs, max_hits=4, backend=backend)
    ref = brute_force_hits(mesh, origins, dirs)
    for i, r in enumerate(ref):
        r = r[np.diff(r, prepend=-1.0) > 1e-6][:4]  # drop shared-edge duplicates
        assert valid[i].sum() == len(r), i
        assert_close(depth[i, : len(r)], r, atol=2e-5)
    assert valid.sum() > 300  # the test exercises multiple hits


def test_max_hits_truncates_to_the_nearest_and_first_hit_agrees():
    mesh = nested_spheres()
    origins = np.array([[0.1, 0.05, -3.0], [5.0, 5.0, -3.0]])
    dirs = np.array([[0, 0, 1.0], [0, 0, 2.0]])  # non-unit direction: depths stay Euclidean
    _, _, d2, v2 = cast_rays_all_hits(mesh, origins, dirs, max_hits=2)
    _, _, d4, _ = cast_rays_all_hits(mesh, origins, dirs, max_hits=4)
    assert_close(d2[0], d4[0, :2], atol=0)
    assert v2[0].all() and not v2[1].any()
    p1, f1, t1, ok1 = cast_rays_first_hit(mesh, origins, dirs)
    assert ok1.tolist() == [True, False] and f1[1] == -1
    assert_close(t1[0], d4[0, 0], atol=1e-9)


def test_bad_rays_raise():
    mesh = trimesh.creation.box()
    with pytest.raises(InvalidInputError, match="non-zero"):
        cast_rays_all_hits(mesh, np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(InvalidInputError, match="directions must have shape"):
        cast_rays_all_hits(mesh, np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(InvalidInputError, match="max_hits"):
        cast_rays_all_hits(mesh, np.zeros((2, 3)), np.ones((2, 3)), max_hits=0)
    with pytest.raises(InvalidInputError, match="backend"):
        cast_rays_all_hits(mesh, np.zeros((2, 3)), np.ones((2, 3)), backend="optix")
