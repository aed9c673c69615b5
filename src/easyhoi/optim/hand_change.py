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


def _keypoints_seen(model, params: HandParams, camera: Camera, metric_scale: float):
    """``params``' 21 keypoints through ``camera``: (21, 2) float64 pixels and (21, 3) float64
    camera-frame points in metres (as :func:`reprojected_keypoints` takes its arguments)."""
    dt = torch.float64
    with torch.no_grad():
        dev = model.faces.device  # the model's device: the parameters go there
        k = model(params.detach().to(dtype=dt, device=dev)).keypoints[0].cpu() / metric_scale
        cam = camera.detach().to(dt, "cpu")
        uv, _ = cam.project(k)
        return uv.numpy(), (cam.world_to_camera(k) * metric_scale).numpy()


def reprojected_keypoints(model, params: HandParams, camera: Camera, metric_scale: float):
    """(21, 2) float64 numpy pixels of ``params``' keypoints through ``camera``.

    ``params`` in the metric object frame and ``camera`` acting on object units, as a result
    holds them (``metric_scale`` metres per object unit; 1 for a hand in a metric frame).
    """
    return _keypoints_seen(model, params, camera, metric_scale)[0]


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
    uv_est, c_est = _keypoints_seen(model, inp.hand_params, inp.hand_camera, 1.0)
    uv_res, c_res = _keypoints_seen(model, params, camera, metric_scale)
    cm = np.linalg.norm((c_res - c_res[0]) - (c_est - c_est[0]), axis=1) * 100.0
    px = np.linalg.norm(uv_res - uv_est, axis=1)
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
                "estimator": round(float(np.linalg.norm(uv_est - q, axis=1).mean()), 2),
                "result": round(float(np.linalg.norm(uv_res - q, axis=1).mean()), 2),
            }
    return out
