"""One overlay per optimizer stage snapshot (initial / camera / contact / refine)."""

from __future__ import annotations

import numpy as np

from easyhoi.hoi import HOIResult
from easyhoi.viz.compose import Panel, compose_grid
from easyhoi.viz.overlay import (
    _check_image,
    _check_result,
    render_overlay,
    result_meshes,
    shrink_photo,
    stage_meshes,
)
from easyhoi.viz.plots import png_bytes, stage_loss_series

__all__ = ["PANEL_WIDTH", "render_stages", "stages_png"]

#: Width in pixels of each stage's panel in ``stages.png``.
PANEL_WIDTH = 360


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
    result: HOIResult,
    image: np.ndarray,
    hand_model=None,
    full_size: bool = False,
    zoomed: bool = False,
) -> bytes:
    """One figure with an overlay panel per stage, titled with the stage's final loss.

    The overlays are drawn at the panels' width (:data:`PANEL_WIDTH` pixels), or at the
    photo's size with ``full_size`` (then downscaled into the same panels). ``zoomed``:
    ``result`` and ``image`` are the window around the hand and the object
    (:mod:`easyhoi.viz.zoom`), which the title then says.
    """
    panels = render_stages(result, image, hand_model, width=None if full_size else PANEL_WIDTH)
    stages = {s.name: s for s in result.stages}
    shown = []
    for i, (name, img, note) in enumerate(panels):
        title = f"{i + 1}. {name}"
        summary = _summary(stages.get(name))
        if summary:
            title += f"\n{summary}"
        if note:
            title += f"\n({note})"
        shown.append(Panel(img, title))
    legend = [(m.name, m.color) for m in result_meshes(result)]
    title = "Optimization stages (meshes over the photo"
    title += ", around the hand and object)" if zoomed else ")"
    fig = compose_grid(shown, 4, PANEL_WIDTH, title=title, legend=legend)
    return png_bytes(fig)
