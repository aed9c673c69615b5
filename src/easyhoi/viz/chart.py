"""Line charts with a logarithmic y axis, drawn with Pillow (the loss curves of a result).

A chart is drawn at twice its size and halved by area averaging, which smooths the lines and
the texts; the same inputs give the same bytes at every run. Drawing with Pillow costs a few
hundredths of a second where a matplotlib figure of the same curves costs 0.2 s (its axes,
tick objects and text layout) plus the first figure's font and text-engine set-up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Series", "log_chart", "log_ticks", "nice_ticks"]

_SS = 2  # supersampling factor
_COLORS = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)
_GRID = (225, 225, 225)
_AXIS = (60, 60, 60)
_TEXT = (20, 20, 20)


@dataclass(frozen=True)
class Series:
    """One curve: ``x`` and positive ``y`` of the same length (other points are left out)."""

    x: np.ndarray
    y: np.ndarray
    thick: bool = False  # drawn thick and black (the total)


def nice_ticks(lo: float, hi: float, most: int = 7) -> list[float]:
    """Round tick values (1, 2 or 5 times a power of ten apart) covering ``[lo, hi]``."""
    if not hi > lo:
        return [lo]
    raw = (hi - lo) / max(1, most - 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def log_ticks(lo: float, hi: float) -> list[float]:
    """Tick values of a log axis spanning ``[lo, hi]`` (both > 0): the powers of ten inside,
    with 2 and 5 times them when the span is under 1.5 decades (so a narrow axis has labels);
    at most 12, thinned to every other decade when there are more."""
    subs = (1.0, 2.0, 5.0) if hi / lo < 10**1.5 else (1.0,)
    out = [
        s * 10.0**k
        for k in range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1)
        for s in subs
        if lo * (1 - 1e-9) <= s * 10.0**k <= hi * (1 + 1e-9)
    ]
    while len(out) > 12:
        out = out[::2]
    return out


def _label(v: float) -> str:
    return f"{v:g}"


def _font(size: int):
    from easyhoi.viz.compose import _font as font

    return font(size * _SS)


def log_chart(
    series: Mapping[str, Series],
    width: int,
    height: int,
    title: str = "",
    xlabel: str = "",
    empty_text: str = "no loss history",
) -> np.ndarray:
    """One chart panel: curves on a log y axis, grid, tick labels, title and a legend.

    Returns:
        (height, width, 3) uint8
    """
    from PIL import Image, ImageDraw

    S = _SS
    img = Image.new("RGB", (width * S, height * S), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    title_lines = title.split("\n") if title else []
    top = (8 + 14 * len(title_lines) + 6) * S
    left, right, bottom = 62 * S, (width - 12) * S, (height - 34) * S
    for k, line in enumerate(title_lines):
        w = draw.textlength(line, font=_font(11))
        draw.text(((width * S - w) / 2, (6 + 14 * k) * S), line, fill=_TEXT, font=_font(11))
    draw.rectangle((left, top, right, bottom), outline=_AXIS, width=S)
    if xlabel:
        w = draw.textlength(xlabel, font=_font(10))
        draw.text(((left + right - w) / 2, bottom + 17 * S), xlabel, fill=_TEXT, font=_font(10))
    kept = {}
    for name, s in series.items():
        x, y = np.asarray(s.x, float), np.asarray(s.y, float)
        ok = np.isfinite(x) & np.isfinite(y) & (y > 0)
        if ok.any():
            kept[name] = (x[ok], y[ok], s.thick)
    if not kept:
        w = draw.textlength(empty_text, font=_font(11))
        draw.text(((left + right - w) / 2, (top + bottom) / 2), empty_text, fill=_TEXT,
                  font=_font(11))  # fmt: skip
        return _halve(img)
    xs = np.concatenate([v[0] for v in kept.values()])
    ys = np.concatenate([v[1] for v in kept.values()])
    x0, x1 = float(xs.min()), float(xs.max())
    if x1 <= x0:
        x0, x1 = x0 - 0.5, x1 + 0.5
    pad = 0.04 * (x1 - x0)
    x0, x1 = x0 - pad, x1 + pad
    ly0, ly1 = math.log10(float(ys.min())), math.log10(float(ys.max()))
    if ly1 - ly0 < 0.1:
        ly0, ly1 = ly0 - 0.05, ly1 + 0.05
    pad = 0.05 * (ly1 - ly0)
    ly0, ly1 = ly0 - pad, ly1 + pad

    def px(x):
        return left + (np.asarray(x) - x0) / (x1 - x0) * (right - left)

    def py(y):
        return bottom - (np.log10(np.asarray(y)) - ly0) / (ly1 - ly0) * (bottom - top)

    for v in log_ticks(10**ly0, 10**ly1):
        yy = float(py(v))
        draw.line((left + S, yy, right - S, yy), fill=_GRID, width=S)
        lab = _label(v)
        w = draw.textlength(lab, font=_font(9))
        draw.text((left - 5 * S - w, yy - 6 * S), lab, fill=_TEXT, font=_font(9))
    for v in nice_ticks(x0, x1):
        xx = float(px(v))
        draw.line((xx, top + S, xx, bottom - S), fill=_GRID, width=S)
        lab = _label(v)
        w = draw.textlength(lab, font=_font(9))
        draw.text((xx - w / 2, bottom + 3 * S), lab, fill=_TEXT, font=_font(9))
    colors = iter(_COLORS * 4)
    legend = []
    drawn = []
    for name, (x, y, thick) in kept.items():
        color = (0, 0, 0) if thick else next(colors)
        pts = list(zip(px(x).tolist(), py(y).tolist(), strict=True))
        drawn.append(_densify(px(x), py(y)))
        lw = (3 if thick else 2) * S
        if len(pts) > 1:
            draw.line(pts, fill=color, width=lw, joint="curve")
        if len(pts) < 12:
            for cx, cy in pts:
                r = 2.5 * S
                draw.ellipse((cx - r, cy - r, cx + r, cy + r), fill=color)
        legend.append((name, color, lw))
    _legend(draw, legend, (left, top, right, bottom), np.concatenate(drawn))
    return _halve(img)


def _densify(x: np.ndarray, y: np.ndarray, step: float = 4.0 * _SS) -> np.ndarray:
    """(N, 2) points along the polyline through ``(x, y)``, at most ``step`` pixels apart.

    A segment of length ``L`` gets ``n = max(1, int(L / step))`` points at ``t = k / n``,
    ``k = 1..n``, after the first point; all segments' points in one array operation.
    """
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    dx, dy = x[1:] - x[:-1], y[1:] - y[:-1]
    lengths = map(math.hypot, dx.tolist(), dy.tolist())  # the same float as hypot of scalars
    n = np.array([max(1, int(d / step)) for d in lengths], np.int64)
    seg = np.repeat(np.arange(len(n)), n)
    k = np.arange(1, len(seg) + 1) - np.repeat(np.cumsum(n) - n, n)  # 1..n in each segment
    t = k / n[seg]
    px = np.concatenate([x[:1], x[:-1][seg] + t * dx[seg]])
    py = np.concatenate([y[:1], y[:-1][seg] + t * dy[seg]])
    return np.stack([px, py], axis=1)


def _legend(draw, items: Sequence[tuple[str, tuple, int]], box, points: np.ndarray) -> None:
    """The legend in the corner of the plot area that hides the fewest curve points (upper
    right, upper left, lower left, lower right on ties)."""
    S = _SS
    font = _font(9)
    row = 13 * S
    left, top, right, bottom = box
    w = max(draw.textlength(name, font=font) for name, _, _ in items) + 30 * S
    h = row * len(items) + 4 * S
    corners = [
        (right - w - 6 * S, top + 6 * S),
        (left + 6 * S, top + 6 * S),
        (left + 6 * S, bottom - h - 6 * S),
        (right - w - 6 * S, bottom - h - 6 * S),
    ]

    def hidden(corner):
        cx, cy = corner
        inside = (points[:, 0] >= cx) & (points[:, 0] <= cx + w)
        return int((inside & (points[:, 1] >= cy) & (points[:, 1] <= cy + h)).sum())

    x0, y0 = min(corners, key=hidden)  # min keeps the first of equal corners
    draw.rectangle((x0, y0, x0 + w, y0 + h), fill=(255, 255, 255),
                   outline=(200, 200, 200), width=S)  # fmt: skip
    for k, (name, color, lw) in enumerate(items):
        y = y0 + 2 * S + k * row + row / 2
        draw.line((x0 + 5 * S, y, x0 + 22 * S, y), fill=color, width=lw)
        draw.text((x0 + 26 * S, y - 6 * S), name, fill=_TEXT, font=font)


def _halve(img) -> np.ndarray:
    from PIL import Image

    w, h = img.size
    return np.asarray(img.resize((w // _SS, h // _SS), Image.Resampling.BOX))
