"""Watertight repair: MeshFix for holes, multi-view depth fusion for messy scans."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError, MissingDependencyError
from easyhoi.geometry.mesh import load_mesh
from easyhoi.geometry.watertight import decimate, fibonacci_directions, make_watertight

SPHERE_VOLUME = 4.0 / 3.0 * np.pi * 0.5**3
try:
    import pymeshlab  # noqa: F401

    HAS_PYMESHLAB = True
except ImportError:
    HAS_PYMESHLAB = False


def messy_sphere():
    """A sphere of radius 0.5 as two unconnected shells with small holes, plus interior junk."""
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    z = s.triangles_center[:, 2]
    holes = np.zeros(len(s.faces), dtype=bool)
    holes[[10, 200, 1500, 3000]] = True
    top = s.submesh([np.flatnonzero((z > 0) & ~holes)], append=True)
    bottom = s.submesh([np.flatnonzero((z <= 0) & ~holes)], append=True)
    bottom.vertices *= 0.995  # scan shells do not share vertices: a small step at the seam
    junk = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    junk.invert()  # an inward-facing shell, as scans often carry
    rng = np.random.default_rng(0)
    soup = trimesh.Trimesh(rng.uniform(-0.2, 0.2, (60, 3)), np.arange(60).reshape(20, 3))
    return trimesh.util.concatenate([top, bottom, junk, soup])


def radial_error(mesh):
    return np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.5)


def test_watertight_mesh_is_left_alone():
    box = trimesh.creation.box(extents=[0.3, 0.2, 0.1])
    out, rep = make_watertight(box)
    assert rep.method == "none" and rep.watertight_before and rep.watertight_after
    assert abs(out.volume - box.volume) < 1e-12


def test_meshfix_fills_small_holes():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    closed_volume = s.volume
    holed = trimesh.Trimesh(s.vertices, np.delete(s.faces, [3, 50, 51, 400], axis=0))
    assert not holed.is_watertight
    out, rep = make_watertight(holed)
    assert rep.method == "meshfix" and not rep.watertight_before
    assert out.is_watertight and rep.watertight_after
    assert abs(out.volume - closed_volume) / closed_volume < 0.01


def test_fusion_rebuilds_a_messy_scan_and_drops_interior_junk():
    messy = messy_sphere()
    out, rep = make_watertight(messy, resolution=48, num_views=12, image_size=160)
    assert rep.method == "fusion-carve", rep
    assert "largest piece" in rep.notes
    assert out.is_watertight and rep.watertight_after and not rep.watertight_before
    assert abs(out.volume - SPHERE_VOLUME) / SPHERE_VOLUME < 0.03
    assert radial_error(out).max() < 0.02  # no junk vertex survives inside
    assert rep.faces_after == len(out.faces) and rep.seconds > 0


def test_meshfix_alone_is_wrong_for_multi_shell_scans():
    """Why auto does not use MeshFix on scans made of several shells: it keeps one."""
    out, rep = make_watertight(messy_sphere(), method="meshfix")
    assert rep.method == "meshfix"
    assert not (out.is_watertight and abs(out.volume - SPHERE_VOLUME) < 0.1 * SPHERE_VOLUME)


@pytest.mark.slow
@pytest.mark.skipif(not HAS_PYMESHLAB, reason="pymeshlab not installed (surface='poisson')")
def test_fusion_poisson_route():
    out, rep = make_watertight(
        messy_sphere(),
        method="fusion",
        surface="poisson",
        num_views=10,
        image_size=128,
        poisson_depth=6,
        voxel_fraction=0.02,
    )
    assert rep.method == "fusion-poisson"
    assert out.is_watertight
    assert abs(out.volume - SPHERE_VOLUME) / SPHERE_VOLUME < 0.05
    assert radial_error(out).max() < 0.03


def _objects(shared_data):
    paths = sorted((shared_data / "objects").glob("*.obj"))
    assert len(paths) == 14
    return paths


def _check(out, rep, reference_volume):
    assert out.is_watertight and rep.watertight_after
    assert out.volume > 0
    assert 0.1 < out.volume / rep.hull_volume <= 1.0 + 1e-6
    assert abs(out.volume - reference_volume) / reference_volume < 0.1


def test_auto_route_on_every_scanned_object(shared_data):
    for path in _objects(shared_data):
        raw = trimesh.load(path, force="mesh", process=False)
        assert not raw.is_watertight, path.name  # as shipped (UV seams split vertices)
        out, rep = make_watertight(load_mesh(path))
        assert rep.method in ("none", "meshfix"), (path.name, rep)
        _check(out, rep, rep.volume_before)


@pytest.mark.slow
def test_fusion_route_on_every_scanned_object(shared_data):
    for path in _objects(shared_data):
        mesh = load_mesh(path)
        out, rep = make_watertight(mesh, method="fusion", resolution=48)
        assert rep.method == "fusion-carve", path.name
        reference, _ = make_watertight(mesh)  # MeshFix / merged original: a closed reference
        _check(out, rep, reference.volume)


@pytest.mark.parametrize("backend", ["pcu", "pymeshlab"])
def test_decimate_keeps_a_closed_shape(backend):
    if backend == "pymeshlab" and not HAS_PYMESHLAB:
        pytest.skip("pymeshlab not installed")
    s = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    small = decimate(s, 2000, backend=backend)
    assert 1000 < len(small.faces) <= 2000
    assert small.is_watertight
    assert abs(small.volume - s.volume) / s.volume < 0.03
    assert radial_error(small).max() < 0.01
    assert len(decimate(s, 10**6).faces) == len(s.faces)


def test_fibonacci_directions_are_unit_and_spread():
    d = fibonacci_directions(16)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.allclose(d.mean(axis=0), 0.0, atol=0.05)
    cos = d @ d.T - 2 * np.eye(16)
    assert cos.max() < 0.8  # no two views closer than ~37 degrees


def test_bad_arguments_raise():
    box = trimesh.creation.box()
    with pytest.raises(InvalidInputError, match="method"):
        make_watertight(box, method="magic")
    with pytest.raises(InvalidInputError, match="surface"):
        make_watertight(box, surface="marching")
    with pytest.raises(InvalidInputError, match="target_faces"):
        decimate(box, 2)


def test_poisson_without_pymeshlab_names_the_fix(monkeypatch):
    monkeypatch.setitem(sys.modules, "pymeshlab", None)  # import now fails
    with pytest.raises(MissingDependencyError, match="pip install pymeshlab"):
        make_watertight(
            messy_sphere(), method="fusion", surface="poisson", num_views=4, image_size=32
        )
