"""Stage-3 terms that keep the hand a hand seen in the photo: 2D keypoints and a pose prior.

- :func:`keypoint_loss`: the reprojected 21 keypoints against the detector's, with the
  Geman-McClure penalty ``rho(r) = r^2 / (r^2 + sigma^2)`` of the residual ``r`` measured in
  units of the hand's size in the photo. It is quadratic near 0 (``(r / sigma)^2``) and
  saturates at 1, so one wrong detection (a finger hidden behind the object and guessed by the
  detector) pulls with a bounded force while the consistent joints hold the hand in place.
  Per-joint detector confidences weight the joints.
- :func:`keypoint_drift_loss`: the confidence-weighted MEAN residual of the keypoints, squared
  (no saturation). The robust term forgives single joints; the hand as a whole cannot be an
  outlier, and a hand pushed across the photo by other terms (penetration) must keep paying for
  it: once every joint is farther than the Geman-McClure scale, the robust term is flat.
- :func:`pose_prior_loss`: how fingers bend. Each joint's axis-angle rotation is split into its
  flexion (the component along the joint's flexion axis, :func:`easyhoi.hand.regions.flexion_axes`)
  and the rest (abduction and twist). Three squared hinge penalties, zero inside the range every
  hand reaches:

  * joint limits on the flexion angle (:data:`FLEXION_LIMITS`);
  * hinge joints (the fingers' middle and distal joints, the thumb's distal joint) rotate about
    one axis: their non-flexion part beyond :data:`HINGE_TOLERANCE`; the finger bases and the
    thumb's two proximal joints also abduct, beyond :data:`ABDUCTION_TOLERANCE`;
  * coupling of the distal and middle joints of the four fingers: the distal joint flexes about
    two thirds of the middle one (the deep flexor tendon drives both and the oblique retinacular
    ligament links them; no one bends a fingertip without the middle joint or the reverse),
    penalised beyond :data:`COUPLING_TOLERANCE`.

Both functions are pure and differentiable; the weights live in :mod:`easyhoi.config`.
"""

from __future__ import annotations

import math

import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.regions import DIGIT_JOINTS

__all__ = [
    "ABDUCTION_TOLERANCE",
    "COUPLING_RATIO",
    "COUPLING_TOLERANCE",
    "FLEXION_LIMITS",
    "HINGE_TOLERANCE",
    "keypoint_drift_loss",
    "keypoint_loss",
    "photo_keypoint_terms",
    "pose_prior_loss",
    "prior_tables",
]

_FINGERS = ("index", "middle", "ring", "pinky")

#: Flexion range (radians) per joint role: finger base (MCP) -20..100 degrees, middle (PIP)
#: -6..110, distal (DIP) -12..85; thumb base (CMC, also opposes: wide) -45..90, thumb middle
#: (MCP) -20..70, thumb distal (IP) -20..85. Active ranges of motion of adult hands, with a
#: margin for the estimator's axis conventions.
FLEXION_LIMITS = {
    "finger": ((-0.35, 1.75), (-0.1, 1.92), (-0.2, 1.48)),
    "thumb": ((-0.8, 1.6), (-0.35, 1.22), (-0.35, 1.48)),
}
#: Non-flexion rotation (radians) a hinge joint may show (axis conventions, skin sliding).
HINGE_TOLERANCE = 0.3
#: Non-flexion rotation (radians) of the joints that also abduct (finger bases: about 20-25
#: degrees each way; the thumb's base and middle joint: more).
ABDUCTION_TOLERANCE = {"finger": 0.45, "thumb": 1.0}
#: Distal flexion ~ this times the middle flexion (fingers only).
COUPLING_RATIO = 2.0 / 3.0
#: Deviation (radians) from the coupling that costs nothing (a fingertip pressed on a surface
#: bends back a little; a hook grip curls it a little more).
COUPLING_TOLERANCE = 0.4


def prior_tables(dtype=torch.float64) -> dict:
    """Per-joint (15 joints, MANO order 1..15) tensors of :func:`pose_prior_loss`: ``lo``, ``hi``
    (flexion limits), ``tol`` (non-flexion tolerance), and the (middle, distal) joint index
    pairs of the coupled fingers (0-based rows of the (15, 3) articulation)."""
    # built on the CPU (filled element by element); callers move them to the run's device
    lo, hi, tol = (torch.zeros(15, dtype=dtype, device="cpu") for _ in range(3))
    for digit, joints in DIGIT_JOINTS.items():
        kind = "thumb" if digit == "thumb" else "finger"
        for role, j in enumerate(joints):
            lo[j - 1], hi[j - 1] = FLEXION_LIMITS[kind][role]
            hinge = role == 2 or (kind == "finger" and role == 1)
            tol[j - 1] = HINGE_TOLERANCE if hinge else ABDUCTION_TOLERANCE[kind]
    pairs = torch.tensor(
        [[DIGIT_JOINTS[d][1] - 1, DIGIT_JOINTS[d][2] - 1] for d in _FINGERS], device="cpu"
    )
    return {"lo": lo, "hi": hi, "tol": tol, "pairs": pairs}


def _violations(theta: torch.Tensor, axes: torch.Tensor, t: dict) -> torch.Tensor:
    """(B, 49) non-negative amounts (radians) by which each joint leaves its range: flexion
    below / above its limits (15 + 15), non-flexion rotation beyond its tolerance (15), distal
    flexion off the coupling beyond its tolerance (4)."""
    flex = (theta * axes).sum(-1)  # (B, 15)
    rest = theta - flex[..., None] * axes
    rest_norm = torch.sqrt((rest**2).sum(-1) + 1e-12)
    pairs = t["pairs"].to(theta.device)
    mid, dist = flex[:, pairs[:, 0]], flex[:, pairs[:, 1]]
    return torch.cat(
        [
            t["lo"].to(theta) - flex,
            flex - t["hi"].to(theta),
            rest_norm - t["tol"].to(theta),
            (dist - COUPLING_RATIO * mid).abs() - COUPLING_TOLERANCE,
        ],
        dim=1,
    ).clamp_min(0.0)


