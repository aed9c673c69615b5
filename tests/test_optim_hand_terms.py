"""Stage-3 hand terms: robust 2D keypoints, anatomical pose prior, rigid push-out, hand change."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.regions import DIGIT_JOINTS
from easyhoi.optim.hand_terms import (
    ABDUCTION_TOLERANCE,
    COUPLING_RATIO,
    COUPLING_TOLERANCE,
    FLEXION_LIMITS,
    HINGE_TOLERANCE,
    keypoint_loss,
    pose_prior_loss,
)
from easyhoi.optim.state import PhotoKeypoints


def _naive_keypoints(pred, target, scale, sigma, weights):
    total, wsum = 0.0, 0.0
    for j in range(len(target)):
        du = float(pred[j][0]) - float(target[j][0])
        dv = float(pred[j][1]) - float(target[j][1])
        r2 = (du * du + dv * dv) / (scale * scale)
        total += float(weights[j]) * r2 / (r2 + sigma * sigma)
        wsum += float(weights[j])
    return total / wsum


def test_keypoint_loss_matches_naive_and_gradcheck():
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(21, 2, generator=g, dtype=torch.float64) * 100
    target = pred + torch.randn(21, 2, generator=g, dtype=torch.float64) * 8
    w = torch.rand(21, generator=g, dtype=torch.float64)
    got = keypoint_loss(pred, target, 60.0, 0.1, w)
    assert float(got) == pytest.approx(_naive_keypoints(pred, target, 60.0, 0.1, w), rel=1e-12)
    x = pred.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: keypoint_loss(p, target, 60.0, 0.1, w), (x,))


def test_keypoint_loss_is_robust_and_quadratic_near_zero():
    target = torch.zeros(21, 2, dtype=torch.float64)
    small = target.clone()
    small[0, 0] = 0.6  # r = 0.01 with scale 60
    # quadratic regime: (r / sigma)^2 / 21
    assert float(keypoint_loss(small, target, 60.0, 0.1)) == pytest.approx(0.01 / 21, rel=0.02)
    far = target.clone()
    far[0, 0] = 1e4  # one wild joint costs at most its share of 1
    assert float(keypoint_loss(far, target, 60.0, 0.1)) < 1.0 / 21 + 1e-9
    x = far.clone().requires_grad_(True)
    keypoint_loss(x, target, 60.0, 0.1).backward()
    assert float(x.grad.abs().max()) < 1e-6  # the outlier barely pulls


def test_keypoint_drift_loss_matches_naive_gradcheck_and_does_not_saturate():
    from easyhoi.optim.hand_terms import keypoint_drift_loss

    g = torch.Generator().manual_seed(1)
    pred = torch.rand(21, 2, generator=g, dtype=torch.float64) * 100
    target = pred + torch.randn(21, 2, generator=g, dtype=torch.float64) * 8
    w = torch.rand(21, generator=g, dtype=torch.float64)
    mean = [
        sum(float(w[j]) * float(pred[j, c] - target[j, c]) for j in range(21)) / float(w.sum())
        for c in range(2)
    ]
    naive = (mean[0] ** 2 + mean[1] ** 2) / (60.0 * 0.1) ** 2
    got = keypoint_drift_loss(pred, target, 60.0, 0.1, w)
    assert float(got) == pytest.approx(naive, rel=1e-12)
    x = pred.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: keypoint_drift_loss(p, target, 60.0, 0.1, w), (x,))
    # a common shift: the robust term's quadratic regime near 0, but unbounded far off, where
    # the robust term is flat
    base = torch.zeros(21, 2, dtype=torch.float64)
    for shift, ratio in ((0.6, 1.0), (60.0, None)):
        moved = base + torch.tensor([shift, 0.0], dtype=torch.float64)
        drift = float(keypoint_drift_loss(moved, base, 60.0, 0.1))
        robust = float(keypoint_loss(moved, base, 60.0, 0.1))
        assert drift == pytest.approx((shift / 6.0) ** 2, rel=1e-12)
        if ratio is not None:
            assert drift == pytest.approx(robust, rel=0.02)
        else:
            assert robust < 1.0 and drift == pytest.approx(100.0)
    with pytest.raises(InvalidInputError):
        keypoint_drift_loss(base, base, 60.0, 0.1, torch.zeros(21))


def test_keypoint_loss_rejects_bad_arguments():
    t = torch.zeros(21, 2)
    with pytest.raises(InvalidInputError):
        keypoint_loss(t, t, 0.0, 0.1)
    with pytest.raises(InvalidInputError):
        keypoint_loss(t, torch.zeros(20, 2), 10.0, 0.1)
    with pytest.raises(InvalidInputError):
        keypoint_loss(t, t, 10.0, 0.1, torch.zeros(21))


def _naive_prior(pose: np.ndarray, axes: np.ndarray) -> float:
    """Loop-per-joint reference of :func:`pose_prior_loss` (no reference articulation)."""
    theta = pose.reshape(15, 3)
    flex = {}
    total = 0.0
    for digit, joints in DIGIT_JOINTS.items():
        kind = "thumb" if digit == "thumb" else "finger"
        for role, j in enumerate(joints):
            a = float(theta[j - 1] @ axes[j - 1])
            flex[j] = a
            lo, hi = FLEXION_LIMITS[kind][role]
            total += max(0.0, lo - a) ** 2 + max(0.0, a - hi) ** 2
            rest = np.linalg.norm(theta[j - 1] - a * axes[j - 1])
            hinge = role == 2 or (kind == "finger" and role == 1)
            tol = HINGE_TOLERANCE if hinge else ABDUCTION_TOLERANCE[kind]
            total += max(0.0, rest - tol) ** 2
    for digit in ("index", "middle", "ring", "pinky"):
        _, mid, dist = DIGIT_JOINTS[digit]
        total += max(0.0, abs(flex[dist] - COUPLING_RATIO * flex[mid]) - COUPLING_TOLERANCE) ** 2
    return total


def _axes(seed=1):
    a = np.random.default_rng(seed).normal(size=(15, 3))
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def test_pose_prior_matches_naive_and_gradcheck():
    axes = _axes()
    rng = np.random.default_rng(2)
    for scale in (0.3, 1.0, 2.5):
        pose = rng.normal(size=45) * scale
        got = float(pose_prior_loss(torch.as_tensor(pose)[None], torch.as_tensor(axes)))
        assert got == pytest.approx(_naive_prior(pose, axes), rel=1e-9, abs=1e-12)
    x = torch.as_tensor(rng.normal(size=(1, 45)) * 1.5).requires_grad_(True)
    ax = torch.as_tensor(axes)
    assert torch.autograd.gradcheck(lambda p: pose_prior_loss(p, ax), (x,))
    ref = torch.as_tensor(rng.normal(size=(1, 45)) * 1.5)
    assert torch.autograd.gradcheck(lambda p: pose_prior_loss(p, ax, reference=ref), (x,))


def test_pose_prior_zero_for_natural_poses_and_positive_for_impossible_ones():
    axes = _axes(3)
    ax = torch.as_tensor(axes)
    # a fist-like pose: every joint flexed about its own axis within range, distal ~ 2/3 middle
    pose = np.zeros((15, 3))
    for b, m, d in DIGIT_JOINTS.values():
        pose[b - 1], pose[m - 1] = axes[b - 1] * 1.2, axes[m - 1] * 1.2
        pose[d - 1] = axes[d - 1] * 0.8
    assert float(pose_prior_loss(torch.as_tensor(pose).reshape(1, 45), ax)) == 0.0
    # a middle joint bent backwards by 1 rad (0.9 beyond its limit) costs 0.81
    bad = pose.copy()
    j = DIGIT_JOINTS["index"][1] - 1
    bad[j] = -axes[j] * 1.0
    got = float(pose_prior_loss(torch.as_tensor(bad).reshape(1, 45), ax))
    assert got > 0.81
    assert got == pytest.approx(_naive_prior(bad.reshape(45), axes), rel=1e-9)


def test_pose_prior_relative_to_reference_penalises_only_further_excess():
    axes = _axes(4)
    ax = torch.as_tensor(axes)
    ref = np.zeros((15, 3))
    j = DIGIT_JOINTS["ring"][2] - 1
    ref[j] = axes[j] * 2.0  # distal joint 0.52 beyond its limit (the estimator saw it so)
    ref_t = torch.as_tensor(ref).reshape(1, 45)
    assert float(pose_prior_loss(ref_t, ax, reference=ref_t)) == 0.0
    more = ref.copy()
    more[j] = axes[j] * 2.1
    got = float(pose_prior_loss(torch.as_tensor(more).reshape(1, 45), ax, reference=ref_t))
    # limit excess grows by 0.1; coupling excess (middle 0) grows by 0.1 as well
    assert got == pytest.approx(0.1**2 + 0.1**2, rel=1e-6)


def test_photo_keypoints_from_meta():
    pts = np.random.default_rng(0).uniform(10, 90, size=(21, 2))
    kp = PhotoKeypoints.from_meta({"keypoints2d": pts.tolist()}, torch.float64)
    assert kp.size == pytest.approx(float(np.ptp(pts, axis=0).max()))
    assert torch.equal(kp.confidence, torch.ones(21, dtype=torch.float64))
    assert PhotoKeypoints.from_meta({}, torch.float64) is None
    with pytest.raises(InvalidInputError):
        PhotoKeypoints.from_meta({"keypoints2d": pts[:5].tolist()}, torch.float64)
    with pytest.raises(InvalidInputError):
        PhotoKeypoints.from_meta(
            {"keypoints2d": pts.tolist(), "keypoints2d_confidence": [-1.0] * 21}, torch.float64
        )


def test_keypoint_term_reprojects_like_the_camera():
    """The refine keypoint term is 0 when the detector's keypoints are the hand's projection."""
    from dataclasses import replace

    from easyhoi.config import get_preset
    from easyhoi.optim.refine import refine_terms
    from easyhoi.optim.state import Scene
    from easyhoi.testing.optim_scenes import make_scene

    sc = make_scene("box")
    hand = sc.model
    cfg = replace(get_preset("fast").optim.refine, keypoint_weight=1.0, hand_mask_weight=0.0,
                  penetration_weight=0.0, contact_weight=0.0, reg_weight=0.0)  # fmt: skip
    with torch.no_grad():
        k = hand(sc.gt_hand).keypoints[0] / sc.gt_metric_scale
        uv, _ = sc.gt_camera.project(k)
    inp = replace(sc.inp, meta={**sc.inp.meta, "keypoints2d": uv.double().numpy().tolist()})
    scene = Scene.from_input(inp, hand, torch.float64)
    params = sc.gt_hand.to(dtype=torch.float64)
    terms = refine_terms(scene, params, sc.gt_metric_scale, params.pose, cfg,
                         sc.gt_camera.to(torch.float64))  # fmt: skip
    assert float(terms["keypoints"]) < 1e-10
    moved = replace(params, transl=params.transl + torch.tensor([[0.01, 0.0, 0.0]]).double())
    terms = refine_terms(scene, moved, sc.gt_metric_scale, params.pose, cfg,
                         sc.gt_camera.to(torch.float64))  # fmt: skip
    assert float(terms["keypoints"]) > 1e-4
    assert math.isfinite(float(terms["total"]))


def test_push_out_takes_a_sunken_hand_out_without_bending_it():
    from dataclasses import replace

    from easyhoi.config import get_preset
    from easyhoi.optim.refine import push_out
    from easyhoi.optim.state import Scene
    from easyhoi.testing.optim_scenes import make_scene

    sc = make_scene("box")
    cfg = replace(get_preset("fast").optim.refine, push_out_steps=6)
    scene = Scene.from_input(sc.inp, sc.model, torch.float64)
    p = sc.gt_hand.to(dtype=torch.float64)
    m = sc.gt_metric_scale
    with torch.no_grad():
        v = sc.model(p).vertices[0] / m
    towards = scene.center.double() - v.mean(0)
    towards = towards / towards.norm()
    sunk = replace(p, transl=p.transl + (0.15 * scene.extent * m) * towards[None])
    with torch.no_grad():
        d0 = scene.sdf(sc.model(sunk).vertices[0] / m, cfg.sdf_resolution)
    assert float(d0.min()) < -0.03  # deeply inside
    move, note = push_out(scene, sunk, m, cfg)
    with torch.no_grad():
        d1 = scene.sdf(sc.model(sunk).vertices[0] / m + move, cfg.sdf_resolution)
    # out but for the finger pads and the palm, which may stay up to pad_tolerance_m inside
    pads = torch.zeros(d1.shape[-1], dtype=torch.bool)
    pads[scene.regions.contact_vertices] = True
    assert float(d1[~pads].min()) > -0.01
    assert float(d1[pads].min()) > -cfg.pad_tolerance_m / (m * float(scene.extent)) - 0.01
    assert note["steps"] >= 1 and 0.03 < note["distance"] <= 0.2 + 1e-9
    # nothing to do for a hand outside the object
    move, note = push_out(scene, p, m, cfg)
    assert note["steps"] == 0 and float(move.norm()) == 0.0


def test_push_out_along_the_camera_ray_keeps_the_hand_in_the_image():
    """Pushed out along the ray through the hand, the sunken hand leaves the object and its 21
    keypoints stay within 1 % of the photo's width of where they were (a move along the
    object's normal shifts them more than 1.5 times as far)."""
    from dataclasses import replace

    from easyhoi.config import get_preset
    from easyhoi.optim.refine import push_out
    from easyhoi.optim.state import Scene
    from easyhoi.testing.optim_scenes import make_scene

    sc = make_scene("box")
    cfg = replace(get_preset("fast").optim.refine, push_out_steps=6)
    scene = Scene.from_input(sc.inp, sc.model, torch.float64)
    cam = sc.gt_camera.to(torch.float64)
    p = sc.gt_hand.to(dtype=torch.float64)
    m = sc.gt_metric_scale
    with torch.no_grad():
        out = sc.model(p)
        v, k = out.vertices[0] / m, out.keypoints[0] / m
    # sunk along the ray through the hand (a depth error: the photo cannot tell)
    ray = v.mean(0) - cam.center.double()
    ray = ray / ray.norm()
    with torch.no_grad():
        d_gt = scene.sdf(v, cfg.sdf_resolution)
    shift = 0.12 * scene.extent * ray
    assert float(scene.sdf(v + shift, cfg.sdf_resolution).min()) < -0.025  # deeply inside
    sunk = replace(p, transl=p.transl + m * shift[None])
    uv0, _ = cam.project(k + shift)
    move, note = push_out(scene, sunk, m, cfg, cam)
    with torch.no_grad():
        d1 = scene.sdf(v + shift + move, cfg.sdf_resolution)
    assert float(d1.min()) > min(-0.01, float(d_gt.min()) - 1e-6)
    assert note["steps"] >= 1
    uv1, _ = cam.project(k + shift + move)
    width = cam.width
    moved_ray = float((uv1 - uv0).norm(dim=1).max())
    assert moved_ray < 0.01 * width
    # the direction is the ray's (parallel to it)
    cos = float(move @ ray) / float(move.norm())
    assert abs(cos) > 1 - 1e-9
    # the normal push moves the keypoints more in the image
    move_n, _ = push_out(scene, sunk, m, cfg)
    uv2, _ = cam.project(k + shift + move_n)
    assert float((uv2 - uv0).norm(dim=1).max()) > 1.5 * moved_ray


