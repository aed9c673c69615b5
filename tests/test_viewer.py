"""The web viewer's copy of scene.glb: photo camera frame and the first orbit view."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.viz.viewer import CV_TO_GL, orbit_position, orbit_to_origin, photo_view_glb


def test_orbit_round_trip_puts_the_camera_at_the_origin():
    rng = np.random.default_rng(0)
    for centre in rng.normal(size=(20, 3)):
        alpha, beta, radius = orbit_to_origin(centre)
        assert 0.0 <= beta <= 180.0 and radius == pytest.approx(np.linalg.norm(centre))
        np.testing.assert_allclose(orbit_position(centre, alpha, beta, radius), 0.0, atol=1e-12)
    # straight in front of a glTF camera (-z): the camera sits at +z of the target, level
    assert orbit_to_origin([0.0, 0.0, -0.5]) == pytest.approx((90.0, 90.0, 0.5))
    with pytest.raises(InvalidInputError):
        orbit_to_origin([0.0, 0.0, 0.0])


def _glb(tmp_path, meshes):
    scene = trimesh.Scene()
    for name, m in meshes.items():
        scene.add_geometry(m, geom_name=name)
    path = tmp_path / "scene.glb"
    path.write_bytes(scene.export(file_type="glb"))
    return path


def test_photo_view_is_the_camera_frame(tmp_path):
    import torch

    box = trimesh.creation.box((0.04, 0.06, 0.02))
    box.apply_translation((0.03, -0.02, 0.01))
    ball = trimesh.creation.icosphere(2, radius=0.03)
    ball.apply_translation((-0.05, 0.04, 0.0))
    path = _glb(tmp_path, {"object": box, "hand": ball})
    R = axis_angle_to_matrix(torch.tensor([0.3, -0.5, 0.2], dtype=torch.float64)).numpy()
    t = np.array([0.01, -0.02, 0.6])
    K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])
    data, (alpha, beta, radius) = photo_view_glb(path, R, t)
    out = trimesh.load(io.BytesIO(data), file_type="glb", force="scene")
    assert sorted(out.geometry) == ["hand", "object"]
    for name, src in (("object", box), ("hand", ball)):
        got = out.geometry[name].vertices
        expected = (CV_TO_GL @ (R @ src.vertices.T + t[:, None])).T
        np.testing.assert_allclose(got, expected, atol=1e-6)  # GLB stores float32
        # what is right of / above the principal point in the photo is +x / +y in the view
        cam = R @ src.vertices.T + t[:, None]
        uv = (K @ cam)[:2] / cam[2]
        assert np.array_equal(got[:, 0] > 0, uv[0] > K[0, 2])
        assert np.array_equal(got[:, 1] > 0, uv[1] < K[1, 2])
        assert (got[:, 2] < 0).all()  # in front of a glTF camera
    lo, hi = out.bounds
    np.testing.assert_allclose(orbit_position((lo + hi) / 2, alpha, beta, radius), 0, atol=1e-6)
    # with the photo's intrinsics: same direction, distance scaled to the viewer's field of view
    _, (a2, b2, r2) = photo_view_glb(path, R, t, K, 240)
    assert (a2, b2) == pytest.approx((alpha, beta))
    assert r2 == pytest.approx(radius * (120 / 500) / np.tan(0.4))


def test_photo_view_bad_input(tmp_path):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a glb")
    with pytest.raises(InvalidInputError, match="bad.glb"):
        photo_view_glb(bad, np.eye(3), np.zeros(3))
    path = _glb(tmp_path, {"object": trimesh.creation.box()})
    with pytest.raises(InvalidInputError, match="camera"):
        photo_view_glb(path, np.eye(2), np.zeros(3))
    with pytest.raises(InvalidInputError, match="camera"):
        photo_view_glb(path, np.eye(3), [0.0, np.nan, 1.0])
