"""Simulation displacement in PyBullet: free fall, a resting object, the decomposition cache."""

from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.metrics import simulation as sim
from easyhoi.metrics.simulation import (
    VHACDParams,
    clear_memory_cache,
    convex_decomposition,
    simulation_displacement,
)

DT = 1.0 / 240.0
G = 9.8


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("EASYHOI_CACHE", str(tmp_path))
    clear_memory_cache()
    yield
    clear_memory_cache()


def _far_hand() -> trimesh.Trimesh:
    """A plate 1 m above the object (against gravity): never touched."""
    return trimesh.creation.box((0.1, 0.01, 0.1), transform=_at([0, -1.0, 0]))


def _at(xyz) -> np.ndarray:
    return trimesh.transformations.translation_matrix(xyz)


def _ball(radius=0.015, centre=(0, 0, 0)) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(2, radius)
    m.apply_translation(centre)
    return m


def _bowl(radius=0.05) -> trimesh.Trimesh:
    """Open hemispherical bowl (single surface), opening towards -y, bottom at y = +radius."""
    sphere = trimesh.creation.icosphere(4, radius)
    keep = sphere.triangles_center[:, 1] > 0.2 * radius
    bowl = trimesh.Trimesh(sphere.vertices, sphere.faces[keep], process=False)
    bowl.remove_unreferenced_vertices()
    return bowl


def test_free_fall_matches_semi_implicit_euler():
    # Bullet integrates v += g dt, then x += v dt: after n steps x = g dt^2 n (n + 1) / 2.
    n = 35
    exact = G * DT**2 * n * (n + 1) / 2 * 100  # cm
    r = simulation_displacement(_far_hand(), _ball(), steps=n, linear_damping=0.0)
    assert r.displacement == pytest.approx(exact, abs=1e-6)
    assert r.displacement == pytest.approx(0.5 * G * (n * DT) ** 2 * 100, rel=0.03)
    np.testing.assert_allclose(
        r.final_position - r.initial_position, [0, exact / 100, 0], atol=1e-9
    )
    # PyBullet's default damping (0.04, kept by the published protocol) slows it by ~0.3 %
    default = simulation_displacement(_far_hand(), _ball(), steps=n)
    assert default.displacement == pytest.approx(exact, rel=0.01)
    assert default.displacement < exact
    assert default.cache == "memory" and default.n_hulls >= 1


def test_gravity_direction_and_zero_steps():
    r = simulation_displacement(
        _far_hand(), _ball(), steps=20, gravity_dir=(0, 0, -2), linear_damping=0.0
    )
    d = r.final_position - r.initial_position
    assert d[2] == pytest.approx(-G * DT**2 * 20 * 21 / 2, rel=1e-6)
    assert abs(d[0]) < 1e-12 and abs(d[1]) < 1e-12
    assert simulation_displacement(_far_hand(), _ball(), steps=0).displacement == 0.0


def test_object_resting_in_a_bowl_barely_moves():
    bowl = _bowl(0.05)
    ball = _ball(0.015, centre=(0, 0.05 - 0.015 - 0.002, 0))  # 2 mm above the bottom
    held = simulation_displacement(bowl, ball)
    free = simulation_displacement(_far_hand(), ball)
    assert held.displacement < 1.0
    assert free.displacement > 10.0
    # the initial centroid is the vertex mean of the object
    np.testing.assert_allclose(held.initial_position, ball.vertices.mean(0), atol=1e-12)


def test_decomposition_cache_memory_then_disk(tmp_path, monkeypatch):
    calls = []
    import pybullet

    real = pybullet.vhacd

    def counting(*a, **k):
        calls.append(k)
        return real(*a, **k)

    monkeypatch.setattr(pybullet, "vhacd", counting)
    obj = trimesh.creation.capsule(height=0.06, radius=0.02, count=[24, 24])
    t0 = time.perf_counter()
    first = simulation_displacement(_far_hand(), obj)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    second = simulation_displacement(_far_hand(), obj)
    warm = time.perf_counter() - t0
    assert (first.cache, second.cache) == ("computed", "memory")
    assert len(calls) == 1
    assert warm < cold and second.decomposition_seconds < 0.1
    assert second.displacement == first.displacement  # deterministic
    # the docs/method.md settings reach V-HACD (max hulls 1024 -> clipping depth 10)
    assert calls[0] == {
        "resolution": 1000,
        "concavity": 0.001,
        "depth": 10,
        "maxNumVerticesPerCH": 64,
        "minVolumePerCH": 1e-4,
    }
    files = sorted(p.name for p in (tmp_path / "vhacd").iterdir())
    assert len(files) == 1 and files[0].endswith(".obj")  # no temporary file left behind
    clear_memory_cache()
    third = simulation_displacement(_far_hand(), obj)
    assert third.cache == "disk" and len(calls) == 1
    # a translated copy shares the decomposition (the key uses centred vertices)
    moved = obj.copy()
    moved.apply_translation([0.1, 0, 0])
    assert simulation_displacement(_far_hand(), moved).cache == "memory"
    # other V-HACD settings are another entry
    d = convex_decomposition(obj, VHACDParams(concavity=0.01))
    assert d.cache == "computed" and len(calls) == 2


