"""A detected hand keeps the average adult size (perception.hand_fit.DETECTION_FIT): neither the
detector's metric 3D keypoints nor the 2D keypoints' perspective set it."""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.hand.openhand import OpenHand
from easyhoi.hand.regions import flexion_axes
from easyhoi.perception.base import HandDetection
from easyhoi.perception.hand_fit import DETECTION_FIT, fit_detection, photo_camera
from easyhoi.structures import HandParams


def _detection(size_units: float, model: OpenHand) -> tuple[HandDetection, torch.Tensor]:
    """Keypoints of a hand of size ``size_units`` (5 % each) 0.45 m in front of the photo
    camera: 2D in pixels and 3D centred, metric, as a detector gives them."""
    axes = torch.as_tensor(flexion_axes(model), dtype=torch.float64)
    betas = torch.zeros(1, 10, dtype=torch.float64)
    betas[0, 0] = size_units
    go = torch.tensor([[2.6, 0.3, 0.2]], dtype=torch.float64)  # palm towards the camera
    params = HandParams(go, torch.tensor([[0.02, -0.01, 0.45]], dtype=torch.float64),
                        (0.35 * axes[None]).reshape(1, 45), betas)  # fmt: skip
    kp = model(params).keypoints
    cam = photo_camera(640, 480).to(dtype=torch.float64)
    uv, _ = cam.project(kp)
    k3 = (kp - kp.mean(1, keepdim=True))[0].numpy()
    det = HandDetection(uv[0].numpy(), k3, "right", 0.99)
    return det, kp


def test_the_size_stays_the_mean_whatever_the_keypoints_say():
    model = OpenHand(dtype=torch.float64)
    for size in (-3.0, 2.0):  # 15 % smaller, 10 % larger than the mean hand
        det, _ = _detection(size, model)
        fitted = fit_detection(det, model, 640, 480)
        b0 = float(fitted.params.betas[0, 0])
        assert abs(b0) < 0.3, (size, b0)
        # the projection is kept: a larger hand farther away, or a smaller one nearer
        assert fitted.meta["fit_error_2d_px"] < 1.5
        assert float(fitted.params.betas[0, 1:].abs().max()) < 0.5


def test_without_the_detection_settings_the_size_follows_the_3d_keypoints():
    model = OpenHand(dtype=torch.float64)
    det, _ = _detection(-3.0, model)
    from easyhoi.hand.fit import FitConfig

    fitted = fit_detection(det, model, 640, 480, config=FitConfig())
    assert float(fitted.params.betas[0, 0]) < -2.0
    assert DETECTION_FIT.scale_free_3d and DETECTION_FIT.size_prior > 0
    assert np.isfinite(fitted.meta["fit_error_3d_mm"])
