"""Mesh loading, validation, normalisation and surface sampling."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.mesh import as_trimesh, load_mesh, normalize_mesh, validate_mesh
from easyhoi.geometry.sampling import sample_surface
from easyhoi.geometry.sdf import exact_signed_distance
from tests.helpers import assert_close


@pytest.fixture
def box():
    m = trimesh.creation.box(extents=[0.2, 0.1, 0.05])
    m.apply_translation([1.0, -2.0, 0.5])
    return m


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb", ".off"])
def test_load_round_trip_every_format(tmp_path, box, suffix):
    path = tmp_path / f"box{suffix}"
    box.export(path)
    m = load_mesh(path, process=True)
    assert len(m.faces) == 12 and m.is_watertight
    assert_close(np.sort(m.vertices, axis=0), np.sort(box.vertices, axis=0), atol=1e-6)
    assert abs(m.volume - box.volume) < 1e-5 * box.volume  # float32 formats round


def test_load_scanned_object(shared_data):
    m = load_mesh(shared_data / "objects" / "mug.obj")
    assert len(m.faces) == 16384 and 0.05 < m.extents.max() < 0.2  # metres


def test_load_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        load_mesh(tmp_path / "missing.obj")
    bad_suffix = tmp_path / "mesh.xyz"
    bad_suffix.write_text("1 2 3\n")
    with pytest.raises(InvalidInputError, match=r"unsupported mesh format.*'\.xyz'"):
        load_mesh(bad_suffix)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(InvalidInputError, match="no triangle mesh|empty"):
        load_mesh(empty)
    corrupt = tmp_path / "corrupt.glb"
    corrupt.write_bytes(b"glTF\x02\x00\x00\x00garbage" * 3)
    with pytest.raises(InvalidInputError, match="could not parse|no triangle mesh"):
        load_mesh(corrupt)
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(InvalidInputError, match="NaN"):
        load_mesh(nan)


def test_validate_mesh_errors():
    with pytest.raises(InvalidInputError, match="trimesh.Trimesh"):
        validate_mesh(np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="only 3 vertices"):
        as_trimesh(np.eye(3), [[0, 1, 5]])
    with pytest.raises(InvalidInputError, match="degenerate"):
        as_trimesh(np.zeros((3, 3)), [[0, 1, 2]])
    open_box = trimesh.creation.box()
    open_box.faces = open_box.faces[:-1]
    validate_mesh(open_box)  # fine unless watertightness is required
    with pytest.raises(InvalidInputError, match="watertight"):
        validate_mesh(open_box, require_watertight=True)


def test_normalize_mesh_unit_radius_and_inverse(box):
    norm, tf = normalize_mesh(box)
    r = np.linalg.norm(norm.vertices, axis=1)
    assert abs(r.max() - 1.0) < 1e-12
    assert_close(0.5 * (norm.bounds[0] + norm.bounds[1]), np.zeros(3), atol=1e-12)
    assert_close(tf.invert(norm.vertices), box.vertices, atol=1e-12)
    hom = np.c_[box.vertices, np.ones(len(box.vertices))] @ tf.matrix().T
    assert_close(hom[:, :3], norm.vertices, atol=1e-12)
    half, _ = normalize_mesh(box, radius=0.5)
    assert_close(half.vertices, norm.vertices * 0.5, atol=1e-12)
    with pytest.raises(InvalidInputError, match="radius"):
        normalize_mesh(box, radius=0.0)


def test_sampling_is_deterministic_and_on_the_surface(box):
    p1, f1, n1 = sample_surface(box, 2000, seed=3)
    p2, f2, n2 = sample_surface(box, 2000, seed=3)
    p3, _, _ = sample_surface(box, 2000, seed=4)
    assert np.array_equal(p1, p2) and np.array_equal(f1, f2) and np.array_equal(n1, n2)
    assert not np.array_equal(p1, p3)
    assert np.abs(exact_signed_distance(box, p1)).max() < 1e-12
    assert_close(n1, box.face_normals[f1], atol=1e-12)


def test_sampling_is_uniform_by_area():
    # two triangles of area 1 and 3: a quarter of the samples on the first
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [2, 0, 1], [5, 0, 1], [2, 2, 1.0]])
    mesh = as_trimesh(v, [[0, 1, 2], [3, 4, 5]])
    pts, fids, _ = sample_surface(mesh, 40000, seed=0)
    frac = (fids == 0).mean()
    assert abs(frac - 0.25) < 0.01  # 4.6 standard deviations
    # uniform inside a triangle: the mean of the samples is the centroid
    assert_close(pts[fids == 1].mean(axis=0), v[3:].mean(axis=0), atol=0.02)
    assert sample_surface(mesh, 0)[0].shape == (0, 3)
    with pytest.raises(InvalidInputError, match="non-negative"):
        sample_surface(mesh, -1)
