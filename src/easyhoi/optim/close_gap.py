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

:func:`meet` then brings such a hand and its object together the other way: the object moves
onto the hand (the camera with the hand, so the hand's projection is again kept exactly) by at
most a finger's width, in the direction that shifts the object least in the photo. Hand and
object side by side in the photo with a gap between them is what two masks that both stop
short of the edge where the fingers meet the object give; the photo shows them touching.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from easyhoi.optim.state import Scene
from easyhoi.structures import Camera, HandParams

__all__ = [
    "CLOSE_GAP_SCAN",
    "MEET_MAX_M",
    "close_gap",
    "meet",
    "moved_with_camera",
    "rescaled_along_rays",
]

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
        hi = _bisect(nearest, lo, hi, target)
        note.update(moved=True, gap_after=nearest(hi), scale_factor=1.0 / hi,
                    distance=abs(hi - 1.0) / unit)  # fmt: skip
        return hi, note


#: Largest move of :func:`meet`, metres: about a finger's width, the band by which the hand mask
#: (grown from the skeleton, wider than the fingers) and the object mask can both stop short of
#: the edge where the fingers meet the object.
MEET_MAX_M = 0.02
#: Weights of the camera ray added to the surface normal in :func:`meet`'s candidate directions.
MEET_RAY_MIX = (0.0, 0.5, -0.5, 1.0, -1.0, 2.0, -2.0, 4.0, -4.0)


def meet(
    scene: Scene,
    params: HandParams,
    metric_scale: float,
    camera: Camera,
    sdf_resolution: int,
    target: float,
    max_move: float,
) -> tuple[torch.Tensor | None, dict]:
    """The move of the object onto a hand beside it that shifts it least in the photo.

    :func:`close_gap` moves a hand along its camera rays, which cannot bring together a hand and
    an object that lie side by side in the photo: there the two masks stop short of each other
    where the fingers meet the object (the hand mask is grown from the skeleton and is wider
    than the fingers; a segmentation boundary is uncertain by a few pixels). This moves the
    object instead, by the smallest step that makes the hand's nearest side touch it, along the
    outward surface normal at the hand's nearest vertex mixed with the camera ray through that
    vertex (:data:`MEET_RAY_MIX`; a move along the ray changes the object's size in the photo,
    not its place); of these, the one that moves the object's centre least in the photo is
    taken. Moving the camera by the same amount keeps the hand exactly where the photo shows it
    (:func:`moved_with_camera`). At most ``max_move`` (normalised object units) and
    :data:`MEET_MAX_M`; a larger gap is not a segmentation edge but a wrong object or hand,
    and is left (and reported).

    Returns:
        ``delta`` (3,) object units by which the hand (and the camera) move, or None when no
        move is made, and a JSON-ready note.
    """
    with torch.no_grad():
        verts = scene.hand_model(params).vertices[0] / metric_scale
    d = scene.sdf(verts, sdf_resolution)
    gap = float(d.min())
    note = {"gap_before": gap, "moved": False}
    limit = min(float(max_move), MEET_MAX_M / (float(metric_scale) * float(scene.extent)))
    if gap <= target or gap - target > limit:
        return None, note
    v = verts[int(torch.argmin(d))].detach().clone().requires_grad_(True)
    with torch.enable_grad():
        (grad,) = torch.autograd.grad(scene.sdf(v, sdf_resolution), v)
    if not bool(torch.isfinite(grad).all()) or float(grad.norm()) <= 0:
        return None, note
    n = grad / grad.norm()  # away from the object: the hand moves against it
    cam = camera.detach().to(verts.dtype)
    ray = v.detach() - cam.center
    ray = ray / ray.norm()
    unit = float(scene.extent)
    centre = scene.object_verts.to(verts.dtype).mean(0)
    uv0 = cam.project(centre[None])[0][0]
    best = None
    for mix in MEET_RAY_MIX:
        u = n + mix * ray
        u = u / u.norm()
        if float(u @ n) < 0.2:  # hardly toward the object
            continue

        def nearest(t: float, u=u) -> float:
            return float(scene.sdf(verts - t * unit * u, sdf_resolution).min())

        t = _first_touch(nearest, limit, target)
        if t is None:
            continue
        delta = -t * unit * u
        shift = float((moved_with_camera(params, metric_scale, cam, delta)[1]
                       .project(centre[None])[0][0] - uv0).norm())  # fmt: skip
        if best is None or shift < best[0] - 1e-9:
            best = (shift, t, delta, mix)
    if best is None:
        return None, note
    shift, t, delta, mix = best
    with torch.no_grad():
        after = float(scene.sdf(verts + delta, sdf_resolution).min())
    note.update(moved=True, gap_after=after, distance=t, ray_mix=mix, shift_px=shift,
                distance_cm=t * unit * float(metric_scale) * 100)  # fmt: skip
    return delta.detach(), note


def _first_touch(nearest, limit: float, target: float) -> float | None:
    """Smallest ``t`` in (0, limit] with ``nearest(t) <= target`` (scan, then bisection), or
    None."""
    steps = [limit * (i + 1) / CLOSE_GAP_SCAN for i in range(CLOSE_GAP_SCAN)]
    hi = next((t for t in steps if nearest(t) <= target), None)
    if hi is None:
        return None
    return _bisect(nearest, hi - limit / CLOSE_GAP_SCAN, hi, target)


def _bisect(nearest, lo: float, hi: float, target: float) -> float:
    """The touching end of ``[lo, hi]`` after :data:`CLOSE_GAP_BISECT` halvings, given
    ``nearest(lo) > target >= nearest(hi)``."""
    for _ in range(CLOSE_GAP_BISECT):
        mid = 0.5 * (lo + hi)
        if nearest(mid) <= target:
            hi = mid
        else:
            lo = mid
    return hi


def moved_with_camera(
    params: HandParams, metric_scale: float, camera: Camera, delta: torch.Tensor
) -> tuple[HandParams, Camera]:
    """The hand moved by ``delta`` (object units) in the object frame and the camera with it:
    the hand's projection is unchanged, the object's moves."""
    d = delta.to(params.transl.dtype)
    moved = replace(params, transl=params.transl + float(metric_scale) * d[None])
    R = camera.R.detach()
    cam = replace(camera, t=camera.t - R @ d.to(R.dtype))
    return moved, cam
