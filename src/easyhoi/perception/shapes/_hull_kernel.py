"""Compiled (numba) kernel of the cuboid fit's objective: the weights inside a convex hull.

:func:`hull_weight_sums` finds the same pixels as
:func:`easyhoi.perception.shapes.cuboid._hull_pixels` with the same floating-point operations:
the same pixel box, the same orientation (the shoelace sum in NumPy's order of additions) and,
per tested pixel, every hull edge's cross product in float64 (no fused multiply-adds: numba's
default, no fast-math flag). Two things make it cheap:

* In a row, each edge's cross product is a monotone function of the column (a rounded
  subtraction or product by a constant is monotone), so each edge passes on a prefix or a
  suffix of the row and the inside pixels are one run. The kernel finds the run's two ends by
  walking from the previous row's ends (a few tests per row) instead of testing every pixel.
* The weights are given as integers (the weight maps times 4, whose sums are exact) in
  row-wise prefix sums, so a run's sum is one subtraction.

Serial and deterministic; compiled once and cached on disk (``cache=True``) like the
renderer's kernels.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _shoelace(px, py):
    """``np.sum(px * roll(py, -1) - roll(px, -1) * py)`` with NumPy's order of additions.

    NumPy adds fewer than eight values from left to right and eight as
    ``((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7))`` (its pairwise sum); the hull of a
    box's 8 corners has at most 8 vertices.
    """
    n = px.shape[0]
    t = np.empty(n)
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        t[i] = px[i] * py[j] - px[j] * py[i]
    if n == 8:
        return ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]))
    s = t[0]
    for i in range(1, n):
        s += t[i]
    return s


@numba.njit(cache=True)
def _span(lo, hi, size):
    """Pixel indices ``[first, stop)`` whose centre (index + 0.5) lies in ``[lo, hi]``, clipped
    to ``[0, size)`` (``first >= stop`` when none); clamped in floating point first, so a
    far-away hull does not overflow the integer cast."""
    first = min(max(np.ceil(lo - 0.5), 0.0), float(size))
    stop = max(min(np.floor(hi - 0.5) + 1.0, float(size)), 0.0)
    return int(first), int(stop)


@numba.njit(cache=True, inline="always")
def _inside(u, row_term, dy, px):
    """Whether the pixel centre at column ``u`` of a row passes every edge's test;
    ``row_term[i]`` is edge ``i``'s ``(q0 - p0) (v - p1)`` on that row."""
    for i in range(px.shape[0]):
        if not (row_term[i] - dy[i] * (u - px[i]) >= 0):
            return False
    return True


@numba.njit(cache=True)
def _run_start(first, c0, c1, row_term, dy, px):
    """First inside column of a row whose inside columns are one run in ``[c0, c1)``, found
    from ``first`` (the previous row's); ``c1`` when the row has none."""
    if _inside(first + 0.5, row_term, dy, px):
        while first > c0 and _inside(first - 0.5, row_term, dy, px):
            first -= 1
        return first
    for c in range(first + 1, c1):  # the run starts right of `first`...
        if _inside(c + 0.5, row_term, dy, px):
            return c
    for c in range(c0, first):  # ...or lies wholly left of it
        if _inside(c + 0.5, row_term, dy, px):
            return c
    return c1


@numba.njit(cache=True)
def _run_end(last, first, c1, row_term, dy, px):
    """Last inside column of a row's run that starts at ``first``, found from ``last``."""
    last = max(last, first)
    if _inside(last + 0.5, row_term, dy, px):
        while last < c1 - 1 and _inside(last + 1.5, row_term, dy, px):
            last += 1
        return last
    while not _inside(last - 0.5, row_term, dy, px):  # `first` is inside: this stops
        last -= 1
    return last - 1


@numba.njit(cache=True)
def hull_weight_sums(hull, sums_a, sums_b):
    """``(A, B, ok)``: two integer weight maps summed over the pixels inside the convex ``hull``.

    ``hull`` is (n, 2) float32 ``(u, v)`` vertices in order (``cv2.convexHull``); a pixel
    (centre ``(u, v)`` = index + 0.5) in the hull's bounding box is inside when, for every edge
    ``p -> q``, ``s ((q0 - p0) (v - p1) - (q1 - p1) (u - p0)) >= 0``, ``s`` the sign of the
    hull's orientation (+1 when the shoelace sum is ``>= 0``; folded into the edge vectors,
    an exact negation). ``sums_a``, ``sums_b``: (H, W + 1) row-wise prefix sums of the maps
    (:func:`easyhoi.perception.shapes.cuboid.row_prefix_sums`). ``ok`` is False (and the sums
    0) when a vertex is not finite.
    """
    n = hull.shape[0]
    height, width = sums_a.shape[0], sums_a.shape[1] - 1
    px = np.empty(n)
    py = np.empty(n)
    for i in range(n):
        px[i] = hull[i, 0]
        py[i] = hull[i, 1]
        if not (np.isfinite(px[i]) and np.isfinite(py[i])):
            return 0, 0, False
    r0, r1 = _span(py.min(), py.max(), height)
    c0, c1 = _span(px.min(), px.max(), width)
    total_a = 0
    total_b = 0
    if r0 >= r1 or c0 >= c1:
        return total_a, total_b, True
    sign = 1.0 if _shoelace(px, py) >= 0 else -1.0
    dx = np.empty(n)
    dy = np.empty(n)
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        dx[i] = sign * (px[j] - px[i])
        dy[i] = sign * (py[j] - py[i])
    row_term = np.empty(n)
    first, last = c0, c0
    for r in range(r0, r1):
        v = r + 0.5
        for i in range(n):
            row_term[i] = dx[i] * (v - py[i])
        start = _run_start(first, c0, c1, row_term, dy, px)
        if start == c1:
            continue
        first = start
        last = _run_end(last, first, c1, row_term, dy, px)
        total_a += sums_a[r, last + 1] - sums_a[r, first]
        total_b += sums_b[r, last + 1] - sums_b[r, first]
    return total_a, total_b, True
