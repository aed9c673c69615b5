"""Loss terms of the three-stage optimizer (docs/method.md section 2.2), one pure function per term.

No weight, threshold or schedule lives here: every factor that scales a term or switches it on
is a field of :mod:`easyhoi.config`. Each function takes tensors, returns a scalar tensor
(``reduction="mean"``, the batch mean) or one value per batch element (``reduction="none"``),
and is differentiable with respect to its first argument.

Terms
-----
- :func:`soft_iou_loss`: ``1 - sum(A*B) / (sum(A) + sum(B) - sum(A*B))`` between soft masks.
- :func:`sinkhorn_mask_loss`: Sinkhorn divergence (Cuturi 2013) between two masks seen as
  normalised 2D distributions, on a coarse grid; gives gradients when masks do not overlap.
- :func:`mask_mse`: mean squared difference between masks.
- :func:`penetration_loss`: ``(1/V) sum_v max(0, -d(v))`` over hand vertices, ``d`` = object SDF.
- :func:`contact_loss`: ``sum_v max(0, d(v))`` over the contact-zone vertices, optionally
  rescaled to a reference vertex count (``reference_count / C``, see below).
- :func:`pose_reg_loss`: ``||theta - theta_0||_1``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from easyhoi.errors import InvalidInputError

__all__ = [
    "IOU_EPS",
    "MANO_CONTACT_VERTICES",
    "MASS_EPS",
    "contact_loss",
    "mask_mse",
    "penetration_loss",
    "pose_reg_loss",
    "sinkhorn_mask_loss",
    "soft_iou_loss",
]

#: Added to the union in :func:`soft_iou_loss` so that two empty masks give a finite loss (1).
IOU_EPS = 1e-6

#: Mass (per coarse cell, in mask units) added to the predicted mask in
#: :func:`sinkhorn_mask_loss`, so that an empty prediction is a uniform distribution.
MASS_EPS = 1e-6

#: Contact-zone vertices of MANO (778 vertices; docs/method.md: "about 115"). The paper's weights
#: were tuned for a sum over this many vertices; :func:`contact_loss` rescales a sum over C
#: vertices by ``MANO_CONTACT_VERTICES / C`` so that those weights mean the same for any hand
#: mesh resolution (the built-in OpenHand has 1902 vertices and 285 contact vertices).
MANO_CONTACT_VERTICES = 115

_REDUCTIONS = ("mean", "sum", "none")


def _reduce(per_item: torch.Tensor, reduction: str) -> torch.Tensor:
    if reduction == "mean":
        return per_item.mean()
    if reduction == "sum":
        return per_item.sum()
    if reduction == "none":
        return per_item
    raise InvalidInputError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")


def _as_batched_masks(pred: torch.Tensor, target: torch.Tensor, name: str):
    """Bring two masks to (B, H, W) with a common floating dtype; check shapes agree."""
    if not isinstance(pred, torch.Tensor) or not isinstance(target, torch.Tensor):
        raise InvalidInputError(f"{name}: pred and target must be torch tensors")
    if pred.ndim not in (2, 3):
        raise InvalidInputError(
            f"{name}: masks must be (H, W) or (B, H, W), got {tuple(pred.shape)}"
        )
    if target.shape != pred.shape:
        raise InvalidInputError(
            f"{name}: target has shape {tuple(target.shape)} but pred has {tuple(pred.shape)}"
        )
    dtype = pred.dtype if pred.is_floating_point() else torch.get_default_dtype()
    pred = pred.to(dtype)
    target = target.to(dtype)
    if pred.ndim == 2:
        pred, target = pred[None], target[None]
    return pred, target


# ----------------------------------------------------------------------------------------------
# mask terms
# ----------------------------------------------------------------------------------------------


def soft_iou_loss(
    pred: torch.Tensor, target: torch.Tensor, eps: float = IOU_EPS, reduction: str = "mean"
) -> torch.Tensor:
    """Soft intersection-over-union loss between soft masks.

    ``L = 1 - I / (U + eps)`` with ``I = sum(A * B)`` and ``U = sum(A) + sum(B) - I``, the sums
    running over the pixels of each mask.

    Args:
        pred ((H, W) or (B, H, W) float tensor): Predicted (rendered) soft mask, values in [0, 1].
        target (same shape as ``pred``): Target mask (bool or float in [0, 1]).
        eps (float): Added to the union; two empty masks give ``L = 1`` (an empty render is a
            failure).
        reduction ({"mean", "sum", "none"}): How the per-mask losses (B,) are combined.

    Returns:
        () tensor, or (B,) with ``reduction="none"``; values in [0, 1].
    """
    A, B = _as_batched_masks(pred, target, "soft_iou_loss")
    inter = (A * B).sum(dim=(1, 2))
    union = A.sum(dim=(1, 2)) + B.sum(dim=(1, 2)) - inter
    return _reduce(1.0 - inter / (union + eps), reduction)


def mask_mse(pred: torch.Tensor, target: torch.Tensor, reduction: str = "mean") -> torch.Tensor:
    """Mean squared difference between two masks.

    Args:
        pred, target: (H, W) or (B, H, W) tensors, values in [0, 1]
        reduction: {"mean", "sum", "none"}

    Returns:
        () tensor, or (B,) with ``reduction="none"`` (mean over the pixels of each mask).
    """
    A, B = _as_batched_masks(pred, target, "mask_mse")
    return _reduce(((A - B) ** 2).mean(dim=(1, 2)), reduction)


def _coarse_cells(h: int, w: int, gh: int, gw: int, dtype, device=None) -> torch.Tensor:
    """(gh*gw, 2) cell centres (x, y) of an adaptive-pooled (gh, gw) grid over an (h, w) image.

    Coordinates are pixel positions divided by ``max(h, w)``: the longer side spans [0, 1] and
    distances keep the image's aspect ratio.
    """
    s = float(max(h, w))
    ys = (torch.arange(gh, dtype=dtype, device=device) + 0.5) * (h / gh) / s
    xs = (torch.arange(gw, dtype=dtype, device=device) + 0.5) * (w / gw) / s
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1)], dim=-1)


def sinkhorn_mask_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    grid: int = 32,
    blur: float = 0.05,
    scaling: float = 0.8,
    reduction: str = "mean",
) -> torch.Tensor:
    """Sinkhorn divergence between two masks seen as 2D distributions (Cuturi 2013).

    Both masks are average-pooled to a coarse ``grid`` x ``grid`` array (fewer cells along a
    side shorter than ``grid`` pixels). Each cell becomes a point at its centre (coordinates:
    pixels / ``max(H, W)``, so the long side spans [0, 1]) weighted by its pooled mass divided by
    the mask's total mass. Target cells of zero weight are dropped; every predicted cell is kept
    (with mass ``+ MASS_EPS``), so the gradient reaches cells that are empty now and mass is
    pulled toward the target even when the masks do not overlap. The value is the debiased
    Sinkhorn divergence of geomloss, ``SamplesLoss("sinkhorn", p=2, blur, scaling)``, whose cost
    is ``|x - y|^2 / 2``: for two single-cell masks it equals half the squared distance of
    their centres.

    Args:
        pred ((H, W) or (B, H, W) float tensor): Predicted soft mask in [0, 1]. An all-zero
            prediction is a uniform distribution (because of ``MASS_EPS``), not an error.
        target (same shape as ``pred``): Target mask; must be non-empty (else
            :class:`InvalidInputError`).
        grid (int): Cells along each side of the coarse grid (>= 1).
        blur (float): Entropic blur of geomloss (length scale, in the normalised coordinates).
        scaling (float): epsilon-scaling ratio of geomloss, in (0, 1); closer to 1 is more accurate
            and slower.
        reduction: {"mean", "sum", "none"}

    Returns:
        () tensor, or (B,) with ``reduction="none"``; non-negative.
    """
    from geomloss import SamplesLoss

    A, B = _as_batched_masks(pred, target, "sinkhorn_mask_loss")
    if int(grid) < 1:
        raise InvalidInputError(f"sinkhorn_mask_loss: grid must be >= 1, got {grid}")
    if not blur > 0:
        raise InvalidInputError(f"sinkhorn_mask_loss: blur must be > 0, got {blur}")
    if not 0 < scaling < 1:
        raise InvalidInputError(f"sinkhorn_mask_loss: scaling must be in (0, 1), got {scaling}")
    h, w = A.shape[-2:]
    gh, gw = min(int(grid), h), min(int(grid), w)
    pa = F.adaptive_avg_pool2d(A[:, None], (gh, gw)).reshape(A.shape[0], -1) + MASS_EPS
    pb = F.adaptive_avg_pool2d(B[:, None], (gh, gw)).reshape(B.shape[0], -1)
    cells = _coarse_cells(h, w, gh, gw, A.dtype, A.device)
    ot = SamplesLoss("sinkhorn", p=2, blur=float(blur), scaling=float(scaling))
    losses = []
    for i in range(A.shape[0]):
        tb = pb[i]
        keep = tb > 0
        if not bool(keep.any()):
            raise InvalidInputError("sinkhorn_mask_loss: the target mask is empty")
        a = pa[i] / pa[i].sum()
        b = tb[keep] / tb[keep].sum()
        losses.append(ot(a, cells, b, cells[keep]))
    return _reduce(torch.stack(losses), reduction)


# ----------------------------------------------------------------------------------------------
# 3D terms
# ----------------------------------------------------------------------------------------------


def _check_sdf(values: torch.Tensor, name: str) -> torch.Tensor:
    if not isinstance(values, torch.Tensor):
        raise InvalidInputError(f"{name}: SDF values must be a torch tensor")
    if values.ndim == 1:
        values = values[None]
    if values.ndim != 2:
        raise InvalidInputError(f"{name}: SDF values must be (B, V), got {tuple(values.shape)}")
    return values


def penetration_loss(
    sdf_values: torch.Tensor, threshold: float = 0.0, reduction: str = "mean"
) -> torch.Tensor:
    """Penetration of hand vertices into the object: ``(1/V) sum_v max(0, -d(v))``.

    A vertex counts only when its signed distance is below ``threshold`` (the reference
    implementation uses -5e-3 in normalised object units, tolerating shallow contact); a
    counted vertex contributes its full depth ``-d(v)``. With ``threshold = 0`` this is exactly
    the term of docs/method.md. The gradient is ``-1/V`` for each counted vertex and 0 elsewhere.

    Args:
        sdf_values ((B, V) or (V,) float tensor): Object signed distance at every hand vertex
            (inside < 0).
        threshold (float or (V,) tensor): Vertices with ``d < threshold`` count (should be
            <= 0); a tensor gives each vertex its own.
        reduction ({"mean", "sum", "none"}): Combines the per-hand values (B,).

    Returns:
        () tensor, or (B,) with ``reduction="none"``; non-negative.
    """
    d = _check_sdf(sdf_values, "penetration_loss")
    if d.shape[1] == 0:
        raise InvalidInputError("penetration_loss: no vertices given")
    depth = torch.where(d < threshold, -d, torch.zeros_like(d)).clamp_min(0.0)
    return _reduce(depth.mean(dim=1), reduction)


def contact_loss(
    sdf_values: torch.Tensor,
    max_distance: float | None = None,
    reduction: str = "mean",
    reference_count: float | None = None,
) -> torch.Tensor:
    """Attraction of the contact-zone vertices to the object surface: ``sum_v max(0, d(v))``.

    With ``reference_count = K`` the sum is multiplied by ``K / C`` (C = number of contact-zone
    vertices given): a resolution-independent sum, ``K`` times the mean gap. With ``K = 115``
    (:data:`MANO_CONTACT_VERTICES`) it equals the paper's plain sum for MANO (whose contact zones
    have ~115 vertices) and keeps the paper's weight meaningful for a denser hand mesh, just as
    the penetration term is a mean over the vertices. A vertex farther than ``max_distance``
    contributes 0 but still counts in C.

    Args:
        sdf_values ((B, C) or (C,) float tensor): Object signed distance at the C contact-zone
            vertices of each hand.
        max_distance (float, (C,) tensor or None): None (the paper): every contact vertex outside
            the object is attracted. A positive number: only vertices with ``0 < d < max_distance``
            are attracted (vertices far away, for example on fingers that do not touch, are left
            alone). A (C,) tensor of positive numbers: one radius per contact vertex.
        reduction ({"mean", "sum", "none"}): Combines the per-hand sums (B,).
        reference_count (float or None): None: the plain sum over the C vertices. A positive number
            K: the sum times ``K / C``.

    Returns:
        () tensor, or (B,) with ``reduction="none"``; non-negative.
    """
    d = _check_sdf(sdf_values, "contact_loss")
    gap = d.clamp_min(0.0)
    if max_distance is not None:
        if isinstance(max_distance, torch.Tensor):
            if max_distance.shape != d.shape[1:]:
                raise InvalidInputError(
                    f"contact_loss: max_distance must be a number or ({d.shape[1]},), got "
                    f"{tuple(max_distance.shape)}"
                )
            ok = bool((max_distance > 0).all())
            max_distance = max_distance.to(d)
        else:
            ok = max_distance > 0
        if not ok:
            raise InvalidInputError(f"contact_loss: max_distance must be > 0, got {max_distance}")
        gap = torch.where(d < max_distance, gap, torch.zeros_like(gap))
    per_hand = gap.sum(dim=1)
    if reference_count is not None:
        if not reference_count > 0:
            raise InvalidInputError(
                f"contact_loss: reference_count must be > 0 or None, got {reference_count}"
            )
        if d.shape[1] == 0:
            raise InvalidInputError("contact_loss: reference_count given but no contact vertices")
        per_hand = per_hand * (float(reference_count) / d.shape[1])
    return _reduce(per_hand, reduction)


def pose_reg_loss(
    theta: torch.Tensor, theta0: torch.Tensor, reduction: str = "mean"
) -> torch.Tensor:
    """L1 distance of the articulation from the estimator's: ``||theta - theta_0||_1``.

    Args:
        theta ((B, P) or (P,) float tensor): Current articulation (P = 45 for MANO axis-angle).
        theta0 (same shape as ``theta`` (or broadcastable)): Reference articulation; treated as a
            constant.
        reduction ({"mean", "sum", "none"}): Combines the per-hand norms (B,).

    Returns:
        () tensor, or (B,) with ``reduction="none"``.
    """
    if not isinstance(theta, torch.Tensor):
        raise InvalidInputError("pose_reg_loss: theta must be a torch tensor")
    theta0 = torch.as_tensor(theta0, dtype=theta.dtype, device=theta.device)
    if theta.ndim == 1:
        theta = theta[None]
    if theta0.ndim == 1:
        theta0 = theta0[None]
    if theta.ndim != 2 or theta0.ndim != 2 or theta0.shape[1] != theta.shape[1]:
        raise InvalidInputError(
            f"pose_reg_loss: theta {tuple(theta.shape)} and theta0 {tuple(theta0.shape)} "
            "must be (B, P) with the same P"
        )
    if theta0.shape[0] not in (1, theta.shape[0]):
        raise InvalidInputError(
            f"pose_reg_loss: theta0 batch {theta0.shape[0]} does not match theta {theta.shape[0]}"
        )
    return _reduce((theta - theta0.detach()).abs().sum(dim=1), reduction)
