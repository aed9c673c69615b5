"""The part of the photo where the hand and the object are, for the figures that judge them.

In most photos the hand and what it holds fill a small part of the frame (a person at a table,
a video frame): drawn over the whole photo at a figure's panel width, the meshes of
``stages.png`` and the masks of ``masks.png`` are a few dozen pixels across and cannot be
judged. Those figures therefore show the window around the input masks and the projected
meshes (:func:`interaction_box`), resampled to at least the panel width; ``masks.png`` keeps
the whole photo as its first panel, with the window outlined.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from easyhoi.hoi import HOIInput, HOIResult

__all__ = ["ZOOM_MARGIN", "ZOOM_MIN_SIDE", "interaction_box", "mapped", "outlined", "zoomed"]

#: Context kept around the hand and the object, on every side, as a fraction of the longer
#: side of their joint bounding box.
ZOOM_MARGIN = 0.3

#: The window is at least this fraction of the photo's longer side (a small object in a
#: large photo still shows what lies around it).
ZOOM_MIN_SIDE = 0.25


def mapped(result: HOIResult, inp: HOIInput, image, mask, camera) -> tuple[HOIResult, HOIInput]:
    """``result`` and ``inp`` for a picture grid: the photo, the three masks and every camera
    passed through ``image``, ``mask`` and ``camera``. The hand-removed photo and the complete
    hand mask, which no picture draws, are dropped (None) rather than resampled."""
    new_inp = replace(
        inp, image=image(inp.image), hand_mask=mask(inp.hand_mask),
        object_mask=mask(inp.object_mask), amodal_mask=mask(inp.amodal_mask),
        inpainted_image=None, complete_hand_mask=None, hand_camera=camera(inp.hand_camera),
    )  # fmt: skip
    stages = tuple(
        replace(st, camera=None if st.camera is None else camera(st.camera)) for st in result.stages
    )
    return replace(result, camera=camera(result.camera), stages=stages), new_inp


def _projected_box(result: HOIResult, height: int, width: int) -> np.ndarray | None:
    """(x0, y0, x1, y1) of the final hand's and object's vertices in the photo, or None."""
    import torch

    cam = result.camera.detach().to(dtype=torch.float64).resized(width, height)
    pts = np.concatenate([result.hand_vertices, np.asarray(result.object_mesh.vertices)])
    uv, z = cam.project(torch.as_tensor(pts, dtype=torch.float64))
    uv = uv.numpy()[(z.numpy() > 0) & np.isfinite(uv.numpy()).all(axis=1)]
    if not len(uv):
        return None
    return np.array([*uv.min(axis=0), *uv.max(axis=0)])


def interaction_box(
    result: HOIResult, inp: HOIInput, margin: float = ZOOM_MARGIN, min_side: float = ZOOM_MIN_SIDE
) -> tuple[int, int, int, int]:
    """The window (x0, y0, x1, y1), pixels, end exclusive, inside the photo, that holds the
    input hand, object and amodal masks and the reconstruction's projection, grown by
    ``margin`` of its longer side on every side and to at least ``min_side`` of the photo's
    longer side; the whole photo when there is nothing to frame."""
    H, W = inp.image.shape[:2]
    boxes = []
    masks = [inp.hand_mask, inp.object_mask, inp.amodal_mask]
    union = np.logical_or.reduce([np.asarray(m, bool) for m in masks])
    if union.any():
        ys, xs = np.nonzero(union)
        boxes.append(np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], float))
    proj = _projected_box(result, H, W)
    if proj is not None:
        boxes.append(np.clip(proj, 0, [W, H, W, H]))
    if not boxes:
        return 0, 0, W, H
    b = np.stack(boxes)
    x0, y0, x1, y1 = b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()
    grow = margin * max(x1 - x0, y1 - y0)
    side_min = min_side * max(H, W)
    out = []
    for lo, hi, size in ((x0, x1, W), (y0, y1, H)):
        lo, hi = lo - grow, hi + grow
        if hi - lo < side_min:  # widen about the centre
            c = 0.5 * (lo + hi)
            lo, hi = c - side_min / 2, c + side_min / 2
        length = min(hi - lo, size)
        lo = min(max(lo, 0.0), size - length)  # shifted into the photo, not cut
        out.append((int(np.floor(lo)), int(min(size, np.ceil(lo + length)))))
    (x0, x1), (y0, y1) = out
    return x0, y0, x1, y1


def zoomed(
    result: HOIResult, inp: HOIInput, box: tuple[int, int, int, int], min_width: int
) -> tuple[HOIResult, HOIInput]:
    """``result`` and ``inp`` cut to ``box`` (photo pixels) and, when the window is narrower
    than ``min_width``, enlarged to that width (bicubic pictures, nearest-neighbour masks), so
    that what is drawn over it is drawn at the width it is shown."""
    import cv2

    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    s = max(1.0, min_width / w)
    tw, th = max(1, round(w * s)), max(1, round(h * s))

    def image(a):
        a = np.ascontiguousarray(a[y0:y1, x0:x1])
        return a if s == 1.0 else cv2.resize(a, (tw, th), interpolation=cv2.INTER_CUBIC)

    def mask(m):
        m = np.ascontiguousarray(m[y0:y1, x0:x1])
        if s == 1.0:
            return m
        return cv2.resize(m.astype(np.uint8), (tw, th), interpolation=cv2.INTER_NEAREST) > 0

    def camera(c):
        full = c.resized(inp.image.shape[1], inp.image.shape[0])
        return full.cropped(x0, y0, w, h).resized(tw, th)

    return mapped(result, inp, image, mask, camera)


def outlined(image: np.ndarray, box: tuple[int, int, int, int], color=(255, 210, 0)) -> np.ndarray:
    """A copy of ``image`` with ``box`` (x0, y0, x1, y1, end exclusive) outlined, the line
    about 0.4 % of the image's longer side wide."""
    import cv2

    out = np.ascontiguousarray(image).copy()
    t = max(1, round(0.004 * max(out.shape[:2])))
    x0, y0, x1, y1 = box
    cv2.rectangle(out, (int(x0), int(y0)), (int(x1) - 1, int(y1) - 1), color, t)
    return out
