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
    stage_meshes,
)
from easyhoi.viz.plots import figure_png, new_figure, stage_loss_series

__all__ = ["render_stages", "stages_png"]

_PANEL_IN = 3.6


def render_stages(
    result: HOIResult, image: np.ndarray, hand_model=None
) -> list[tuple[str, np.ndarray, str]]:
    """Overlays of every stage snapshot.

    Args:
        result: The reconstruction.
        image: (H, W, 3) uint8, the photo.
        hand_model: The run's hand model, posing the snapshots' hands; without it the earlier
            snapshots show the object only.

    Returns:
        ``(name, (H, W, 3) uint8 overlay, note)`` per stage, in stage order; ``note`` is empty
        or says why the hand is missing. A result without stages gives one panel
        ``("final", ...)``.
    """
    result = _check_result(result)
    image = _check_image(image)
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


def stages_png(result: HOIResult, image: np.ndarray, hand_model=None) -> bytes:
    """One figure with an overlay panel per stage, titled with the stage's final loss."""
    from matplotlib.patches import Patch

    panels = render_stages(result, image, hand_model)
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
    fig.tight_layout(rect=(0, 0.05, 1, 0.95))
    return figure_png(fig)
