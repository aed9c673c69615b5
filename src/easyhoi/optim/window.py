"""The optimizer's window: the part of the photo around the hand and the object.

Every silhouette the optimizer compares is rendered at ``OptimConfig.render_size`` pixels on its
longer side. Over the whole photo, a hand and an object that fill a fifth of a video frame's
width are a few pixels each at that size (a cup 60 px wide in a 1280 px frame is 6 px at 128),
and a silhouette fit at that resolution accepts cameras whose full-resolution silhouette misses
half the object. So the optimizer works on a window of the photo: the box of the masks and the
detector's keypoints, grown by :data:`MARGIN` of its longer side on every side (room for the
silhouettes to move and for the background that tells a spilling silhouette from a fitting
one), at least ``render_size`` pixels on its longer side where the photo has them (never a
window the renders would enlarge), within the photo. A photo no larger than ``render_size`` is
rendered at its own resolution already and is used whole. A window is a crop, not a resampling: the
focal length in pixels is the same and only the principal point moves
(:meth:`easyhoi.structures.Camera.cropped`), so every 3D quantity is unchanged; the result's
cameras are moved back to the whole photo at the end.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from easyhoi.geometry.masks import mask_box
from easyhoi.hoi import HOIInput, HOIResult

__all__ = ["MARGIN", "crop_input", "interest_window", "to_photo"]

#: Growth of the window on every side, as a fraction of the longer side of the masks' box.
MARGIN = 0.25


def _span(a: float, b: float, length: float, limit: int) -> tuple[int, int]:
    """``[a, b)`` widened about its centre to at least ``length`` (at most ``limit``), then moved
    inside ``[0, limit)`` (a box at the photo's edge keeps its size by growing inwards)."""
    length = min(length, float(limit))
    if b - a < length:
        c = 0.5 * (a + b)
        a, b = c - 0.5 * length, c + 0.5 * length
    if a < 0:
        a, b = 0.0, b - a
    if b > limit:
        a, b = a - (b - limit), float(limit)
    return int(np.floor(max(a, 0.0))), int(np.ceil(min(b, float(limit))))


def interest_window(
    inp: HOIInput, render_size: int, margin: float = MARGIN
) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` (x1, y1 exclusive) of the window around the hand and the object
    (module docs)."""
    H, W = inp.size
    if max(H, W) <= render_size:  # the renders already see every pixel of the photo
        return 0, 0, W, H
    # an HOIInput's masks are never empty
    boxes = [mask_box(m) for m in (inp.hand_mask, inp.object_mask, inp.amodal_mask)]
    kp = (inp.meta or {}).get("keypoints2d")
    if kp is not None:
        pts = np.asarray(kp, dtype=np.float64).reshape(-1, 2)
        if pts.size and np.isfinite(pts).all():
            lo, hi = np.floor(pts.min(axis=0)), np.ceil(pts.max(axis=0)) + 1
            boxes.append((int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])))
    x0, y0 = min(b[0] for b in boxes), min(b[1] for b in boxes)
    x1, y1 = max(b[2] for b in boxes), max(b[3] for b in boxes)
    grow = margin * max(x1 - x0, y1 - y0)
    gx, gy = (x0 - grow, x1 + grow), (y0 - grow, y1 + grow)
    # the longer side at least render_size pixels where the photo has them
    long_x = gx[1] - gx[0] >= gy[1] - gy[0]
    ax, bx = _span(*gx, render_size if long_x else 0, W)
    ay, by = _span(*gy, 0 if long_x else render_size, H)
    return ax, ay, bx, by


def crop_input(inp: HOIInput, win: tuple[int, int, int, int]) -> HOIInput:
    """``inp`` seen through the window: images and masks cut, the hand's camera cropped and the
    detector's keypoints moved by the window's offset."""
    x0, y0, x1, y1 = win
    if (x0, y0, x1, y1) == (0, 0, inp.size[1], inp.size[0]):
        return inp

    def cut(a):
        return None if a is None else np.ascontiguousarray(a[y0:y1, x0:x1])

    meta = dict(inp.meta)
    if meta.get("keypoints2d") is not None:
        pts = np.asarray(meta["keypoints2d"], dtype=np.float64) - np.array([x0, y0], np.float64)
        meta["keypoints2d"] = pts.tolist()
    return replace(
        inp,
        image=cut(inp.image),
        hand_mask=cut(inp.hand_mask),
        object_mask=cut(inp.object_mask),
        amodal_mask=cut(inp.amodal_mask),
        inpainted_image=cut(inp.inpainted_image),
        complete_hand_mask=cut(inp.complete_hand_mask),
        hand_camera=inp.hand_camera.cropped(x0, y0, x1 - x0, y1 - y0),
        meta=meta,
    )


def to_photo(result: HOIResult, win: tuple[int, int, int, int], size: tuple[int, int]) -> HOIResult:
    """``result`` of the windowed input with its cameras (final and per stage) moved onto the
    whole photo of ``size`` (H, W)."""
    x0, y0 = int(win[0]), int(win[1])
    H, W = size
    if (x0, y0, win[2], win[3]) == (0, 0, W, H):
        return result

    def back(cam):
        return None if cam is None else cam.cropped(-x0, -y0, W, H)

    stages = tuple(replace(s, camera=back(s.camera)) for s in result.stages)
    return replace(result, camera=back(result.camera), stages=stages)
