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
from easyhoi.hoi import HOIInput, HOIResult
from easyhoi.render.raster import depth_map
from easyhoi.viz.overlay import (
    _check_result,
    photo_camera,
    render_overlay,
    result_meshes,
    shrink_photo,
)
from easyhoi.viz.plots import FIGURE_DPI, figure_png, new_figure

__all__ = ["MASK_PAIRS", "mask_iou", "mask_ious", "masks_png", "rendered_masks"]

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


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks; NaN when both are empty."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise InvalidInputError(f"masks differ in shape: {a.shape} vs {b.shape}")
    union = np.count_nonzero(a | b)
    return float("nan") if union == 0 else np.count_nonzero(a & b) / union


def mask_ious(result: HOIResult, inp: HOIInput) -> dict[str, float]:
    """IoU of each :data:`MASK_PAIRS` pair, keyed by the rendered mask's name."""
    H, W = inp.size
    rendered = rendered_masks(result, H, W)
    return {r: mask_iou(getattr(inp, i), rendered[r]) for i, r, _ in MASK_PAIRS}


def _compare(input_mask: np.ndarray, rendered: np.ndarray) -> np.ndarray:
    out = np.empty(input_mask.shape + (3,), np.uint8)
    out[:] = _NONE
    out[input_mask & rendered] = _BOTH
    out[input_mask & ~rendered] = _INPUT_ONLY
    out[~input_mask & rendered] = _RENDER_ONLY
    return out


def masks_png(result: HOIResult, inp: HOIInput, full_size: bool = False) -> bytes:
    """Figure: top row photo and input masks, bottom row overlay and input-vs-rendered maps.

    Bottom-row colours: green where both masks agree, red for input only, blue for rendered
    only; each title gives the IoU (computed at the input's size). The overlay is drawn at the
    panel's size in the figure, or at the photo's size with ``full_size``.
    """
    from matplotlib.patches import Patch

    result = _check_result(result)
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"expected an HOIInput, got {type(inp).__name__}")
    H, W = inp.size
    rendered = rendered_masks(result, H, W)
    panel_w = 3.2
    panel_h = panel_w * H / W
    fig = new_figure(panel_w * 4, 2 * (panel_h + 0.6) + 1.0)
    fig.suptitle(
        "Input masks (top) vs masks rendered from the reconstruction (bottom)", fontsize=12
    )
    top = [("input photo", inp.image, None)]
    top += [(f"input {label}", getattr(inp, i), "gray") for i, _, label in MASK_PAIRS]
    photo = shrink_photo(inp.image, None if full_size else round(panel_w * FIGURE_DPI))
    bottom = [("reconstruction overlay", render_overlay(result, photo).image, None)]
    for i, r, label in MASK_PAIRS:
        iou = mask_iou(getattr(inp, i), rendered[r])
        name = r.replace("_", " ")
        title = f"rendered {name} vs {label.split()[-1]}\nIoU {iou:.3f}"
        bottom.append((title, _compare(getattr(inp, i), rendered[r]), None))
    for k, (title, img, cmap) in enumerate(top + bottom):
        ax = fig.add_subplot(2, 4, k + 1)
        kw = dict(cmap=cmap, vmin=0, vmax=1) if cmap else {}
        ax.imshow(img, interpolation="nearest", **kw)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    handles = [
        Patch(color=np.array(_BOTH) / 255, label="both"),
        Patch(color=np.array(_INPUT_ONLY) / 255, label="input only"),
        Patch(color=np.array(_RENDER_ONLY) / 255, label="rendered only"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.86, bottom=0.08, wspace=0.05, hspace=0.32)
    return figure_png(fig)
