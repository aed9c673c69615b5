"""Input masks next to the masks the reconstruction renders, with their IoU.

Rendered masks come from the hard z-buffers of hand and object seen by the result's camera:
the hand is visible where its depth is not behind the object's (ties go to the hand, as in
:mod:`easyhoi.render.composite`), the object where it is in front of the hand, and the amodal
object wherever it is hit at all.
"""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.masks import mask_box, mask_iou
from easyhoi.hoi import HOIInput, HOIResult
from easyhoi.render.raster import depth_map
from easyhoi.viz.compose import Panel, compose_grid
from easyhoi.viz.marks import REGION_COLOUR
from easyhoi.viz.overlay import (
    _check_result,
    photo_camera,
    render_overlay,
    result_meshes,
    shrink_photo,
)
from easyhoi.viz.plots import png_bytes

__all__ = ["MASK_PAIRS", "PANEL_WIDTH", "mask_iou", "mask_ious", "masks_png", "rendered_masks"]

#: Width in pixels of each panel of ``masks.png``.
PANEL_WIDTH = 320

#: (input mask attribute of HOIInput, rendered mask key, label) compared in the figure.
MASK_PAIRS = (
    ("hand_mask", "hand_visible", "hand M_h"),
    ("object_mask", "object_visible", "object M_o"),
    ("amodal_mask", "object_amodal", "amodal object M^_o"),
)

_BOTH = (40, 160, 70)
_INPUT_ONLY = (220, 60, 50)
_RENDER_ONLY = (60, 110, 235)
_NONE = (245, 245, 245)


def rendered_masks(result: HOIResult, height: int, width: int) -> dict[str, np.ndarray]:
    """Masks of the final reconstruction on an ``height`` x ``width`` pixel grid.

    Returns:
        dict of str -> (H, W) bool: ``hand_visible``, ``object_visible``, ``hand_amodal``,
            ``object_amodal``.
    """
    result = _check_result(result)
    cam = photo_camera(result.camera, np.zeros((height, width, 3), np.uint8))
    cam = cam.detach().to(dtype=torch.float64)
    hand, obj = result_meshes(result)
    zh = depth_map(torch.tensor(hand.vertices), torch.tensor(hand.faces), cam).numpy()
    zo = depth_map(torch.tensor(obj.vertices), torch.tensor(obj.faces), cam).numpy()
    h, o = np.isfinite(zh), np.isfinite(zo)
    return {
        "hand_visible": h & (zh <= zo),
        "object_visible": o & (zo < zh),
        "hand_amodal": h,
        "object_amodal": o,
    }


def mask_ious(result: HOIResult, inp: HOIInput) -> dict[str, float]:
    """IoU of each :data:`MASK_PAIRS` pair, keyed by the rendered mask's name."""
    H, W = inp.size
    rendered = rendered_masks(result, H, W)
    return {r: mask_iou(getattr(inp, i), rendered[r]) for i, r, _ in MASK_PAIRS}


#: Colour of each comparison code ``2 * input + rendered``.
_PALETTE = np.array([_NONE, _RENDER_ONLY, _INPUT_ONLY, _BOTH], np.uint8)


