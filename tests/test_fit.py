import math

import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.fit import FitConfig, fit_keypoints, kabsch
from easyhoi.structures import Camera, HandParams
from easyhoi.testing.toy_hand import ToyHand
from tests.helpers import assert_close


def plausible_pose(batch: int, gen: torch.Generator, dtype=torch.float64) -> torch.Tensor:
    """Flexion about each joint's flexion axis, small sideways spread at the knuckles, no twist."""
    from easyhoi.hand.fit import anatomical_prior_weights

    axes = anatomical_prior_weights(ToyHand(), 1.0, dtype).axes  # (15, 3, 3): flex, bone, side
    flex = torch.rand(batch, 15, 1, generator=gen, dtype=dtype) * 1.0
    spread = (torch.rand(batch, 15, 1, generator=gen, dtype=dtype) - 0.5) * 0.3
    knuckle = torch.zeros(15, 1, dtype=dtype)
    knuckle[[0, 3, 6, 9]] = 1.0
    pose = flex * axes[None, :, 0] + spread * knuckle * axes[None, :, 2]
    return pose.reshape(batch, 45)


def random_params(batch, gen, dtype=torch.float64):
    go = (torch.rand(batch, 3, generator=gen, dtype=dtype) - 0.5) * 2.0
    tr = (torch.rand(batch, 3, generator=gen, dtype=dtype) - 0.5) * 0.2
    tr[:, 2] += 0.6
    betas = torch.zeros(batch, 10, dtype=dtype)
    betas[:, :2] = (torch.rand(batch, 2, generator=gen, dtype=dtype) - 0.5) * 2
    return HandParams(go, tr, plausible_pose(batch, gen, dtype), betas)


def test_kabsch_recovers_rotation():
    from easyhoi.geometry.transforms import random_rotations

    g = torch.Generator().manual_seed(0)
    src = torch.randn(4, 10, 3, generator=g, dtype=torch.float64)
    R = random_rotations(4, g)
    t = torch.randn(4, 3, generator=g, dtype=torch.float64)
    dst = src @ R.transpose(1, 2) + t[:, None]
    R2, t2 = kabsch(src, dst)
    assert_close(R2, R, atol=1e-10)
    assert_close(t2, t, atol=1e-10)


def test_fit_3d_round_trip_toy():
    model = ToyHand()
    g = torch.Generator().manual_seed(3)
    gt = random_params(4, g)
    target = model(gt).keypoints
    fit = fit_keypoints(model, target)
    assert fit.error_3d.max() < 2e-3  # below 2 mm everywhere
    assert fit.error_3d.mean() < 5e-4


def test_fit_2d_plus_relative_3d_recovers_placement():
    model = ToyHand()
    g = torch.Generator().manual_seed(5)
    gt = random_params(2, g)
    cam = Camera.from_focal(800.0, 640, 480, dtype=torch.float64)
    kp = model(gt).keypoints
    uv, _ = cam.project(kp)
    rel = kp - kp.mean(1, keepdim=True) + 0.3  # unknown offset
    fit = fit_keypoints(model, rel, keypoints2d=uv, camera=cam, relative_3d=True)
    assert fit.error_2d.max() < 2.0  # pixels
    kp_fit = fit.keypoints
    assert (kp_fit - kp).norm(dim=-1).max() < 0.01  # placement within 1 cm at 0.6 m


def test_fit_left_hand_round_trip():
    model = ToyHand()
    g = torch.Generator().manual_seed(7)
    gt = random_params(2, g)
    from easyhoi.hand.base import mirror_params

    gt_left = mirror_params(gt)  # the mirror image of an anatomical right hand
    target = model(gt_left).keypoints
    fit = fit_keypoints(model, target, side="left")
    assert fit.params.side == "left"
    assert fit.error_3d.max() < 2e-3
    assert_close(model(fit.params).keypoints, target, atol=2e-3)


def test_fit_is_robust_to_one_outlier():
    model = ToyHand()
    g = torch.Generator().manual_seed(11)
    gt = random_params(1, g)
    target = model(gt).keypoints.clone()
    target[0, 8] += torch.tensor([0.08, 0.05, 0.0], dtype=torch.float64)  # index tip way off
    fit = fit_keypoints(model, target, config=FitConfig(robust_scale_m=0.01))
    err = fit.error_3d[0]
    others = torch.cat([err[:8], err[9:]])
    assert others.median() < 3e-3


def test_fit_rejects_bad_input():
    model = ToyHand()
    with pytest.raises(InvalidInputError):
        fit_keypoints(model, torch.zeros(1, 20, 3))
    with pytest.raises(InvalidInputError):
        fit_keypoints(model, None)
    with pytest.raises(InvalidInputError):
        fit_keypoints(model, keypoints2d=torch.zeros(1, 21, 2))
    bad = torch.zeros(1, 21, 3)
    bad[0, 0, 0] = math.nan
    with pytest.raises(InvalidInputError):
        fit_keypoints(model, bad)


