"""Log-scale line charts drawn with Pillow: ticks against a naive enumeration, curve placement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from easyhoi.viz.chart import Series, log_chart, log_ticks, nice_ticks


@pytest.mark.parametrize("lo,hi", [(0.0, 126.0), (3.0, 17.0), (0.0, 1.0), (-5.0, 5.0)])
def test_nice_ticks_are_evenly_spaced_round_numbers_covering_the_range(lo, hi):
    t = nice_ticks(lo, hi)
    step = t[1] - t[0]
    mant = step / 10 ** math.floor(math.log10(step))
    assert min(abs(mant - m) for m in (1, 2, 5, 10)) < 1e-9
    assert np.allclose(np.diff(t), step)
    assert lo - 1e-9 <= t[0] < lo + step and hi - step < t[-1] <= hi + 1e-9
    assert 3 <= len(t) <= 8


@pytest.mark.parametrize("lo,hi", [(0.05, 0.21), (1e-7, 10.0), (2e-4, 0.3), (0.9, 1.1)])
def test_log_ticks_match_a_naive_enumeration(lo, hi):
    narrow = hi / lo < 10**1.5
    subs = (1, 2, 5) if narrow else (1,)
    naive = sorted(
        s * 10.0**k
        for k in range(-12, 12)
        for s in subs
        if lo * (1 - 1e-9) <= s * 10.0**k <= hi * (1 + 1e-9)
    )
    while len(naive) > 12:
        naive = naive[::2]
    assert np.allclose(log_ticks(lo, hi), naive, rtol=1e-12)


def test_curves_land_where_the_log_axis_puts_them():
    x = np.arange(50, dtype=float)
    flat = Series(x, np.full(50, 1e-2), thick=True)  # a thick black line at one level
    falling = Series(x, 10.0 ** (-x / 10))  # five decades
    img = log_chart({"total": flat, "other": falling}, 400, 300, "t", "iteration")
    assert img.shape == (300, 400, 3) and img.dtype == np.uint8
    black = img.astype(int).sum(axis=2) < 120
    rows = np.flatnonzero(black[:, 100:300].sum(axis=1) > 150)  # the flat line spans the plot
    assert len(rows) >= 1 and np.ptp(rows) <= 4
    # 1e-2 lies 2/5 of the way from 1 (the top curve's start) to 1e-5 (roughly its end),
    # inside the plot area (between the title and the x labels)
    top, bottom = 30, 300 - 34
    frac = (rows.mean() - top) / (bottom - top)
    assert 0.3 < frac < 0.5


def test_empty_chart_and_same_bytes():
    a = log_chart({"a": Series(np.arange(3.0), np.array([-1.0, 0.0, np.nan]))}, 200, 150)
    assert a.shape == (150, 200, 3)
    s = {"a": Series(np.arange(5.0), np.arange(1.0, 6.0))}
    assert np.array_equal(log_chart(s, 200, 150, "x"), log_chart(s, 200, 150, "x"))