def test_hand_change_zero_for_unchanged_hand_and_counts_moves():
    from easyhoi.optim.hand_change import hand_change
    from easyhoi.structures import Camera
    from easyhoi.testing.optim_scenes import make_scene

    sc = make_scene("cylinder")
    inp = sc.inp
    est = inp.hand_params.to(dtype=torch.float64)
    cam = inp.hand_camera.to(torch.float64)
    # the estimator's hand in its own camera, "object frame" = that camera frame, m = 1
    same = hand_change(sc.model, inp, est, cam, 1.0)
    assert same["max_cm"] < 1e-6 and same["max_px"] < 1e-6
    assert len(same["cm"]) == 21 and len(same["px"]) == 21
    # translating by 1 cm sideways: 0 cm after wrist alignment, px > 0
    moved = type(est)(est.global_orient, est.transl + torch.tensor([[0.01, 0.0, 0.0]]).double(),
                      est.pose, est.betas, est.side)  # fmt: skip
    ch = hand_change(sc.model, inp, moved, cam, 1.0)
    assert ch["max_cm"] < 1e-6 and ch["mean_px"] > 0.5
    # object units twice as small (m = 0.5) and the camera's translation in those units: the
    # same hand in the same place
    cam2 = Camera(cam.K, cam.R, cam.t * 2.0, cam.width, cam.height)
    ch = hand_change(sc.model, inp, est, cam2, 0.5)
    assert ch["max_px"] < 1e-6 and ch["max_cm"] < 1e-6
    bent = type(est)(est.global_orient, est.transl, est.pose + 0.3, est.betas, est.side)
    assert hand_change(sc.model, inp, bent, cam, 1.0)["max_cm"] > 0.5


