"""Hand pose metrics: MPJPE and MPVPE in centimetres (docs/method.md section 3).

Inputs are in METRES; errors are mean Euclidean distances per point, in cm. Alignments:

- ``"none"``: compare as given.
- ``"root"``: subtract the root (joint 0, the wrist, for MPJPE) from each hand.
- ``"rotation"`` (EasyHOI's convention, "global rotation removed"): subtract the roots, then
  rotate the prediction about its root by the rotation R that minimises
  ``sum_i |R p_i - g_i|^2`` (Kabsch, proper rotation, no scale, no further translation).
  This undoes any error of the global orientation as well as of the position, leaving only the
  articulation (and shape) error.
- ``"procrustes"``: per-sample similarity Procrustes (scale, rotation, translation; Umeyama),
  the "PA-" metrics of the hand pose literature.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.metrics._common import M_TO_CM, to_numpy

HandAlign = Literal["none", "root", "rotation", "procrustes"]
Reduction = Literal["mean", "none"]

_ALIGNS = ("none", "root", "rotation", "procrustes")


def _batched_points(x, name: str) -> np.ndarray:
    a = to_numpy(x, name)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[-1] != 3 or a.shape[1] == 0:
        raise InvalidInputError(f"{name} must have shape (B, N, 3) or (N, 3), got {a.shape}")
    if not np.isfinite(a).all():
        raise InvalidInputError(f"{name} contains NaN or infinite values")
    return a


def _batched_root(x, batch: int, name: str) -> np.ndarray:
    a = to_numpy(x, name)
    if a.shape not in ((3,), (1, 3), (batch, 3)):
        raise InvalidInputError(f"{name} must have shape ({batch}, 3) or (3,), got {a.shape}")
    a = a.reshape(-1, 3)
    if not np.isfinite(a).all():
        raise InvalidInputError(f"{name} contains NaN or infinite values")
    return np.broadcast_to(a, (batch, 3))[:, None, :]


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(B, N, 3) centred points -> (B, 3, 3) proper rotations R minimising |R src - dst|^2."""
    H = np.einsum("bni,bnj->bij", src, dst)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("bji,bkj->bik", Vt, U)))
    d[d == 0] = 1.0
    D = np.zeros_like(H)
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    return np.einsum("bji,bjk,blk->bil", Vt, D, U)  # V D U^T


def align_hands(
    pred, gt, align: HandAlign = "none", pred_root=None, gt_root=None
) -> tuple[np.ndarray, np.ndarray]:
    """Apply one of the alignments to a batch of predicted / ground-truth point sets.

    Args:
        pred, gt ((B, N, 3) or (N, 3) array or tensor): Joints or vertices, metres.
        align ({"none", "root", "rotation", "procrustes"}): See the module docstring.
        pred_root, gt_root ((B, 3) or (3,), optional): Root positions for "root" / "rotation";
            default: point 0 of each set (the wrist for MANO joints and keypoints).

    Returns:
        (pred_aligned, gt_aligned) : (B, N, 3) float64 each, metres.
    """
    p = _batched_points(pred, "pred")
    g = _batched_points(gt, "gt")
    if p.shape != g.shape:
        raise InvalidInputError(
            f"pred and gt must have the same shape, got {p.shape} and {g.shape}"
        )
    if align not in _ALIGNS:
        raise InvalidInputError(f"align must be one of {_ALIGNS}, got {align!r}")
    B = p.shape[0]
    if align == "none":
        return p, g
    if align in ("root", "rotation"):
        pr = p[:, :1] if pred_root is None else _batched_root(pred_root, B, "pred_root")
        gr = g[:, :1] if gt_root is None else _batched_root(gt_root, B, "gt_root")
        p, g = p - pr, g - gr
        if align == "rotation":
            R = _kabsch(p, g)
            p = np.einsum("bij,bnj->bni", R, p)
        return p, g
    # similarity Procrustes (Umeyama 1991), per sample
    mp, mg = p.mean(1, keepdims=True), g.mean(1, keepdims=True)
    pc, gc = p - mp, g - mg
    R = _kabsch(pc, gc)
    rotated = np.einsum("bij,bnj->bni", R, pc)
    var = (pc**2).sum(axis=(1, 2))
    scale = np.where(var > 0, (rotated * gc).sum(axis=(1, 2)) / np.where(var > 0, var, 1), 1.0)
    return scale[:, None, None] * rotated + mg, g


def _error(pred, gt, align, pred_root, gt_root, reduction) -> float | np.ndarray:
    if reduction not in ("mean", "none"):
        raise InvalidInputError(f"reduction must be 'mean' or 'none', got {reduction!r}")
    p, g = align_hands(pred, gt, align, pred_root, gt_root)
    per_sample = np.linalg.norm(p - g, axis=-1).mean(axis=1) * M_TO_CM
    return float(per_sample.mean()) if reduction == "mean" else per_sample


def mpjpe(
    pred, gt, align: HandAlign = "none", reduction: Reduction = "mean", root_index: int = 0
) -> float | np.ndarray:
    """Mean per-joint position error, cm.

    Args:
        pred, gt ((B, J, 3) or (J, 3) array or tensor): Joints (usually the 21 keypoints), metres,
            in the same order.
        align ({"none", "root", "rotation", "procrustes"}): Alignment before measuring (module
            docstring); "rotation" is EasyHOI's convention.
        reduction ({"mean", "none"}): "mean": a float averaged over the batch; "none": (B,)
            per-sample errors.
        root_index (int): Joint used as the root by "root" and "rotation" (0 = wrist in MANO and
            OpenPose order).

    Returns:
        float or (B,) float: Error in cm.
    """
    p = _batched_points(pred, "pred")
    g = _batched_points(gt, "gt")
    if not 0 <= int(root_index) < p.shape[1]:
        raise InvalidInputError(f"root_index must be in [0, {p.shape[1]}), got {root_index}")
    if p.shape != g.shape:
        raise InvalidInputError(
            f"pred and gt must have the same shape, got {p.shape} and {g.shape}"
        )
    return _error(p, g, align, p[:, root_index], g[:, root_index], reduction)


def mpvpe(
    pred, gt, align: HandAlign = "none", reduction: Reduction = "mean", pred_root=None, gt_root=None
) -> float | np.ndarray:
    """Mean per-vertex position error, cm.

    Args:
        pred, gt ((B, V, 3) or (V, 3) array or tensor): Hand vertices (778 for MANO), metres, in
            corresponding order.
        align ({"none", "root", "rotation", "procrustes"}): Alignment before measuring (module
            docstring).
        reduction ({"mean", "none"}): "mean": a float; "none": (B,) per-sample errors.
        pred_root, gt_root ((B, 3) or (3,), optional): Root joints (wrists) for "root" / "rotation";
            default: the vertex centroid of each hand. Pass the wrist joints to match the MPJPE
            root.

    Returns:
        float or (B,) float: Error in cm.
    """
    p = _batched_points(pred, "pred")
    g = _batched_points(gt, "gt")
    pred_root = p.mean(1) if pred_root is None else pred_root
    gt_root = g.mean(1) if gt_root is None else gt_root
    return _error(p, g, align, pred_root, gt_root, reduction)