def pose_prior_loss(
    pose: torch.Tensor,
    flexion_axes: torch.Tensor,
    reference: torch.Tensor | None = None,
    tables: dict | None = None,
) -> torch.Tensor:
    """Anatomical prior of an articulation (module docstring); 0 for poses every hand takes.

    With a ``reference`` articulation (the estimator's) a joint is penalised only for leaving
    its range further than the reference does: the estimator read the pose from the photo, and
    the prior's task is to keep the optimizer from bending joints where no hand goes, not to
    overrule the photo.

    Args:
        pose: (B, 45) or (45,) axis-angle articulation (joints 1..15), right-hand convention.
        flexion_axes: (15, 3) unit flexion axes of the model's joints (rest frame).
        reference: (45,) or (1, 45) articulation or None.
        tables: dict from :func:`prior_tables` (default: built here).

    Returns:
        () tensor: the batch mean of the summed squared excesses (radians^2).
    """
    if not isinstance(pose, torch.Tensor):
        raise InvalidInputError("pose_prior_loss: pose must be a torch tensor")
    theta = pose.reshape(-1, 15, 3)
    axes = torch.as_tensor(flexion_axes, dtype=theta.dtype, device=theta.device)
    if axes.shape != (15, 3):
        raise InvalidInputError(f"pose_prior_loss: flexion_axes must be (15, 3), got {axes.shape}")
    t = prior_tables(theta.dtype) if tables is None else tables
    excess = _violations(theta, axes, t)
    if reference is not None:
        ref = reference.detach().to(theta.dtype).reshape(-1, 15, 3)
        excess = (excess - _violations(ref, axes, t)).clamp_min(0.0)
    return (excess**2).sum(1).mean()


def keypoint_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    scale: float,
    sigma: float,
    weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Robust 2D keypoint term: ``sum_j w_j rho(|p_j - q_j| / scale) / sum_j w_j``.

    Args:
        pred: (B, J, 2) or (J, 2) reprojected keypoints, pixels.
        target: (J, 2) detected keypoints, pixels (constant).
        scale: float, the hand's size in the photo in pixels (residuals are divided by it).
        sigma: float, the Geman-McClure scale in units of ``scale``: residuals well below it cost
            ``(r / sigma)^2``, residuals well above it cost about 1.
        weights: (J,) non-negative per-joint confidences or None (all 1).

    Returns:
        () tensor in [0, 1): the batch mean.
    """
    p, q, w = _keypoint_inputs("keypoint_loss", pred, target, scale, sigma, weights)
    r2 = ((p - q) ** 2).sum(-1) / scale**2
    rho = r2 / (r2 + sigma**2)
    return ((rho * w).sum(1) / w.sum()).mean()


def keypoint_drift_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    scale: float,
    sigma: float,
    weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Whole-hand drift from the detected keypoints: ``|sum_j w_j (p_j - q_j) / sum_j w_j|^2 /
    (scale sigma)^2`` (arguments as :func:`keypoint_loss`). Equals :func:`keypoint_loss`'s
    quadratic regime for a common shift of every joint, but does not saturate.

    Returns:
        () tensor >= 0: the batch mean.
    """
    p, q, w = _keypoint_inputs("keypoint_drift_loss", pred, target, scale, sigma, weights)
    mean = ((p - q) * w[:, None]).sum(1) / w.sum()  # (B, 2)
    return ((mean**2).sum(-1) / (scale * sigma) ** 2).mean()


def photo_keypoint_terms(
    uv: torch.Tensor, keypoints, sigma: float, drift: bool
) -> dict[str, torch.Tensor]:
    """The keypoint terms of a stage, unweighted: ``uv`` (21, 2) reprojected keypoints against
    the detector's ``keypoints`` (an :class:`easyhoi.optim.state.PhotoKeypoints`: points,
    per-joint confidence, hand size) at the Geman-McClure scale ``sigma``.

    Returns:
        dict: ``keypoints`` (:func:`keypoint_loss`) and, with ``drift``, ``keypoint_drift``
        (:func:`keypoint_drift_loss`).
    """
    args = (keypoints.points, keypoints.size, sigma, keypoints.confidence)
    out = {"keypoints": keypoint_loss(uv, *args)}
    if drift:
        out["keypoint_drift"] = keypoint_drift_loss(uv, *args)
    return out


def _keypoint_inputs(name: str, pred, target, scale: float, sigma: float, weights):
    """Checked ``(pred (B, J, 2), target (J, 2), weights (J,))`` of the keypoint terms."""
    if not (scale > 0 and sigma > 0 and math.isfinite(scale) and math.isfinite(sigma)):
        raise InvalidInputError(f"{name}: scale and sigma must be > 0 ({scale}, {sigma})")
    p = pred.reshape(-1, *pred.shape[-2:])
    q = torch.as_tensor(target, dtype=p.dtype, device=p.device).detach()
    if q.shape != p.shape[1:]:
        raise InvalidInputError(
            f"{name}: target {tuple(q.shape)} does not match pred {tuple(p.shape[1:])}"
        )
    w = torch.ones(q.shape[0], dtype=p.dtype, device=p.device)
    if weights is not None:
        w = weights.to(device=p.device, dtype=p.dtype)
    if not float(w.sum()) > 0:
        raise InvalidInputError(f"{name}: the joint weights sum to 0")
    return p, q, w
