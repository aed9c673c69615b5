"""Figures made of pictures, composed directly with Pillow: a grid of titled panels.

The figures of overlays, views and masks are pictures side by side with a title over each and
a colour legend under them. Drawing them through matplotlib costs an axes per panel (ticks,
spines, layout) and a resampling pass per picture, several times the cost of the pictures
themselves; here every panel is pasted at its final pixel size (downscaled by area averaging
when larger) and the texts are drawn with Pillow's built-in scalable font, so the same
inputs give the same bytes at every run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from easyhoi.errors import InvalidInputError

__all__ = ["Panel", "compose_grid", "fit_width"]

#: Pixel sizes of the figure title, the panel titles and the legend's labels.
TITLE_PX = 17
PANEL_TITLE_PX = 13
LEGEND_PX = 13
_MARGIN = 10  # outer margin and gap between panels
_LINE_GAP = 3
_TEXT = (20, 20, 20)
_FRAME = (200, 200, 200)


@dataclass(frozen=True)
class Panel:
    """One picture of a figure.

    Attributes:
        image: (H, W, 3) uint8 picture, or an (H, W) bool mask (drawn white on black).
        title: Text above it; ``\\n`` separates lines.
    """

    image: np.ndarray
    title: str = ""


@lru_cache(maxsize=8)
def _font(size: int):
    from PIL import ImageFont

    return ImageFont.load_default(size)


def fit_width(image: np.ndarray, width: int) -> np.ndarray:
    """``image`` as (h, w, 3) uint8 at most ``width`` wide: area-averaged down, aspect kept.

    A narrower picture keeps its size (enlarging adds no detail); a bool mask becomes white on
    black. A one-channel picture is scaled before its channel is repeated (area averaging
    treats the channels alike: a third of the work for the same pixels).
    """
    import cv2

    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3) or a.dtype != np.uint8:
        raise InvalidInputError(f"panel must be (H, W, 3) uint8 or (H, W) bool, got {a.shape}")
    H, W = a.shape[:2]
    if W > width:
        h = max(1, round(H * width / W))
        a = cv2.resize(a, (int(width), h), interpolation=cv2.INTER_AREA)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return a


def _line_height(size: int) -> int:
    return size + _LINE_GAP


def _text_width(draw, text: str, size: int) -> float:
    return draw.textlength(text, font=_font(size))


def _centered_lines(draw, text: str, cx: float, top: int, size: int) -> None:
    for k, line in enumerate(text.split("\n") if text else []):
        x = cx - _text_width(draw, line, size) / 2
        draw.text((round(x), top + k * _line_height(size)), line, fill=_TEXT, font=_font(size))


def compose_grid(
    panels: Sequence[Panel],
    cols: int,
    panel_width: int,
    title: str = "",
    legend: Sequence[tuple[str, tuple[int, int, int]]] = (),
    background=(255, 255, 255),
) -> np.ndarray:
    """Panels in rows of ``cols``, each in a slot ``panel_width`` pixels wide, with a legend.

    Wider pictures are downscaled to the slot's width (:func:`fit_width`), narrower ones
    centred in it.

    Every row is as tall as its tallest panel and its panel titles; the figure's title is
    centred above, the legend (a colour square and a label per entry) centred below.

    Returns:
        (H, W, 3) uint8
    """
    from PIL import Image, ImageDraw

    if not panels or cols < 1:
        raise InvalidInputError("a figure needs at least one panel and one column")
    pics = [fit_width(p.image, panel_width) for p in panels]
    cols = min(cols, len(panels))
    rows = [list(range(i, min(i + cols, len(panels)))) for i in range(0, len(panels), cols)]
    title_h = len(title.split("\n")) * _line_height(TITLE_PX) + _MARGIN if title else 0
    row_heights = []
    for r in rows:
        lines = max(len(panels[i].title.split("\n")) if panels[i].title else 0 for i in r)
        row_heights.append((lines * _line_height(PANEL_TITLE_PX), max(pics[i].shape[0] for i in r)))
    legend_h = _line_height(LEGEND_PX) + _MARGIN if legend else 0
    W = cols * panel_width + (cols + 1) * _MARGIN
    H = _MARGIN + title_h + sum(t + p + _MARGIN for t, p in row_heights) + legend_h
    canvas = Image.new("RGB", (W, H), tuple(int(c) for c in background))
    draw = ImageDraw.Draw(canvas)
    if title:
        _centered_lines(draw, title, W / 2, _MARGIN, TITLE_PX)
    y = _MARGIN + title_h
    for r, (text_h, pic_h) in zip(rows, row_heights, strict=True):
        for k, i in enumerate(r):
            x = _MARGIN + k * (panel_width + _MARGIN)
            _centered_lines(draw, panels[i].title, x + panel_width / 2, y, PANEL_TITLE_PX)
            pic = pics[i]
            h, w = pic.shape[:2]
            px = x + (panel_width - w) // 2  # a narrower picture is centred in its slot
            canvas.paste(Image.fromarray(pic), (px, y + text_h))
            draw.rectangle((px - 1, y + text_h - 1, px + w, y + text_h + h), outline=_FRAME)
        y += text_h + pic_h + _MARGIN
    if legend:
        _legend(draw, legend, W, y)
    return np.asarray(canvas)


def _legend(draw, legend, width: int, top: int) -> None:
    box = LEGEND_PX - 2
    items = [(label, tuple(int(c) for c in color)) for label, color in legend]
    widths = [box + 6 + _text_width(draw, label, LEGEND_PX) for label, _ in items]
    gap = 24
    x = (width - sum(widths) - gap * (len(items) - 1)) / 2
    for (label, color), w in zip(items, widths, strict=True):
        x0 = round(x)
        draw.rectangle((x0, top + 2, x0 + box, top + 2 + box), fill=color)
        draw.text((x0 + box + 6, top), label, fill=_TEXT, font=_font(LEGEND_PX))
        x += w + gap
