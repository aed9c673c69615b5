"""Compiled (numba) part of :func:`easyhoi.viz.shade.corner_normals`: the crease-aware sums.

For every corner (face ``g``, slot ``k``, vertex ``v``) the kernel adds the cross products of
the faces around ``v`` whose unit normal is within the crease angle of ``g``'s, in increasing
face order, from 0.0: the additions ``np.bincount`` makes over the NumPy path's (corner,
neighbour) pairs, in the same order, and each dot product as NumPy's ``(a * b).sum(1)`` adds
three products (no fused multiply-adds: numba's default). The NumPy path materialises about 18
pairs per corner (70,000 for a hand) in arrays; the kernel walks them without storing them.
Serial and deterministic; compiled once and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def corner_sums(faces, n_vertices, cross, unit, cos_crease):
    """(3F, 3) float64: per corner, the sum of the neighbouring faces' ``cross`` rows whose
    ``unit`` normal has a dot product >= ``cos_crease`` with the corner's own face's."""
    n_faces = faces.shape[0]
    n_corners = 3 * n_faces
    starts = np.zeros(n_vertices + 1, np.int64)
    for c in range(n_corners):
        starts[faces[c // 3, c % 3] + 1] += 1
    for v in range(n_vertices):
        starts[v + 1] += starts[v]
    fill = starts[:-1].copy()
    around = np.empty(n_corners, np.int64)  # faces around each vertex, in corner order
    for c in range(n_corners):
        v = faces[c // 3, c % 3]
        around[fill[v]] = c // 3
        fill[v] += 1
    acc = np.zeros((n_corners, 3))
    for c in range(n_corners):
        g = c // 3
        v = faces[g, c % 3]
        for i in range(starts[v], starts[v + 1]):
            h = around[i]
            dot = unit[g, 0] * unit[h, 0] + unit[g, 1] * unit[h, 1] + unit[g, 2] * unit[h, 2]
            if dot >= cos_crease:
                acc[c, 0] += cross[h, 0]
                acc[c, 1] += cross[h, 1]
                acc[c, 2] += cross[h, 2]
    return acc
