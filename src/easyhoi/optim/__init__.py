"""Prior-guided optimization (docs/method.md section 2.2): loss terms and the three stages."""

from easyhoi.optim.losses import (
    contact_loss,
    mask_mse,
    penetration_loss,
    pose_reg_loss,
    sinkhorn_mask_loss,
    soft_iou_loss,
)

__all__ = [
    "contact_loss",
    "mask_mse",
    "penetration_loss",
    "pose_reg_loss",
    "sinkhorn_mask_loss",
    "soft_iou_loss",
]
