"""Turn a detected hand (2D keypoints + root-relative metric 3D keypoints) into hand parameters.

Camera convention for photos without calibration: a pinhole camera with the principal point at
the image centre and a horizontal-or-vertical field of view of ``fov_deg`` (default 50 degrees)
on the image's longer side, ``f = max(W, H) / (2 tan(fov / 2))`` — a typical phone main camera.
HaMeR's convention (``f = 5000 / 256 * max(W, H)``, nearly orthographic) is available as
``focal="hamer"`` for compatibility with imported HaMeR results.

The fit (:func:`easyhoi.hand.fit.fit_keypoints`) uses the 3D keypoints up to a translation and
a scale for the articulation and proportions (:data:`DETECTION_FIT`) and the 2D keypoints for
placement (depth from apparent size). The hand's size stays near the hand model's mean (an
average adult hand), held there by a prior as wide as adult hands vary: one photo cannot tell a
small hand near the camera from a large one farther away. The 2D keypoints' perspective does not
measure it, as the field of view is assumed (docs/object_shape.md: posed against the 3D
keypoints, no field of view fits them better than another), and the detector's metric 3D
keypoints do not either. They are its network's estimate in its own landmark definitions:
against OpenHand's mean hand the detected hands of the development photos (54) have a palm 5 %
shorter, fingers 12 % shorter and a knuckle line 20 % narrower (medians), and fitted with their
size they came out 14 % smaller than the average adult hand (size coefficient median -2.8 units
of 5 %), among the smallest few per cent of women's hands, and so did every metric length
derived from them. On synthetic renders, whose hands' sizes are known, that fitted size does
not follow the true one at all (docs/benchmark.md).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.base import HandModel
from easyhoi.hand.fit import FitConfig, fit_keypoints
from easyhoi.perception.base import HandDetection
from easyhoi.structures import Camera

DEFAULT_FOV_DEG = 50.0

#: The fit of a detected hand: 3D keypoints compared up to scale, and the size held near the
#: mean by a prior of about 1.4 units (7 %, how much adult hands vary), since the 2D keypoints'
#: perspective under an assumed field of view does not measure it either (module docstring).
DETECTION_FIT = FitConfig(scale_free_3d=True, size_prior=0.5)


def photo_camera(width: int, height: int, focal: str | float = "fov", fov_deg: float = 50.0):
    """The uncalibrated photo camera (see the module docstring)."""
    if focal == "hamer":
        return Camera.hamer_convention(width, height)
    if focal == "fov":
        f = max(width, height) / (2 * math.tan(math.radians(fov_deg) / 2))
        return Camera.from_focal(f, width, height)
    if isinstance(focal, int | float) and focal > 0:
        return Camera.from_focal(float(focal), width, height)
    raise InvalidInputError(f"focal must be 'fov', 'hamer' or a positive number, got {focal!r}")


def fit_detection(
    detection: HandDetection,
    model: HandModel,
    width: int,
    height: int,
    focal: str | float = "fov",
    config: FitConfig | None = None,
) -> HandDetection:
    """Return ``detection`` with fitted ``params`` and ``camera`` filled in.

    Args:
        detection: a hand with 21 OpenPose-order 2D keypoints (and ideally metric 3D ones).
        model: the hand model to fit.
        width, height: image size in pixels.
        focal: camera convention (see :func:`photo_camera`).
        config: the fit's settings (default :data:`DETECTION_FIT`).
    """
    cam = photo_camera(width, height, focal)
    k2 = torch.as_tensor(detection.keypoints2d, dtype=torch.float64)[None]
    k3 = None
    if detection.keypoints3d is not None:
        k3 = torch.as_tensor(detection.keypoints3d, dtype=torch.float64)[None]
    fit = fit_keypoints(
        model, k3, keypoints2d=k2, camera=cam, side=detection.side, relative_3d=True,
        config=config or DETECTION_FIT,
    )  # fmt: skip
    meta = dict(detection.meta)
    meta["fit_error_2d_px"] = float(fit.error_2d.mean())
    if fit.error_3d is not None:
        meta["fit_error_3d_mm"] = float(fit.error_3d.mean() * 1000)
    return replace(detection, params=fit.params.to(dtype=torch.float32), camera=cam, meta=meta)
