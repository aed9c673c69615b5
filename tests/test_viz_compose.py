"""Figures composed with Pillow: panels pasted pixel for pixel, downscaled by area averaging."""

from __future__ import annotations

import numpy as np
import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.viz.compose import Panel, compose_grid, fit_width


def _find(canvas: np.ndarray, pic: np.ndarray) -> list[tuple[int, int]]:
    """Every (row, col) where ``pic`` appears exactly in ``canvas``."""
    h, w = pic.shape[:2]
    H, W = canvas.shape[:2]
    hits = []
    for y in range(H - h + 1):
        rows = np.flatnonzero((canvas[y, : W - w + 1] == pic[0, 0]).all(-1))
        hits += [(y, int(x)) for x in rows if (canvas[y : y + h, x : x + w] == pic).all()]
    return hits


def test_panels_are_pasted_unchanged_in_reading_order():
    rng = np.random.default_rng(0)
    pics = [rng.integers(0, 256, (30, 40, 3), dtype=np.uint8) for _ in range(5)]
    fig = compose_grid([Panel(p, f"p{i}") for i, p in enumerate(pics)], 3, 40, title="t",
                       legend=[("a", (255, 0, 0))])  # fmt: skip
    where = [_find(fig, p) for p in pics]
    assert all(len(w) == 1 for w in where)
    (r0, c0), (r1, c1), (r2, c2), (r3, c3) = (w[0] for w in where[:4])
    assert r0 == r1 == r2 < r3 and c0 < c1 < c2 and c3 == c0  # three per row, left to right
    assert fig.shape[1] == 3 * 40 + 4 * 10
    # the legend's colour square is drawn below the panels
    red = np.argwhere((fig == (255, 0, 0)).all(-1))
    assert len(red) > 0 and red[:, 0].min() > r3 + 30


def test_fit_width_is_an_area_average():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    small = fit_width(a, 30)  # a factor of two: each output pixel is a 2 x 2 block mean
    ref = a.reshape(20, 2, 30, 2, 3).astype(float).mean(axis=(1, 3))
    assert small.shape == (20, 30, 3)
    assert np.abs(small - ref).max() <= 0.5 + 1e-9
    mask = np.zeros((4, 6), bool)
    mask[1, 2] = True
    m = fit_width(mask, 10)  # narrower than the slot: kept as it is
    assert m.shape == (4, 6, 3) and m[1, 2].tolist() == [255] * 3 and m.sum() == 3 * 255
    with pytest.raises(InvalidInputError):
        fit_width(np.zeros((4, 6, 2), np.uint8), 3)


def test_a_narrow_picture_is_centred_in_its_slot():
    pic = np.full((8, 10, 3), 200, np.uint8)
    pic[0, 0] = (1, 2, 3)
    fig = compose_grid([Panel(pic)], 1, 30)
    ((y, x),) = _find(fig, pic)
    assert x == 10 + (30 - 10) // 2  # margin, then half the slot's spare width


def test_same_bytes_every_time():
    pics = [Panel(np.full((10, 10, 3), 7 * i, np.uint8), f"panel {i}\nline") for i in range(3)]
    a = compose_grid(pics, 2, 20, title="x")
    b = compose_grid(pics, 2, 20, title="x")
    assert a.dtype == np.uint8 and np.array_equal(a, b)
    with pytest.raises(InvalidInputError):
        compose_grid([], 2, 20)
