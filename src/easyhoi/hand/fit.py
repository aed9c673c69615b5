"""Fit hand parameters to 21 keypoints (3D, optionally with 2D reprojection through a camera).

The fit is a batched, robust least-squares problem solved in float64 with L-BFGS:

1. Rigid initialisation: Kabsch alignment of the model's rest-pose palm keypoints (wrist and the
   four finger bases) to the targets gives the global rotation and translation.
2. Articulation: all parameters (global rotation, translation, 45 articulation values and
   optionally the shape) minimise a Geman-McClure-robustified keypoint error plus small
   quadratic priors on articulation and shape (these keep the twist about each bone, which
   keypoints cannot observe, near zero).

With 2D keypoints and a camera, a reprojection term (pixels, robustified) is added; with
``relative_3d=True`` the 3D term compares centred keypoint sets, which is what a root-relative
estimator (e.g. MediaPipe world landmarks) provides: the 3D term then fixes articulation and
size, the 2D term the placement.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
import torch

from easyhoi.checks import check_finite, check_shape
from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle
from easyhoi.hand.base import HandModel, mirror_params, mirror_points
from easyhoi.structures import NUM_KEYPOINTS, OPENPOSE_ORDER, Camera, HandParams

_NO_VERTS = torch.zeros(0, dtype=torch.long)

#: Palm keypoints (OpenPose order): wrist, index/middle/ring/pinky bases; nearly rigid.
PALM_KEYPOINTS = (0, 5, 9, 13, 17)


#: OpenPose indices of the index and little-finger knuckles (MCP), the palm's edges.
PALM_EDGE_KNUCKLES = (5, 17)


@dataclass(frozen=True)
class FitConfig:
    """Settings of :func:`fit_keypoints`.

    Attributes:
        iterations: L-BFGS outer iterations of the full fit.
        robust_scale_m: Geman-McClure scale for 3D residuals (metres).
        robust_scale_px: Geman-McClure scale for 2D residuals (pixels).
        weight_2d: weight of the 2D term relative to the 3D term (per-pixel residuals are divided
            by ``robust_scale_px`` and 3D ones by ``robust_scale_m`` before weighting).
        pose_prior: weight of ``||pose||^2``.
        shape_prior: weight of ``||betas||^2``.
        proportion_prior: weight of ``||betas[1:]||^2`` on top of ``shape_prior``. The
            coefficients after the first (the size) are the hand's proportions (OpenHand: digit
            length, palm width, finger and palm thickness, thumb length, 5 % per unit; MANO: its
            shape space's unit-variance directions). One photo's keypoints hardly determine
            them, and with ``shape_prior`` alone the fit left proportions no adult hand has
            (a palm 55 % narrower than the model's; docs/benchmark.md). 0.1 is a standard
            deviation of about 3 units, wider than adult hands vary.
        knuckle_3d_weight: weight of the 3D residuals of the index and little-finger knuckles
            (:data:`PALM_EDGE_KNUCKLES`); their 2D residuals count fully. The detector's
            skeleton and the hand model place those joints differently across the palm (the
            distance between them over the palm's length is 0.57 in the detector's 3D
            keypoints, median of the 44 hands of the development photos, and 0.67 between
            OpenHand's joints): a difference of definition, which the fit must not read as a
            narrow palm.
        scale_free_3d: with ``relative_3d``, compare the 3D keypoints up to scale (the model's
            centred keypoints scaled to the targets' size): their shape sets the articulation
            and proportions, and the size is left to the other terms (the 2D keypoints'
            perspective, ``shape_prior``, ``size_prior``). For a detector's metric keypoints,
            whose size is the detector's estimate in its own landmark definitions and not a
            measurement (:data:`easyhoi.perception.hand_fit.DETECTION_FIT`); the reported
            ``error_3d`` is then the error up to scale too.
        size_prior: weight of ``betas[0]^2`` (the size) on top of ``shape_prior``; 0.5 is a
            standard deviation of about 1.4 units (7 %), about as much as adult hands vary.
            For a size no keypoint measures: the 2D keypoints' perspective moves it only
            through the assumed field of view.
        fit_shape: optimise betas (else they stay at the initial value).
        anatomy_weight: weight of the anatomical prior (:func:`anatomical_prior_weights`):
            penalises twist about the bones, sideways bending of the finger hinges and
            hyper-extension, which noisy keypoints otherwise turn into crumpled fingers.
    """

    iterations: int = 20
    robust_scale_m: float = 0.02
    robust_scale_px: float = 20.0
    weight_2d: float = 1.0
    pose_prior: float = 1e-5
    shape_prior: float = 1e-2
    proportion_prior: float = 0.1
    scale_free_3d: bool = False
    size_prior: float = 0.0
    knuckle_3d_weight: float = 0.25
    fit_shape: bool = True
    anatomy_weight: float = 1.0


@dataclass(frozen=True)
class KeypointFit:
    """Result of :func:`fit_keypoints`.

    Attributes:
        params: fitted :class:`HandParams` (float32 unless the targets were float64).
        keypoints: (B, 21, 3) fitted keypoints.
        error_3d: (B, 21) Euclidean 3D error per keypoint in metres (after centring when the fit
            was relative), or None without 3D targets.
        error_2d: (B, 21) reprojection error in pixels, or None without 2D targets.
        loss: final objective value.
    """

    params: HandParams
    keypoints: torch.Tensor
    error_3d: torch.Tensor | None
    error_2d: torch.Tensor | None
    loss: float


def _gm(r2: torch.Tensor, scale: float) -> torch.Tensor:
    """Geman-McClure on squared residuals: ``s^2 r^2 / (s^2 + r^2)`` in normalised units."""
    x = r2 / scale**2
    return x / (1 + x)


def kabsch(src: torch.Tensor, dst: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation R and translation t minimising ``||R src + t - dst||`` per batch.

    Args:
        src, dst: (B, N, 3).
    Returns:
        R (B, 3, 3), t (B, 3).
    """
    mu_s, mu_d = src.mean(1, keepdim=True), dst.mean(1, keepdim=True)
    H = (src - mu_s).transpose(1, 2) @ (dst - mu_d)
    U, _, Vt = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vt.transpose(1, 2) @ U.transpose(1, 2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    R = Vt.transpose(1, 2) @ D @ U.transpose(1, 2)
    t = mu_d[:, 0] - (R @ mu_s.transpose(1, 2))[..., 0]
    return R, t


def _compared_3d(kp: torch.Tensor, k3: torch.Tensor, relative: bool, scale_free: bool):
    """The model's (B, 21, 3) keypoints and the targets as the 3D term compares them: centred
    when ``relative``; with ``scale_free`` the model's centred keypoints are also scaled to the
    targets' root-mean-square size, so that their shape counts and the model's size does not
    (scaling the targets instead would let a shrinking model shrink the residuals)."""
    if not relative:
        return kp, k3
    a, b = kp - kp.mean(1, keepdim=True), k3 - k3.mean(1, keepdim=True)
    if scale_free:
        rms = lambda x: x.pow(2).sum((1, 2), keepdim=True).clamp_min(1e-12).sqrt()  # noqa: E731
        a = a * (rms(b) / rms(a))
    return a, b


def _validate(keypoints3d, keypoints2d, camera, weights):
    if keypoints3d is None and keypoints2d is None:
        raise InvalidInputError("fit_keypoints needs 3D keypoints, 2D keypoints, or both")
    B = None
    for name, kp, d in (("keypoints3d", keypoints3d, 3), ("keypoints2d", keypoints2d, 2)):
        if kp is None:
            continue
        check_shape(kp, (B, NUM_KEYPOINTS, d), name)
        check_finite(kp, name)
        B = kp.shape[0]
    if keypoints2d is not None and camera is None:
        raise InvalidInputError("2D keypoints need a Camera to project through")
    if weights is not None:
        check_shape(weights, (B, NUM_KEYPOINTS), "weights")
    return B


def fit_keypoints(
    model: HandModel,
    keypoints3d: torch.Tensor | None = None,
    *,
    keypoints2d: torch.Tensor | None = None,
    camera: Camera | None = None,
    side: str = "right",
    relative_3d: bool = False,
    weights: torch.Tensor | None = None,
    init: HandParams | None = None,
    config: FitConfig = FitConfig(),
) -> KeypointFit:
    """Fit MANO-layout hand parameters to 21 keypoints in OpenPose order.

    Args:
        model: any :class:`HandModel` (built-in open hand or MANO).
        keypoints3d: (B, 21, 3) target keypoints in metres (camera or world frame), or None.
        keypoints2d: (B, 21, 2) target pixels (needs ``camera``), or None.
        camera: camera for the 2D term; 3D targets are then in its world frame.
        side: "right" or "left" (left hands are fitted as mirrored right hands).
        relative_3d: compare centred 3D sets (targets known up to a translation).
        weights: (B, 21) per-keypoint confidence weights (default 1).
        init: initial parameters (else a Kabsch initialisation from the 3D palm keypoints, or
            a hand 0.5 m in front of the camera when only 2D targets are given).
        config: :class:`FitConfig`.
    Returns:
        :class:`KeypointFit`.
    """
    B = _validate(keypoints3d, keypoints2d, camera, weights)
    if side not in ("right", "left"):
        raise InvalidInputError(f"side must be 'right' or 'left', got {side!r}")
    out_dtype = (keypoints3d if keypoints3d is not None else keypoints2d).dtype
    dt = torch.float64
    k3 = keypoints3d.to(dt) if keypoints3d is not None else None
    k2 = keypoints2d.to(dt) if keypoints2d is not None else None
    cam = camera.detach().to(dtype=dt) if camera is not None else None
    w = (weights if weights is not None else torch.ones(B, NUM_KEYPOINTS)).to(dt)
    left = side == "left"
    if left:  # fit a right hand to the mirrored targets, mirror the result back
        k3 = mirror_points(k3) if k3 is not None else None
        if cam is not None:
            M = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=dt))
            cam = replace(cam, R=cam.R @ M)  # world point x -> camera sees mirror(x) as before
            if init is not None:
                init = mirror_params(init)

    p0 = _initial_params(model, k3, k2, cam, relative_3d, B, init)
    anatomy = anatomical_prior_weights(model, config.anatomy_weight, dt)
    n_shape = 10 if config.fit_shape else 0

    def unpack(x: torch.Tensor) -> HandParams:
        betas = x[:, 51:61] if config.fit_shape else p0.betas
        return HandParams(x[:, :3], x[:, 3:6], x[:, 6:51], betas)

    knuckles = torch.ones(NUM_KEYPOINTS, 1, dtype=dt)
    knuckles[list(PALM_EDGE_KNUCKLES)] = config.knuckle_3d_weight**0.5

    def keypoint_residuals(x: torch.Tensor, kp_weights: torch.Tensor) -> torch.Tensor:
        """(B, R_kp) scaled keypoint residuals; ``kp_weights`` (B, 21, 2) are IRLS x confidence."""
        kp = model(unpack(x), vertex_ids=_NO_VERTS).keypoints
        parts = []
        if k3 is not None:
            a, b = _compared_3d(kp, k3, relative_3d, config.scale_free_3d)
            r = (a - b) / config.robust_scale_m * kp_weights[..., 0:1].sqrt() * knuckles
            parts.append(r.reshape(B, -1))
        if k2 is not None:
            uv, _ = cam.project(kp)
            r = (
                (uv - k2)
                / config.robust_scale_px
                * (config.weight_2d * kp_weights[..., 1:2]).sqrt()
            )
            parts.append(r.reshape(B, -1))
        return torch.cat(parts, dim=1)

    def prior_residuals(x: torch.Tensor, kp_weights: torch.Tensor) -> torch.Tensor:
        """(B, R_prior) residuals of the pose, anatomy and shape priors (the model not used)."""
        parts = [x[:, 6:51] * config.pose_prior**0.5]
        if anatomy is not None:
            aa = x[:, 6:51].reshape(B, 15, 1, 3)
            comp = (aa * anatomy.axes).sum(-1)  # (B, 15, 3): flexion, twist, sideways
            hyper = torch.relu(-comp[..., 0] - HYPEREXTENSION_ALLOWANCE)
            parts.append((comp[..., 1:] * anatomy.weights[:, 1:]).reshape(B, -1))
            parts.append(hyper * anatomy.weights[:, 0])
        if n_shape:
            parts.append(x[:, 51:61] * config.shape_prior**0.5)
            if config.proportion_prior > 0:
                parts.append(x[:, 52:61] * config.proportion_prior**0.5)
            if config.size_prior > 0:
                parts.append(x[:, 51:52] * config.size_prior**0.5)
        return torch.cat(parts, dim=1)

    def irls_weights(x: torch.Tensor, anneal: float) -> torch.Tensor:
        """Geman-McClure IRLS weights rho'(r^2 / s^2) = 1 / (1 + r^2 / s^2)^2, times confidence."""
        with torch.no_grad():
            kp = model(unpack(x), vertex_ids=_NO_VERTS).keypoints
            out = torch.ones(B, NUM_KEYPOINTS, 2, dtype=dt)
            if k3 is not None:
                a, b = _compared_3d(kp, k3, relative_3d, config.scale_free_3d)
                q = ((a - b) ** 2).sum(-1) / (anneal * config.robust_scale_m) ** 2
                out[..., 0] = 1 / (1 + q) ** 2
            if k2 is not None:
                q = ((cam.project(kp)[0] - k2) ** 2).sum(-1) / (
                    anneal * config.robust_scale_px
                ) ** 2
                out[..., 1] = 1 / (1 + q) ** 2
            return out * w[..., None]

    x = torch.cat([p0.global_orient, p0.transl, p0.pose] + ([p0.betas] if n_shape else []), dim=1)
    # graduated non-convexity: a wide robust kernel first, then the configured one
    schedule = [10.0] * (config.iterations // 3) + [1.0] * (
        config.iterations - config.iterations // 3
    )
    residuals = (keypoint_residuals, prior_residuals)  # stacked in this order
    x, last = _levenberg_marquardt(residuals, irls_weights, x, schedule)

    with torch.no_grad():
        fitted = unpack(x)
        kp = model(fitted).keypoints
        e3 = e2 = None
        if k3 is not None:
            a, b = _compared_3d(kp, k3, relative_3d, config.scale_free_3d)
            e3 = (a - b).norm(dim=-1)
        if k2 is not None:
            e2 = (cam.project(kp)[0] - k2).norm(dim=-1)
        if left:
            fitted = mirror_params(fitted)
            kp = mirror_points(kp)
    cast = lambda x: None if x is None else x.to(out_dtype)  # noqa: E731
    return KeypointFit(fitted.to(dtype=out_dtype), kp.to(out_dtype), cast(e3), cast(e2), last)


#: Flexion below this (radians, i.e. hyper-extension) is free; beyond it the prior applies.
HYPEREXTENSION_ALLOWANCE = 0.15


@dataclass(frozen=True)
class AnatomicalPrior:
    """Per-joint axes and weights of the anatomical prior.

    Attributes:
        axes: (15, 3, 3) rows: flexion axis, bone axis (twist), sideways axis, rest frame.
        weights: (15, 3) residual weights per radian: hyper-extension, twist, sideways.
    """

    axes: torch.Tensor
    weights: torch.Tensor


def anatomical_prior_weights(model: HandModel, scale: float, dtype) -> AnatomicalPrior | None:
    """Joint axes from the model's rest geometry and the prior's weights (None if ``scale == 0``).

    Finger hinges (PIP, DIP) bend about one axis: sideways bending costs 3 per radian; the
    knuckles (MCP) may spread (0.7); twist about a bone costs 3 everywhere except the thumb's
    base (CMC), which is a saddle joint with wide freedom (0.3). Weights are per radian in the
    units of the keypoint residuals (1 = one robust scale of keypoint error).
    """
    if scale <= 0:
        return None
    from easyhoi.hand.regions import bone_axes, flexion_axes, rest_geometry

    verts, _, _, joints = rest_geometry(model)
    flex = flexion_axes(model)
    bone = bone_axes(joints, verts[model.tip_vertex_ids.cpu().numpy()])[1:]
    side = np.cross(flex, bone)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    w = np.zeros((15, 3))
    for j in range(1, 16):
        if j == 13:  # thumb CMC
            w[j - 1] = (0.5, 0.3, 0.3)
        elif j in (1, 4, 7, 10):  # finger MCP
            w[j - 1] = (3.0, 3.0, 0.7)
        elif j == 14:  # thumb MCP
            w[j - 1] = (1.0, 1.5, 1.0)
        else:  # PIP, DIP, thumb IP
            w[j - 1] = (3.0, 3.0, 3.0)
    axes = np.stack([flex, bone, side], axis=1)
    return AnatomicalPrior(
        torch.as_tensor(axes, dtype=dtype), torch.as_tensor(w * scale, dtype=dtype)
    )


def _rotation_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) minimal rotation taking directions a (B, 3) to b (B, 3)."""
    a = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    b = b / b.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    axis = torch.cross(a, b, dim=-1)
    s = axis.norm(dim=-1, keepdim=True)
    c = (a * b).sum(-1, keepdim=True)
    angle = torch.atan2(s, c)
    aa = axis / s.clamp_min(1e-12) * angle
    return axis_angle_to_matrix(aa)


#: For each non-root joint: the keypoint (OpenPose index) of its child along the finger.
def _child_keypoint(j: int) -> int:
    tip_of = {3: 17, 6: 18, 9: 20, 12: 19, 15: 16}  # source index of the finger's tip
    src = tip_of.get(j, j + 1)
    return OPENPOSE_ORDER.index(src)


def inverse_kinematics(model: HandModel, k3: torch.Tensor, betas: torch.Tensor) -> HandParams:
    """Closed-form pose from 3D keypoints: palm by Kabsch, each bone by the minimal rotation.

    Args:
        model: hand model (right hand).
        k3: (B, 21, 3) target keypoints (OpenPose order).
        betas: (B, 10) shape to use.
    Returns:
        :class:`HandParams` whose bone directions match the targets (no twist about bones).
    """
    B, dt = k3.shape[0], k3.dtype
    zero = HandParams(
        torch.zeros(B, 3, dtype=dt), torch.zeros(B, 3, dtype=dt), torch.zeros(B, 45, dtype=dt),
        betas,
    )  # fmt: skip
    out = model(zero)
    rest_kp, j0 = out.keypoints, out.joints[:, 0]
    idx = list(PALM_KEYPOINTS)
    R0, t = kabsch(rest_kp[:, idx], k3[:, idx])
    # global_orient rotates about the wrist joint j0: x' = R (x - j0) + j0 + transl
    transl = t + (R0 @ j0[..., None])[..., 0] - j0
    glob = [R0] + [None] * 15  # global (accumulated) rotation of every joint
    local = torch.eye(3, dtype=dt).repeat(B, 15, 1, 1)
    for j in range(1, 16):
        parent = model.parents[j]
        kp_j = OPENPOSE_ORDER.index(j)
        kp_c = _child_keypoint(j)
        rest_dir = rest_kp[:, kp_c] - rest_kp[:, kp_j]
        Gp = glob[parent]
        cur = (Gp @ rest_dir[..., None])[..., 0]
        want = k3[:, kp_c] - k3[:, kp_j]
        G = _rotation_between(cur, want) @ Gp
        glob[j] = G
        local[:, j - 1] = Gp.transpose(1, 2) @ G
    return HandParams(
        matrix_to_axis_angle(R0), transl, matrix_to_axis_angle(local).reshape(B, 45), betas
    )


def _initial_params(model, k3, k2, cam, relative_3d, B, init) -> HandParams:
    dt = torch.float64
    if init is not None:
        if init.batch_size != B:
            raise InvalidInputError(f"init has batch {init.batch_size}, targets have batch {B}")
        return init.to(dtype=dt)
    p = HandParams.zeros(B, dtype=dt)
    if k3 is not None:
        ik = inverse_kinematics(model, k3, p.betas)
        if relative_3d and k2 is not None:
            ik = replace(ik, transl=_place_by_2d(model, ik, k2, cam))
        return ik
    # 2D only: put the hand in front of the camera at a depth matching its pixel size
    return HandParams(p.global_orient, _place_by_2d(model, p, k2, cam), p.pose, p.betas)


def _place_by_2d(model, params: HandParams, k2, cam) -> torch.Tensor:
    """Translation putting the hand's keypoints where the 2D keypoints are (similar triangles)."""
    kp = model(params).keypoints  # (B, 21, 3) with the current transl
    kc = cam.world_to_camera(kp)
    centred = kc - kc.mean(1, keepdim=True)
    size3 = centred[..., :2].norm(dim=-1).mean(1)  # metres, in the image plane
    size2 = (k2 - k2.mean(1, keepdim=True)).norm(dim=-1).mean(1)  # pixels
    f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
    depth = f * size3 / size2.clamp_min(1e-6)
    centre_uv = k2.mean(1)
    target_centre = cam.unproject(centre_uv, depth)  # world point at that depth
    current_centre = kp.mean(1)
    return params.transl + target_centre - current_centre


def _residuals_and_jacobian(fs, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Residuals (B, R) and their Jacobian (B, R, P): ``fs`` stacked, one forward pass each.

    The samples are independent, so the Jacobian of ``sum_b f(x)_b`` w.r.t. ``x`` (R, B, P)
    holds sample b's block at ``[:, b]``. Its rows are vector-Jacobian products with the
    standard basis, run as one batched backward pass per part of the residuals: what
    ``torch.autograd.functional.jacobian(..., vectorize=True)`` does on the stacked residuals
    (the batched backward costs per row, and a prior's rows no longer travel through the hand
    model's graph as zeros), minus the shape check of ``torch.autograd.grad`` that imports
    torch's symbolic-shape module and sympy (0.25 s CPU in a fresh process). The same values to
    the last bit (tested); the residuals come from the same forward passes.
    """
    outs, jacs = [], []
    for f in fs:
        out, J = _jacobian_part(f, x)
        outs.append(out)
        jacs.append(J)
    return torch.cat(outs, dim=1), torch.cat(jacs, dim=1)


def _jacobian_part(f, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    z = x.detach().requires_grad_(True)
    with torch.enable_grad():
        out = f(z)
    flat = out.sum(0)
    basis = flat.new_zeros(flat.numel(), flat.numel())
    basis.diagonal(0).fill_(1)
    from torch import _vmap_internals

    run = getattr(torch.autograd.graph, "_engine_run_backward", None)
    vmap = getattr(_vmap_internals, "_vmap", None)
    if run is None or vmap is None:  # another torch: the public path
        (J,) = torch.autograd.grad(flat, z, basis, is_grads_batched=True, allow_unused=True)
    else:

        def vjp(g):
            return run((flat,), (g,), False, False, (z,), True, accumulate_grad=False)

        (J,) = vmap(vjp, 0, 0, allow_none_pass_through=True)(basis)
    if J is None:  # x does not reach these residuals
        J = torch.zeros((flat.numel(), *x.shape), dtype=x.dtype)
    return out.detach(), J.detach().permute(1, 0, 2)


def _levenberg_marquardt(residuals, irls_weights, x, schedule, lam=1e-3):
    """Batched Levenberg-Marquardt with per-sample damping and IRLS robust weights.

    Args:
        residuals: parts ``f(x (B, P), weights) -> (B, R_i)`` of the residuals, stacked in
            order; samples are independent.
        irls_weights: ``g(x, anneal) -> weights`` recomputed every iteration.
        x: (B, P) initial parameters.
        schedule: robust-kernel widening factor per iteration (its length = iterations).
    Returns:
        the final (B, P) parameters and the final summed cost.
    """
    B, P = x.shape
    lam = torch.full((B,), lam, dtype=x.dtype)
    eye = torch.eye(P, dtype=x.dtype)
    cost = None
    for anneal in schedule:
        wts = irls_weights(x, anneal)
        fs = [functools.partial(part, kp_weights=wts) for part in residuals]
        r, J = _residuals_and_jacobian(fs, x)
        cost = (r**2).sum(1)
        JtJ = J.transpose(1, 2) @ J
        g = (J.transpose(1, 2) @ r[..., None])[..., 0]
        diag = torch.diagonal(JtJ, dim1=1, dim2=2)
        A = JtJ + lam[:, None, None] * torch.diag_embed(diag + 1e-9) + 1e-12 * eye
        delta = torch.linalg.solve(A, -g)
        with torch.no_grad():
            new_cost = (torch.cat([f(x + delta) for f in fs], dim=1) ** 2).sum(1)
        better = new_cost < cost
        x = torch.where(better[:, None], x + delta, x).detach()
        lam = torch.where(better, lam * 0.3, lam * 10).clamp(1e-9, 1e9)
        cost = torch.where(better, new_cost, cost)
    return x, float(cost.sum())
