"""Superquadric (ellipsoid family): balls, fruit, computer mice, bars of soap.

The outline is a superellipse ``|x / a|^p + |y / b|^p = 1`` in the mask's principal frame
(``p = 2``: ellipse; larger ``p``: squarer, rounded corners); the solid extends it in depth
with an elliptic profile, ``(|x / a|^p + |y / b|^p)^(2 / p) + (z / c)^2 = 1``. The principal
axes of the mask give the frame, the mask's extent along them gives ``a : b``, and the area
fixes the size (area of a superellipse: ``4 a b Gamma(1 + 1/p)^2 / Gamma(1 + 2/p)``). The
exponent is the one of ``EXPONENTS`` whose outline fits best. Depth: ``c = b`` (round, as
balls and fruit are) unless the grasp gives the thickness.
"""

from __future__ import annotations

from math import gamma

import numpy as np
import trimesh

from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    pixel_centres,
    principal_axes,
    rasterize,
)

#: Outline exponents tried (2 = ellipse).
EXPONENTS = (2.0, 2.5, 3.5, 5.0)


def superquadric_mesh(center, axes, a, b, c, p, subdivisions: int = 3):
    """Vertices (u, v, z) and faces of the superquadric (module docs) about ``center``.

    ``axes`` (2, 2): rows are the in-plane unit axes of ``a`` and ``b``. A unit icosphere is
    mapped radially onto the surface, so the mesh is closed and star-shaped.
    """
    sph = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sph.vertices)
    g = (np.abs(d[:, 0] / a) ** p + np.abs(d[:, 1] / b) ** p) ** (2.0 / p) + (d[:, 2] / c) ** 2
    r = g ** (-0.5)
    local = d * r[:, None]
    uv = center + local[:, :1] * axes[0] + local[:, 1:2] * axes[1]
    return np.concatenate([uv, local[:, 2:]], axis=1), np.asarray(sph.faces, np.int64)


def fit(wf: WorkFrame) -> Hypothesis:
    """The best-fitting superquadric of the working frame's mask (``c = b``)."""
    m = wf.mask
    c0, axes = principal_axes(m)
    pts = pixel_centres(m, c0)
    x, y = pts @ axes[0], pts @ axes[1]
    (x0, x1), (y0, y1) = np.percentile(x, [0.5, 99.5]), np.percentile(y, [0.5, 99.5])
    center = c0 + 0.5 * (x0 + x1) * axes[0] + 0.5 * (y0 + y1) * axes[1]
    a0, b0 = 0.5 * (x1 - x0) + 0.5, 0.5 * (y1 - y0) + 0.5
    area = float(m.sum())
    best = None
    for p in EXPONENTS:
        k = np.sqrt(area / (4 * a0 * b0 * gamma(1 + 1 / p) ** 2 / gamma(1 + 2 / p)))
        a, b = a0 * k, b0 * k
        verts, faces = superquadric_mesh(center, axes, a, b, b, p)
        iou = fit_iou(rasterize(verts[:, :2], faces, m.shape), wf)
        if best is None or iou > best[0] + 1e-3:
            best = (iou, verts, faces, dict(exponent=p, semi_axes=[round(float(a), 3),
                    round(float(b), 3)]))  # fmt: skip
    iou, verts, faces, info = best
    return Hypothesis("superquadric", verts, faces, iou, False, info=info)