def test_push_out_as_a_scale_keeps_the_projection_exactly():
    """The push-out as a change of the metric scale frees the sunken hand and keeps its 21
    keypoints' pixels (to rounding), where the translation along the centroid's ray moves them;
    the refined hand then belongs to the new scale (fit_refine reports it)."""
    from dataclasses import replace

    from easyhoi.config import get_preset
    from easyhoi.optim.refine import push_out
    from easyhoi.optim.state import Scene
    from easyhoi.testing.optim_scenes import make_scene

    sc = make_scene("box")
    cfg = replace(get_preset("fast").optim.refine, push_out_steps=6)
    scene = Scene.from_input(sc.inp, sc.model, torch.float64)
    cam = sc.gt_camera.to(torch.float64)
    p = sc.gt_hand.to(dtype=torch.float64)
    m = sc.gt_metric_scale
    with torch.no_grad():
        out = sc.model(p)
        v, k = out.vertices[0] / m, out.keypoints[0] / m
    eye = cam.center.double()
    ray = v.mean(0) - eye
    ray = ray / ray.norm()
    shift = 0.12 * scene.extent * ray
    sunk = replace(p, transl=p.transl + m * shift[None])
    assert float(scene.sdf(v + shift, cfg.sdf_resolution).min()) < -0.025
    factor, note = push_out(scene, sunk, m, cfg, cam, as_scale=True)
    f = float(factor)
    assert note["steps"] >= 1 and f != 1.0
    assert note["scale_factor"] == pytest.approx(1.0 / f)
    freed = eye + (v + shift - eye) * f
    assert float(scene.sdf(freed, cfg.sdf_resolution).min()) > -0.01
    uv0, _ = cam.project(k + shift)
    uv1, _ = cam.project(eye + (k + shift - eye) * f)
    assert float((uv1 - uv0).norm(dim=1).max()) < 1e-6
    move, _ = push_out(scene, sunk, m, cfg, cam)
    uv2, _ = cam.project(k + shift + move)
    assert float((uv2 - uv0).norm(dim=1).max()) > 0.05
