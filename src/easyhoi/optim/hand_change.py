"""How far the optimizer moved the hand from the estimator's: the ``hand_change`` report.

Per keypoint (21, OpenPose / MANO order):

- ``cm``: 3D distance between the estimator's keypoint and the result's, both in their camera's
  frame in metres with the wrists aligned (the change of articulation and of the hand's
  orientation seen from the camera; the placement in depth, which the photo does not fix, is
  left out);
- ``px``: distance in the photo between the two reprojections (estimator's hand through its
  camera, the result through the fitted object camera).

With the detector's keypoints (``HOIInput.meta["keypoints2d"]``) ``detector_px`` gives the
mean 2D distance of the estimator's and the result's keypoints to them. Large values mean that
the optimizer overrode the photo (contact or penetration pulled the hand away from what the
photo shows).
"""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.hoi import HOIInput
from easyhoi.structures import Camera, HandParams

__all__ = ["hand_change"]


def _round(values: np.ndarray, digits: int = 3) -> list[float]:
    return [round(float(v), digits) for v in values]


def reprojected_keypoints(model, params: HandParams, camera: Camera, metric_scale: float):
    """(21, 2) float64 numpy pixels of ``params``' keypoints through ``camera``.

    ``params`` in the metric object frame and ``camera`` acting on object units, as a result
    holds them (``metric_scale`` metres per object unit; 1 for a hand in a metric frame).
    """
    dt = torch.float64
    with torch.no_grad():
        dev = model.faces.device
        k = model(params.detach().to(dtype=dt, device=dev)).keypoints[0].cpu() / metric_scale
        uv, _ = camera.detach().to(dt, "cpu").project(k)
    return uv.numpy()


def hand_change(
    model, inp: HOIInput, params: HandParams, camera: Camera, metric_scale: float
) -> dict:
    """JSON-ready ``hand_change`` block (module docstring) of a result's hand.

    Args:
        model: HandModel the parameters belong to.
        inp: HOIInput, for the estimator's hand and camera and the detector's keypoints.
        params: HandParams, the result's hand in the metric object frame.
        camera: Camera, the result's object camera (object units to pixels, full photo).
        metric_scale: float, metres per object unit.
    """
    dt = torch.float64
    with torch.no_grad():
        dev = model.faces.device  # the model's device: the parameters go there
        k_est = model(inp.hand_params.to(dtype=dt, device=dev)).keypoints[0].cpu()
        k_res = model(params.detach().to(dtype=dt, device=dev)).keypoints[0].cpu() / metric_scale
        cam_h, cam_o = inp.hand_camera.detach().to(dt, "cpu"), camera.detach().to(dt, "cpu")
        uv_est, _ = cam_h.project(k_est)
        uv_res, _ = cam_o.project(k_res)
        c_est = cam_h.world_to_camera(k_est)
        c_res = cam_o.world_to_camera(k_res) * metric_scale  # metres
    c_est, c_res = c_est.numpy(), c_res.numpy()
    cm = np.linalg.norm((c_res - c_res[0]) - (c_est - c_est[0]), axis=1) * 100.0
    px = np.linalg.norm(uv_res.numpy() - uv_est.numpy(), axis=1)
    out = {
        "cm": _round(cm),
        "px": _round(px, 2),
        "mean_cm": round(float(cm.mean()), 3),
        "max_cm": round(float(cm.max()), 3),
        "mean_px": round(float(px.mean()), 2),
        "max_px": round(float(px.max()), 2),
    }
    det = inp.meta.get("keypoints2d") if isinstance(inp.meta, dict) else None
    if det is not None:
        q = np.asarray(det, dtype=np.float64)
        if q.shape == (21, 2):
            out["detector_px"] = {
                "estimator": round(float(np.linalg.norm(uv_est.numpy() - q, axis=1).mean()), 2),
                "result": round(float(np.linalg.norm(uv_res.numpy() - q, axis=1).mean()), 2),
            }
    return out
