"""Placing a hand: rigid motions of hand parameters and the changes of frame between the
estimator's camera, the object camera and the metric object frame (see :mod:`easyhoi.optim.state`
for the frames)."""

from __future__ import annotations

import torch

from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle
from easyhoi.hand.base import HandModel, mirror_params
from easyhoi.structures import Camera, HandParams

__all__ = ["camera_hand_to_object", "hand_in_camera", "move_hand", "rest_wrist"]


def rest_wrist(model: HandModel, betas: torch.Tensor) -> torch.Tensor:
    """(3,) wrist joint of the flat rest pose for ``betas`` (the centre of global_orient)."""
    with torch.no_grad():
        _, joints = model.shaped(betas.reshape(1, -1))
    return joints[0, 0]


def move_hand(p: HandParams, R: torch.Tensor, t: torch.Tensor, wrist: torch.Tensor) -> HandParams:
    """Parameters of the hand ``R x + t`` (rigid motion applied to every vertex).

    ``wrist`` (3,) is the rest wrist joint (:func:`rest_wrist`); ``R`` (3, 3), ``t`` (3,).

    Right hands: the model is ``Rot(go) (x - J) + J + transl``; left hands are mirrored, so the
    motion is conjugated by the mirror before it is applied to the mirrored parameters.
    """
    if p.side == "left":
        M = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=R.dtype, device=R.device))
        R_, t_ = M @ R @ M, M @ t
    else:
        R_, t_ = R, t
    go = matrix_to_axis_angle(R_ @ axis_angle_to_matrix(_right(p).global_orient[0]))
    tr = R_ @ (wrist + _right(p).transl[0]) + t_ - wrist
    out = HandParams(go[None], tr[None], _right(p).pose, _right(p).betas, "right")
    if p.side == "left":
        return mirror_params(out)
    return out


def _right(p: HandParams) -> HandParams:
    return mirror_params(p) if p.side == "left" else p


def hand_in_camera(params: HandParams, camera: Camera, model: HandModel) -> HandParams:
    """Hand parameters given in ``camera``'s world frame -> the camera's own frame (metres)."""
    wrist = rest_wrist(model, params.betas.to(params.pose.dtype))
    p = params.to(dtype=camera.K.dtype)
    return move_hand(p, camera.R.detach(), camera.t.detach(), wrist.to(camera.K.dtype))


def camera_hand_to_object(
    params_cam: HandParams, camera: Camera, metric_scale: float, model: HandModel
) -> HandParams:
    """Hand in the object camera's frame (metres) -> hand in the metric object frame.

    Object-unit vertices are ``R^T (V_cam / m - t)``; in the metric object frame (times ``m``)
    that is the rigid motion ``x -> R^T x - m R^T t`` of the camera-frame hand.
    """
    wrist = rest_wrist(model, params_cam.betas).to(params_cam.pose.dtype)
    R = camera.R.detach().to(params_cam.pose.dtype)
    t = camera.t.detach().to(params_cam.pose.dtype)
    return move_hand(params_cam, R.T, -metric_scale * (R.T @ t), wrist)
