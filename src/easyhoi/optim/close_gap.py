"""Close the gap between a hand that ends beside its object and the object, along the camera rays.

A photo fixes where the hand is in the image, and the keypoint and mask terms of the
refinement hold it there, but a photo says little about how far the hand is from the camera
relative to the object: that is the one direction in which the refinement's terms (masks, 2D
keypoints, the pose prior) are nearly blind, and the contact term pulls only fingers that are
already within a few per cent of the object's size. A hand that the refinement leaves a few
millimetres off the object therefore stays there, although the photo shows it holding it.

:func:`close_gap` moves such a hand along the camera rays to the depth where its nearest vertex
touches the object's surface: it scales the object-unit hand about the camera centre by a factor
``k`` (``v -> eye + k (v - eye)``, the metric scale becomes ``m / k``, as
:func:`easyhoi.optim.refine.push_out` with ``push_out_scale``), which keeps the hand's projection
exactly, so nothing the photo shows changes. The smallest such move is taken, toward the camera
or away from it, at most :data:`~easyhoi.optim.refine.PUSH_OUT_MAX` of the object's size; a hand
already touching or penetrating, or one that no move along its rays brings onto the object (it
lies beside the object in the image), is left where it is.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from easyhoi.optim.state import Scene
from easyhoi.structures import Camera, HandParams

__all__ = ["CLOSE_GAP_SCAN", "close_gap", "rescaled_along_rays"]

#: Candidate moves of the hand's centroid along its ray scanned each way before the bisection,
#: up to the largest move (normalised object units, see :data:`easyhoi.optim.refine.PUSH_OUT_MAX`).
CLOSE_GAP_SCAN = 24
#: Bisection steps between the last scanned move with a gap and the first that touches.
CLOSE_GAP_BISECT = 30


def rescaled_along_rays(
    params: HandParams, metric_scale: float, k: float, camera: Camera
) -> tuple[HandParams, float]:
    """The same metric hand in the camera after its object-unit vertices are scaled by ``k``
    about the camera centre: the object's metric scale becomes ``m / k`` and, in the metric
    object frame, the hand moves by ``(m / k - m) eye`` (``eye``: the camera centre, object
    units). Returns (params, new metric scale)."""
    m_new = float(metric_scale) / float(k)
    eye = camera.center.detach().to(params.transl.dtype)
    return replace(params, transl=params.transl + (m_new - float(metric_scale)) * eye[None]), m_new


def close_gap(
    scene: Scene,
    params: HandParams,
    metric_scale: float,
    camera: Camera,
    sdf_resolution: int,
    target: float,
    max_move: float,
) -> tuple[float, dict]:
    """The factor ``k`` of the smallest move along the camera rays that makes the hand touch.

    Args:
        scene: the optimizer's scene (object SDF, hand model).
        params: the hand (metric object frame).
        metric_scale: metres per object unit.
        camera: the object camera (object frame, object units).
        sdf_resolution: SDF grid size for the distance lookups.
        target: the signed distance (normalised object units, negative inside) the hand's
            nearest vertex is brought to: a hair inside the surface, so that it touches.
        max_move: the largest move of the hand's centroid along its ray, normalised units.

    Returns:
        ``k`` (1: no move; the metric scale becomes ``metric_scale / k`` and the metric-frame
        hand moves by ``(metric_scale / k - metric_scale) * eye``) and a JSON-ready note.
    """
    with torch.no_grad():
        verts = scene.hand_model(params).vertices[0] / metric_scale
        eye = camera.center.detach().to(verts.dtype)
        dist = float((verts.mean(0) - eye).norm())  # the centroid's distance, object units

        def nearest(k: float) -> float:
            v = eye + (verts - eye) * k
            return float(scene.sdf(v, sdf_resolution).min())

        gap = nearest(1.0)
        note = {"gap_before": gap, "moved": False}
        if gap <= 0.0 or dist <= 0.0:
            return 1.0, note
        unit = float(scene.extent) / dist  # k per normalised unit of centroid move
        steps = [max_move * (i + 1) / CLOSE_GAP_SCAN for i in range(CLOSE_GAP_SCAN)]
        lo = hi = None
        for t in steps:  # the smallest move first, toward the camera and away from it
            for sign in (1.0, -1.0):
                k = 1.0 + sign * t * unit
                if k > 0 and nearest(k) <= target:
                    hi = k
                    lo = 1.0 + sign * (t - max_move / CLOSE_GAP_SCAN) * unit
                    break
            if hi is not None:
                break
        if hi is None:  # no move along the rays reaches the object
            return 1.0, note
        for _ in range(CLOSE_GAP_BISECT):  # nearest(lo) > target >= nearest(hi)
            mid = 0.5 * (lo + hi)
            if nearest(mid) <= target:
                hi = mid
            else:
                lo = mid
        note.update(moved=True, gap_after=nearest(hi), scale_factor=1.0 / hi,
                    distance=abs(hi - 1.0) / unit)  # fmt: skip
        return hi, note
