"""Figure helpers (PNG encoding without pyplot's global state) and the loss-curve plot."""

from __future__ import annotations

import io
import math

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIResult

__all__ = ["figure_png", "losses_png", "new_figure", "png_bytes", "stage_loss_series"]

_DPI = 100


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of an (H, W, 3) or (H, W) uint8 array."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim not in (2, 3):
        raise InvalidInputError(f"expected a uint8 image, got {a.shape} {a.dtype}")
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG", optimize=False)
    return buf.getvalue()


def new_figure(width_in: float, height_in: float):
    """A matplotlib Figure with an Agg canvas (no pyplot, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig) -> bytes:
    """PNG bytes of a Figure (deterministic: no timestamp metadata)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})
    return buf.getvalue()


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
    and black.
    """
    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    stages = [s for s in result.stages if stage_loss_series(s.losses)[1]]
    skipped = [s.name for s in result.stages if not any(s is t for t in stages)]
    n = max(1, len(stages))
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig = new_figure(4.2 * cols, 3.3 * rows + 0.4)
    title = "Loss curves per stage (log scale)"
    if skipped:
        title += f"\nno loss history: {', '.join(skipped)}"
    fig.suptitle(title, fontsize=11)
    if not stages:
        ax = fig.add_subplot(1, 1, 1)
        ax.axis("off")
        ax.text(0.5, 0.5, "no loss history recorded", ha="center", va="center")
        return figure_png(fig)
    for i, st in enumerate(stages):
        ax = fig.add_subplot(rows, cols, i + 1)
        title = f"{st.name}: {st.iterations} it, {st.seconds:.2f} s"
        if st.stop_reason:
            title += f"\nstop: {st.stop_reason}"
        ax.set_title(title, fontsize=9)
        x, series = stage_loss_series(st.losses)
        drawn = 0
        for k, y in series.items():
            ok = np.isfinite(y) & (y > 0)
            if not ok.any():
                continue
            style = dict(color="black", lw=2.2, zorder=3) if k == "total" else dict(lw=1.3)
            ax.plot(x[ok], y[ok], label=k, marker="." if ok.sum() < 12 else None, **style)
            drawn += 1
        if drawn:
            ax.set_yscale("log")
            ax.legend(fontsize=7, loc="best")
            ax.grid(True, which="both", alpha=0.3)
        else:
            ax.text(0.5, 0.5, "no loss history", ha="center", va="center", transform=ax.transAxes)
            ax.set_yticks([])
        ax.set_xlabel("iteration", fontsize=8)
        ax.tick_params(which="both", labelsize=7)
    fig.tight_layout()
    return figure_png(fig)
