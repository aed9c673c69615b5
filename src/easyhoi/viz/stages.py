"""One overlay per optimizer stage snapshot (initial / camera / contact / refine)."""

from __future__ import annotations

import math

import numpy as np

from easyhoi.hoi import HOIResult
from easyhoi.viz.overlay import (
    _check_image,
    _check_result,
    render_overlay,
    result_meshes,
    shrink_photo,
    stage_meshes,
)
from easyhoi.viz.plots import (
    FIGURE_DPI,
    figure_png,
    fixed_margins,
    new_figure,
    stage_loss_series,
)

__all__ = ["render_stages", "stages_png"]

_PANEL_IN = 3.6


def render_stages(
    result: HOIResult, image: np.ndarray, hand_model=None, width: int | None = None
) -> list[tuple[str, np.ndarray, str]]:
    """Overlays of every stage snapshot.

    Args:
        result: The reconstruction.
        image: (H, W, 3) uint8, the photo.
        hand_model: The run's hand model, posing the snapshots' hands; without it the earlier
            snapshots show the object only.
        width: Draw the overlays this many pixels wide (the photo downscaled, aspect kept)
            when the photo is wider; None draws them at the photo's size.

    Returns:
        ``(name, (h, w, 3) uint8 overlay, note)`` per stage, in stage order; ``note`` is empty
        or says why the hand is missing. A result without stages gives one panel
        ``("final", ...)``.
    """
    result = _check_result(result)
    image = shrink_photo(_check_image(image), width)
    if not result.stages:
        return [("final", render_overlay(result, image).image, "")]
    out = []
    for st in result.stages:
        meshes, cam, note = stage_meshes(result, st, hand_model)
        out.append((st.name, render_overlay(result, image, meshes=meshes, camera=cam).image, note))
    return out


def _summary(stage) -> str:
    if stage is None:
        return ""
    _, series = stage_loss_series(stage.losses)
    key = "total" if "total" in series else next(iter(series), None)
    parts = [f"{stage.iterations} it"] if stage.iterations else []
    if key is not None:
        y = series[key]
        y = y[np.isfinite(y)]
        if y.size:
            parts.append(f"{key} {y[-1]:.3g}")
    return ", ".join(parts)


def stages_png(
    result: HOIResult, image: np.ndarray, hand_model=None, full_size: bool = False
) -> bytes:
    """One figure with an overlay panel per stage, titled with the stage's final loss.

    The overlays are drawn at the panels' size in the figure (``_PANEL_IN`` inches at the
    figure's resolution), or at the photo's size with ``full_size``.
    """
    from matplotlib.patches import Patch

    panel_px = None if full_size else round(_PANEL_IN * FIGURE_DPI)
    panels = render_stages(result, image, hand_model, width=panel_px)
    stages = {s.name: s for s in result.stages}
    n = len(panels)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    H, W = image.shape[:2]
    panel_h = _PANEL_IN * H / W
    fig = new_figure(_PANEL_IN * cols, (panel_h + 0.75) * rows + 0.6)
    fig.suptitle("Optimization stages (meshes over the photo)", fontsize=12)
    for i, (name, img, note) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(img, interpolation="lanczos")
        title = f"{i + 1}. {name}"
        summary = _summary(stages.get(name))
        if summary:
            title += f"\n{summary}"
        if note:
            title += f"\n({note})"
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    meshes = result_meshes(result)
    handles = [Patch(color=np.array(m.color) / 255, label=m.name) for m in meshes]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=9, frameon=False)
    # the suptitle and up to three lines of panel title above each row, the legend below
    fixed_margins(fig, left=0.05, right=0.05, top=0.95, bottom=0.3, wspace=0.1, hspace=0.7)
    return figure_png(fig)
