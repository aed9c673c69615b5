"""PNG encoding, a matplotlib figure without pyplot's global state, and the loss curves."""

from __future__ import annotations

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIResult

__all__ = [
    "FIGURE_DPI",
    "PNG_COMPRESS_LEVEL",
    "losses_png",
    "new_figure",
    "png_bytes",
    "stage_loss_series",
]

#: Pixels per inch of the matplotlib figures (:func:`new_figure`).
FIGURE_DPI = 100
#: zlib level of every PNG written (0-9). Level 1 encodes the pictures several times faster
#: than the default 6 for files about a third larger; the bytes are the same at every run.
PNG_COMPRESS_LEVEL = 1


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of an (H, W, 3) or (H, W) uint8 array (:func:`easyhoi.viz.png.encode_png`)."""
    from easyhoi.viz.png import encode_png

    return encode_png(image, PNG_COMPRESS_LEVEL)


def new_figure(width_in: float, height_in: float):
    """A matplotlib Figure with an Agg canvas (no pyplot, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=FIGURE_DPI)
    FigureCanvasAgg(fig)
    return fig


def stage_loss_series(losses: list[dict]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Iteration numbers and one series per numeric loss key of a stage history.

    Args:
        losses (list of dict): ``StageResult.losses``; ``"iter"`` (if present) gives the x axis,
            every other key with numeric values becomes a series (missing entries are NaN).

    Returns:
        x: (N,) float
        series: dict of str -> (N,) float
    """
    x = np.array(
        [float(d.get("iter", i)) if _is_num(d.get("iter", i)) else i for i, d in enumerate(losses)]
    )
    keys: list[str] = []
    for d in losses:
        keys += [k for k, v in d.items() if k != "iter" and _is_num(v) and k not in keys]
    series = {
        k: np.array([float(d[k]) if _is_num(d.get(k)) else np.nan for d in losses]) for k in keys
    }
    return x, series


def _is_num(v) -> bool:
    if isinstance(v, bool):
        return False
    try:
        float(v)
    except (TypeError, ValueError):
        return False
    return getattr(v, "ndim", 0) == 0


def losses_png(result: HOIResult) -> bytes:
    """Loss curves, one panel per stage with a history, log scale.

    Non-positive and non-finite values are left out of the log plot. Stages without a history
    (e.g. "initial") get no panel; they are listed under the title. ``"total"`` is drawn thick
    and black. The panels are drawn with Pillow (:mod:`easyhoi.viz.chart`).
    """
    from easyhoi.viz.chart import Series, log_chart
    from easyhoi.viz.compose import Panel, compose_grid

    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    stages = [s for s in result.stages if stage_loss_series(s.losses)[1]]
    skipped = [s.name for s in result.stages if not any(s is t for t in stages)]
    title = "Loss curves per stage (log scale)"
    if skipped:
        title += f"\nno loss history: {', '.join(skipped)}"
    panels = []
    for st in stages:
        # no seconds in a picture: the pictures are the same bytes at every run of a seed (the
        # report's stage table gives the times)
        name = f"{st.name}: {st.iterations} it"
        if st.stop_reason:
            name += f"\nstop: {st.stop_reason}"
        x, series = stage_loss_series(st.losses)
        curves = {k: Series(x, y, thick=k == "total") for k, y in series.items()}
        panels.append(Panel(log_chart(curves, _CHART_W, _CHART_H, name, "iteration")))
    if not panels:
        panels = [Panel(log_chart({}, _CHART_W, _CHART_H, empty_text="no loss history recorded"))]
    cols = min(len(panels), 4)
    return png_bytes(compose_grid(panels, cols, _CHART_W, title=title))


#: Size in pixels of one stage's panel in ``losses.png``.
_CHART_W, _CHART_H = 420, 320