def test_explicit_cache_dir(tmp_path):
    d = convex_decomposition(_ball(), cache_dir=tmp_path / "here")
    assert d.path.parent == tmp_path / "here" and d.path.is_file()
    assert sim.default_cache_dir() == tmp_path / "vhacd"


def test_bad_inputs():
    with pytest.raises(InvalidInputError, match="gravity_dir"):
        simulation_displacement(_far_hand(), _ball(), gravity_dir=(0, 0, 0))
    with pytest.raises(InvalidInputError, match="steps"):
        simulation_displacement(_far_hand(), _ball(), steps=-1)
    ball = _ball()
    v = ball.vertices.copy()
    v[3] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        simulation_displacement(_far_hand(), (v, ball.faces))
    with pytest.raises(InvalidInputError, match="empty"):
        simulation_displacement((np.zeros((0, 3)), np.zeros((0, 3), int)), ball)


def test_gravity_cone_directions():
    from easyhoi.metrics.simulation import gravity_cone

    g = np.array([0.3, 2.0, -0.5])
    d = gravity_cone(g, tilt_deg=10.0, azimuths=6)
    assert d.shape == (7, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    gu = g / np.linalg.norm(g)
    np.testing.assert_allclose(d[0], gu, atol=1e-12)
    angles = np.degrees(np.arccos(np.clip(d[1:] @ gu, -1, 1)))
    np.testing.assert_allclose(angles, 10.0, atol=1e-9)
    # evenly spaced azimuths: consecutive tilted directions 60 degrees apart about g
    p = d[1:] - np.outer(d[1:] @ gu, gu)
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    steps = np.degrees(np.arccos(np.clip(np.sum(p * np.roll(p, -1, axis=0), axis=1), -1, 1)))
    np.testing.assert_allclose(steps, 60.0, atol=1e-9)
    np.testing.assert_array_equal(gravity_cone(g, 10.0, 6), d)  # deterministic
    assert gravity_cone(g, 0.0, 0).shape == (1, 3)
    for bad in (dict(tilt_deg=90.0), dict(tilt_deg=-1.0), dict(azimuths=-1)):
        with pytest.raises(InvalidInputError):
            gravity_cone(g, **bad)
    with pytest.raises(InvalidInputError, match="gravity_dir"):
        gravity_cone((0, 0, 0))


def test_cone_displacement_is_the_mean_over_the_cone():
    from easyhoi.metrics.simulation import cone_displacement, gravity_cone

    # free fall: every direction falls the same exact distance
    n = 35
    exact = G * DT**2 * n * (n + 1) / 2 * 100
    mean, per = cone_displacement(_far_hand(), _ball(), tilt_deg=20.0, azimuths=4,
                                  steps=n, linear_damping=0.0)  # fmt: skip
    assert len(per) == 5
    np.testing.assert_allclose(per, exact, rtol=1e-6)
    # a ball in a bowl: each entry is the single-direction simulation along that direction
    bowl = _bowl(0.05)
    ball = _ball(0.015, centre=(0, 0.05 - 0.015 - 0.002, 0))
    mean, per = cone_displacement(bowl, ball, tilt_deg=15.0, azimuths=3)
    dirs = gravity_cone((0.0, 1.0, 0.0), 15.0, 3)
    naive = [simulation_displacement(bowl, ball, gravity_dir=d).displacement for d in dirs]
    np.testing.assert_allclose(per, naive, rtol=1e-9, atol=1e-9)
    assert mean == pytest.approx(np.mean(naive)) and mean < 1.0