def _compare(input_mask: np.ndarray, rendered: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: both, input only, rendered only or neither, in their colours."""
    code = np.left_shift(input_mask, 1, dtype=np.uint8) | rendered
    return _PALETTE[code]


#: Margin around the offered regions in their panels, as a share of the regions' larger side.
CHOICE_MARGIN = 0.25


def choice_panels(photo: np.ndarray, meta: dict, scale: float) -> list[Panel]:
    """One panel per object region offered for ``--object-choice`` (``meta["object_choices"]``,
    outlines in photo pixels, :mod:`easyhoi.perception.outlines`), drawn on ``photo`` (the
    photo resized by ``scale``), the one used marked; [] when there are none.

    Every panel shows the same window: the box round all the regions, grown by
    :data:`CHOICE_MARGIN` of its larger side on every side (within the photo), so that regions a
    small part of the photo (a pen, a lid, a label) are large enough to tell apart. Each region
    is tinted and outlined (:func:`_mark_region`), so that one a few pixels wide still shows
    when the panel is shrunk to :data:`PANEL_WIDTH`.
    """
    from easyhoi.perception.outlines import outlines_mask

    choices = meta.get("object_choices") or []
    used = meta.get("object_choice") or 1
    regions = [outlines_mask(outlines, photo.shape[:2], scale) for outlines in choices]
    if not regions:
        return []
    y0, y1, x0, x1 = _window(np.logical_or.reduce(regions))
    panels = []
    for k, m in enumerate(regions, start=1):
        crop, m = photo[y0:y1, x0:x1].copy(), m[y0:y1, x0:x1]  # the window holds every region
        crop[m] = (0.45 * crop[m] + 0.55 * np.array(REGION_COLOUR)).astype(np.uint8)
        _mark_region(crop, m)
        title = f"--object-choice {k}" + (" (used)" if k == used else "")
        panels.append(Panel(crop, title))
    return panels


#: A region whose box's larger side is below this share of its panel's larger side gets a ring.
SMALL_REGION = 0.15


def _mark_region(img: np.ndarray, m: np.ndarray) -> None:
    """Outline the region ``m`` on ``img`` (in place), about 1.5 pixels wide once the panel is
    shrunk to :data:`PANEL_WIDTH`; a small region (:data:`SMALL_REGION`) also gets a ring round
    it, as the tint of a pen a few photo pixels wide vanishes when the panel is shrunk."""
    import cv2

    side = max(img.shape[:2])
    width = max(1, round(1.5 * side / PANEL_WIDTH))
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return
    cv2.drawContours(img, contours, -1, REGION_COLOUR, width)
    u0, v0, u1, v1 = mask_box(m)
    extent = max(v1 - v0, u1 - u0)
    if extent < SMALL_REGION * side:
        centre = (int(round((u0 + u1 - 1) / 2)), int(round((v0 + v1 - 1) / 2)))
        radius = int(round(max(0.75 * extent, 0.06 * side))) + 2 * width
        cv2.circle(img, centre, radius, REGION_COLOUR, width)


def _window(union: np.ndarray) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the box round ``union`` grown by :data:`CHOICE_MARGIN` of its larger
    side, within the picture; the whole picture when ``union`` is empty."""
    h, w = union.shape
    if not union.any():
        return 0, h, 0, w
    u0, v0, u1, v1 = mask_box(union)
    pad = CHOICE_MARGIN * max(v1 - v0, u1 - u0)
    y0, y1 = int(max(0, v0 - pad)), int(min(h, v1 + pad))
    return y0, y1, int(max(0, u0 - pad)), int(min(w, u1 + pad))


def masks_png(
    result: HOIResult,
    inp: HOIInput,
    full_size: bool = False,
    context: np.ndarray | None = None,
    choices: list[Panel] | None = None,
) -> bytes:
    """Figure: top row photo and input masks, bottom row overlay and input-vs-rendered maps;
    with ``choices`` (:func:`choice_panels`), a third row of the object regions a user may
    pick instead.

    Bottom-row colours: green where both masks agree, red for input only, blue for rendered
    only; each title gives the IoU (computed at the input's size). The panels are
    :data:`PANEL_WIDTH` pixels wide; the overlay is drawn at that width, or at the photo's size
    with ``full_size`` (then downscaled into its panel). With ``context`` (the whole photo
    with the window that ``result`` and ``inp`` were cut to outlined, see
    :mod:`easyhoi.viz.zoom`) the first panel shows it instead of ``inp``'s photo.
    """
    result = _check_result(result)
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"expected an HOIInput, got {type(inp).__name__}")
    H, W = inp.size
    rendered = rendered_masks(result, H, W)
    small = shrink_photo(inp.image, PANEL_WIDTH)  # the photo panel, as compose_grid shows it
    first = (
        Panel(small, "input photo")
        if context is None
        else Panel(context, "input photo\n(outlined: the part shown)")
    )
    panels = [first]
    panels += [Panel(getattr(inp, i), f"input {label}") for i, _, label in MASK_PAIRS]
    photo = inp.image if full_size else small
    panels.append(Panel(render_overlay(result, photo).image, "reconstruction overlay"))
    for i, r, label in MASK_PAIRS:
        iou = mask_iou(getattr(inp, i), rendered[r])
        name = r.replace("_", " ")
        title = f"rendered {name} vs {label.split()[-1]}\nIoU {iou:.3f}"
        panels.append(Panel(_compare(getattr(inp, i), rendered[r]), title))
    legend = [("both", _BOTH), ("input only", _INPUT_ONLY), ("rendered only", _RENDER_ONLY)]
    title = "Input masks (top) vs masks rendered from the reconstruction (bottom)"
    if context is not None:
        title += ", around the hand and object"
    if choices:
        panels += list(choices)
        legend.append(("object region offered", REGION_COLOUR))
        title += "; the object regions offered (third row)"
    return png_bytes(compose_grid(panels, 4, PANEL_WIDTH, title=title, legend=legend))
