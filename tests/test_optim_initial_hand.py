"""Placing the estimator's hand in an object camera of another focal length: the joints keep
their pixels (the photo fixes them), whatever the depth."""

from __future__ import annotations

import math

import pytest
import torch

from easyhoi.optim.contact import _origin_camera, initial_hand, keypoint_shift, ray_rotation
from easyhoi.optim.placement import hand_in_camera
from easyhoi.optim.state import Scene
from easyhoi.structures import Camera
from easyhoi.testing.optim_scenes import make_scene

SIZE = 96


def test_keypoint_shift_recovers_a_translation_exactly():
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(21, 3, generator=g, dtype=torch.float64) * 0.05
    pts[:, 2] += 0.6
    cam = Camera.from_focal(300.0, 320, 240).to(torch.float64)
    true = torch.tensor([0.03, -0.02, 0.15], dtype=torch.float64)
    uv, _ = cam.project(pts + true)
    shift = keypoint_shift(pts, uv, cam)
    assert torch.allclose(shift, true, atol=1e-9)


def test_ray_rotation_turns_one_direction_onto_another():
    a = torch.tensor([0.1, -0.2, 1.0], dtype=torch.float64)
    b = torch.tensor([-0.3, 0.05, 0.8], dtype=torch.float64)
    R = ray_rotation(a, b)
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert math.isclose(float(torch.linalg.det(R)), 1.0, abs_tol=1e-12)
    assert torch.allclose(R @ (a / a.norm()), b / b.norm(), atol=1e-12)
    # the smallest rotation: the common perpendicular stays put
    axis = torch.linalg.cross(a, b)
    assert torch.allclose(R @ axis, axis, atol=1e-12)
    assert torch.equal(ray_rotation(a, 2 * a), torch.eye(3, dtype=torch.float64))


@pytest.mark.parametrize("ratio", [0.7, 1.4])
def test_initial_hand_keeps_the_joints_pixels_under_another_focal(hand, ratio):
    """A camera whose focal is ``ratio`` times the estimator's: the placed hand's 21 joints
    project within 3 % of the photo's width of the estimator's (a rigid hand cannot undo the
    change of perspective exactly), less than 0.3 times the error of the placement that keeps
    only the centroid's pixel and apparent size (0.7: 2.0 px against 9.7 px)."""
    sc = make_scene("cylinder", size=SIZE)
    scene = Scene.from_input(sc.inp, hand, torch.float64)
    est_cam = sc.inp.hand_camera.to(torch.float64)
    gt = sc.gt_camera.to(torch.float64)
    K = gt.K.clone()
    K[0, 0] *= ratio
    K[1, 1] *= ratio
    cam = Camera(K, gt.R, gt.t, gt.width, gt.height)
    p_est = hand_in_camera(sc.inp.hand_params.to(dtype=torch.float64), est_cam, hand)
    with torch.no_grad():
        out = hand(p_est)
        target, _ = _origin_camera(est_cam).project(out.keypoints[0])
        p, _, _ = initial_hand(scene, sc.inp, cam, SIZE)
        placed, _ = _origin_camera(cam).project(hand(p).keypoints[0])
        # the centroid-only placement, written out
        c = out.vertices[0].mean(0)
        uv, z = _origin_camera(est_cam).project(c)
        k = math.sqrt(float(K[0, 0] * K[1, 1] / (est_cam.K[0, 0] * est_cam.K[1, 1])))
        c_new = _origin_camera(cam).unproject(uv, z * k)
        naive, _ = _origin_camera(cam).project(out.keypoints[0] + (c_new - c))
    err = float((placed - target).norm(dim=1).max())
    err_naive = float((naive - target).norm(dim=1).max())
    assert err < 0.03 * SIZE
    assert err < 0.3 * err_naive
