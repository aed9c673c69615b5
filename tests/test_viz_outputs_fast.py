"""The cheaper formulations of the result pictures equal the plain ones they replace."""

from __future__ import annotations

import numpy as np

from easyhoi.viz.shade import _blend


def test_blend_on_covered_pixels_equals_the_whole_picture_formula():
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    hit = rng.random((37, 53)) < 0.4
    shade = rng.uniform(-20.0, 280.0, (int(hit.sum()), 3))  # out of range on purpose: clipped
    for alpha in (0.0, 0.3, 0.65, 1.0):
        out = bg.astype(np.float64)  # the whole picture in float64, then the uncovered restored
        out[hit] = (1.0 - alpha) * out[hit] + alpha * shade
        ref = np.clip(np.rint(out), 0, 255).astype(np.uint8)
        ref[~hit] = bg[~hit]
        got = bg.copy()
        _blend(got.reshape(-1, 3), np.flatnonzero(hit), shade, alpha)
        np.testing.assert_array_equal(got, ref)