def test_fit_openhand_round_trip_pose_close():
    from easyhoi.hand.openhand import OpenHand
    from easyhoi.hand.regions import flexion_axes

    model = OpenHand(dtype=torch.float64)
    axes = torch.as_tensor(flexion_axes(model), dtype=torch.float64)  # (15, 3), + flexes
    g = torch.Generator().manual_seed(0)
    B = 3
    flex = torch.rand(B, 15, 1, generator=g, dtype=torch.float64) * 1.2
    pose = (flex * axes[None]).reshape(B, 45)
    go = (torch.rand(B, 3, generator=g, dtype=torch.float64) - 0.5) * 2
    tr = torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64).expand(B, 3)
    betas = torch.zeros(B, 10, dtype=torch.float64)
    betas[:, 0] = torch.tensor([-1.0, 0.0, 1.5], dtype=torch.float64)
    gt = HandParams(go, tr, pose, betas)
    target = model(gt).keypoints
    fit = fit_keypoints(model, target)
    assert fit.error_3d.max() < 2e-3  # metres
    # pose close: per-joint rotation angle difference
    from easyhoi.geometry.transforms import axis_angle_to_matrix

    Ra = axis_angle_to_matrix(fit.params.pose.reshape(B, 15, 3).double())
    Rb = axis_angle_to_matrix(pose.reshape(B, 15, 3))
    cos = ((Ra.transpose(-1, -2) @ Rb).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    angle = torch.arccos(cos.clamp(-1, 1))
    assert angle.mean() < 0.1  # radians, mean over joints
    go_err = (fit.params.global_orient.double() - go).norm(dim=-1)
    assert go_err.max() < 0.05


def _flexed_mean_hand(flex: float):
    """OpenHand (float64) and the mean hand 0.5 m ahead, every joint flexed by ``flex`` rad."""
    from easyhoi.hand.openhand import OpenHand
    from easyhoi.hand.regions import flexion_axes

    model = OpenHand(dtype=torch.float64)
    axes = torch.as_tensor(flexion_axes(model), dtype=torch.float64)
    pose = (flex * axes[None]).reshape(1, 45)
    z = torch.zeros(1, 3, dtype=torch.float64)
    gt = HandParams(z, z + torch.tensor([[0.0, 0.0, 0.5]], dtype=torch.float64), pose,
                    torch.zeros(1, 10, dtype=torch.float64))  # fmt: skip
    return model, gt


def test_a_narrow_knuckle_line_is_not_read_as_a_narrow_palm():
    """Keypoints whose index and little-finger knuckles sit closer together than the model's
    (as the detector's do, FitConfig.knuckle_3d_weight) leave the fitted proportions near the
    model's; with the knuckles counted fully and no proportion prior the palm width gives."""
    from easyhoi.hand.fit import PALM_EDGE_KNUCKLES, FitConfig

    model, gt = _flexed_mean_hand(0.4)
    target = model(gt).keypoints.clone()
    mid = target[:, 9]
    for k in PALM_EDGE_KNUCKLES:  # 30 % of the way towards the middle knuckle
        target[:, k] += 0.3 * (mid - target[:, k])
    fitted = fit_keypoints(model, target).params.betas[0]
    loose = FitConfig(proportion_prior=0.0, knuckle_3d_weight=1.0)
    free = fit_keypoints(model, target, config=loose).params.betas[0]
    assert free[2] < -1.5  # the palm read as about 10 % narrower
    assert fitted[1:6].abs().max() < 0.3 and abs(float(fitted[2])) < 0.25 * abs(float(free[2]))
    # nor is the size what gives instead
    assert abs(float(fitted[0])) < 0.3


def test_a_scale_free_3d_term_leaves_the_size_to_the_prior():
    """Keypoints of the mean hand scaled by 0.85 (a detector whose metric keypoints are smaller
    than the model's): with the 3D term compared up to scale the fitted size stays the mean and
    the pose and proportions are those of the keypoints; compared as they are, the size gives."""
    from easyhoi.hand.fit import _compared_3d

    model, gt = _flexed_mean_hand(0.5)
    kp = model(gt).keypoints
    target = (kp - kp.mean(1, keepdim=True)) * 0.85
    free = fit_keypoints(model, target, relative_3d=True, config=FitConfig(scale_free_3d=True))
    plain = fit_keypoints(model, target, relative_3d=True)
    assert float(plain.params.betas[0, 0]) < -2.0  # 15 % smaller: about -3 units of 5 %
    assert abs(float(free.params.betas[0, 0])) < 0.3
    assert free.params.betas[0, 1:].abs().max() < 0.3
    assert free.error_3d.max() < 2e-3  # the shape matches (compared up to scale)
    fitted = model(free.params).keypoints
    fitted = fitted - fitted.mean(1, keepdim=True)
    assert (fitted - (kp - kp.mean(1, keepdim=True))).norm(dim=-1).max() < 3e-3  # metres

    # the comparison itself against a plain implementation; without relative_3d it is a no-op
    g = torch.Generator().manual_seed(3)
    a = torch.randn(2, 21, 3, generator=g, dtype=torch.float64)
    b = torch.randn(2, 21, 3, generator=g, dtype=torch.float64) + 5.0
    ca, cb = _compared_3d(a, b, relative=True, scale_free=True)
    for i in range(2):
        ac, bc = a[i] - a[i].mean(0), b[i] - b[i].mean(0)
        assert_close(cb[i], bc)
        assert_close(ca[i], ac * (bc.norm() / ac.norm()))
    assert _compared_3d(a, b, relative=False, scale_free=True)[1] is b
    # the model's size does not change what is compared (no gradient along a pure scaling)
    a2 = a.clone().requires_grad_(True)
    s = torch.ones(1, dtype=torch.float64, requires_grad=True)
    ca, cb = _compared_3d(a2 * s, b, relative=True, scale_free=True)
    ((ca - cb) ** 2).sum().backward()
    assert abs(float(s.grad)) < 1e-9
