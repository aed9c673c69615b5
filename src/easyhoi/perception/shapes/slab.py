"""Slab with rounded edges: phones, books, boards, plates, remote controls.

The outline is the observed (amodal) outline, the thickness ``t`` is constant and the rim is a
half-round of radius ``t / 2``: with ``d`` the distance to the contour, the half-thickness is
``h = sqrt(dc (t - dc))``, ``dc = min(d, t / 2)``. Flat objects are held face-on to the camera
far more often than edge-on (a phone is looked at, a book is read), so the slab's faces are
parallel to the image. ``t`` is not visible in the outline: it comes from the grasp aperture
when the hand pinches the slab front to back, else from a prior ratio to the slab's width.
"""

from __future__ import annotations

import numpy as np

from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    rasterize,
    signed_distance_2d,
)
from easyhoi.perception.shapes.inflation import implicit_slab_mesh

#: Thickness prior without a depth cue, as a fraction of the largest inscribed diameter.
PRIOR_THICKNESS_RATIO = 0.3


def slab_h2(mask: np.ndarray, thickness: float) -> np.ndarray:
    """(H, W) squared half-thickness of a rounded slab of ``thickness`` pixels over ``mask``."""
    d = signed_distance_2d(mask)
    rho = 0.5 * float(thickness)
    dc = np.minimum(d, rho)
    return dc * (2 * rho - dc)


def fit(
    wf: WorkFrame,
    thickness: float | None = None,
    min_thickness: float | None = None,
    max_faces: int = 6000,
) -> Hypothesis:
    """The slab hypothesis; ``thickness`` in working pixels (None: the prior, at least
    ``min_thickness``)."""
    width = 2 * float(signed_distance_2d(wf.mask).max())
    t = PRIOR_THICKNESS_RATIO * width if thickness is None else float(thickness)
    if thickness is None and min_thickness is not None:
        t = max(t, float(min_thickness))
    t = float(np.clip(t, 1.0, width))
    verts, faces = implicit_slab_mesh(wf.mask, slab_h2(wf.mask, t), max_faces=max_faces)
    iou = fit_iou(rasterize(verts[:, :2], faces, wf.mask.shape), wf)
    info = dict(thickness_ratio=round(t / width, 4), thickness_from="cue" if thickness else "prior")
    return Hypothesis("slab", verts, faces, iou, False, info=info)
