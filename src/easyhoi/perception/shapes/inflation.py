"""Inflation (the fallback) and the height-field solids it shares with the slab.

A height field over the mask, mirrored front and back and closed at the contour. With ``d`` the
distance to the contour and ``R`` the local half-width (radius of the largest inscribed disk
containing the pixel, smoothed), the half-thickness is ``h = sqrt(d (2R - d))``: a circular
cross-section, so a disk inflates to a sphere and a bar to a tube. The closed surface is the
zero level set of ``h^2 - (z - c)^2`` (``c`` = mid-surface) extracted by marching cubes. The
outline is reproduced exactly whatever its shape, which is why inflation is the fallback: it
explains any outline and so is chosen only when no family with fewer parameters fits.

The hypothesis is then flattened about its mid-surface to :data:`DEPTH_RATIO` of that round
depth (an elliptical cross-section). The outline says nothing about the depth, and the round
one is the largest an object of that outline is likely to have: the objects people hold in
one hand are mostly flatter along the view than across it (phones, remotes, boxes, tubes of
paste, soap, tools) and seldom deeper (a mug seen from its side). A mildly flatter default is
closer on average; docs/object_shape.md gives the measurements.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes.common import Hypothesis, WorkFrame, fit_iou, rasterize
from easyhoi.perception.shapes.common import signed_distance_2d as signed_distance_2d

#: Depth of the inflation along the view as a share of the round cross-section's (module docs).
DEPTH_RATIO = 0.85


def local_thickness(mask: np.ndarray, d: np.ndarray, levels: int = 48) -> np.ndarray:
    """(H, W) radius of the largest inscribed disk containing each pixel (pixels).

    ``R(p) = max { d(q) : |p - q| <= d(q) }`` over interior points ``q`` (``d`` = distance to
    the contour), evaluated on ``levels`` radii: ``p`` has ``R >= r`` when it lies within
    ``r + 1`` (one pixel of rasterisation slack) of the set ``{d >= r}``. Robust to contour
    noise (no medial-axis spurs). Pixels outside the mask take the nearest inside pixel's value.
    """
    dmax = float(d[mask].max())
    R = np.zeros(mask.shape)
    for r in np.linspace(0.5, dmax, levels):
        core = d >= r - 1e-9
        if not core.any():
            continue
        reach = ndimage.distance_transform_edt(~core) <= r + 1.0
        R[reach & mask] = r
    _, (ri, ci) = ndimage.distance_transform_edt(~mask, return_indices=True)
    return np.maximum(R[ri, ci], 0.5)


def half_thickness_sq(mask: np.ndarray, smooth: float = 1.5) -> np.ndarray:
    """(H, W) ``h^2 = d (2R - d)`` (pixels^2): positive inside, negative outside, 0 on the contour.

    ``d`` is :func:`signed_distance_2d`; ``R`` the :func:`local_thickness` (Gaussian-smoothed
    by ``smooth`` pixels).
    """
    d = signed_distance_2d(mask)
    R = local_thickness(mask, d)
    if smooth > 0:
        R = ndimage.gaussian_filter(R, smooth)
    dc = np.minimum(d, R)
    return dc * (2 * R - dc)


def implicit_slab_mesh(
    mask: np.ndarray,
    h2: np.ndarray,
    mid: np.ndarray | None = None,
    max_faces: int = 8000,
    resolution: int = 48,
) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface ``{ (u, v, z) : h2(u, v) = (z - mid(u, v))^2 }`` by marching cubes.

    Args:
        mask: (H, W) bool, the silhouette (sets the grid's extent).
        h2: (H, W) float squared half-thickness (negative outside the mask), pixels^2.
        mid: (H, W) float mid-surface depth in pixels (z away from the camera), or None for 0.
        max_faces: the grid is coarsened until the mesh has at most this many faces.
        resolution: grid cells across the mask's larger side at the first attempt. The depth step
            is at most a sixth of the largest thickness, so thin slabs keep their faces.

    Returns:
        verts: (V, 3) float (u, v, z) pixel units, faces : (F, 3) int.
    """
    from skimage.measure import marching_cubes

    rows, cols = np.nonzero(mask)
    lo = np.array([cols.min(), rows.min()], dtype=np.float64)
    hi = np.array([cols.max() + 1, rows.max() + 1], dtype=np.float64)
    mid = np.zeros_like(h2) if mid is None else mid
    h_in = np.sqrt(np.maximum(h2[mask], 0))
    zlo, zhi = float((mid[mask] - h_in).min()), float((mid[mask] + h_in).max())
    step = float((hi - lo).max()) / resolution
    zstep = min(step, max(2 * float(h_in.max()), 1e-3) / 6)
    for _ in range(6):
        pad, zpad = 2 * step, 2 * zstep
        gu = np.arange(lo[0] - pad, hi[0] + pad + step, step)
        gv = np.arange(lo[1] - pad, hi[1] + pad + step, step)
        gz = np.arange(zlo - zpad, zhi + zpad + zstep, zstep)
        V, U = np.meshgrid(gv - 0.5, gu - 0.5, indexing="ij")
        coords = np.stack([V, U])
        h2g = ndimage.map_coordinates(h2, coords, order=1, mode="nearest").T  # (U, V)
        midg = ndimage.map_coordinates(mid, coords, order=1, mode="nearest").T
        vol = h2g[..., None] - (gz[None, None, :] - midg[..., None]) ** 2
        vol[[0, -1]] = vol[:, [0, -1]] = vol[:, :, [0, -1]] = -1.0  # closed at the border
        verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(step, step, zstep))
        if len(faces) <= max_faces:
            break
        f = float(np.sqrt(len(faces) / max_faces)) * 1.05
        step, zstep = step * f, zstep * f
    verts = verts + np.array([gu[0], gv[0], gz[0]])
    return verts, faces.astype(np.int64)


def fit(wf: WorkFrame, max_faces: int = 6000) -> Hypothesis:
    """The inflation hypothesis of the working frame's mask: round cross-sections flattened to
    :data:`DEPTH_RATIO` about the mid-surface (z = 0)."""
    verts, faces = implicit_slab_mesh(wf.mask, half_thickness_sq(wf.mask), max_faces=max_faces)
    verts[:, 2] *= DEPTH_RATIO
    iou = fit_iou(rasterize(verts[:, :2], faces, wf.mask.shape), wf)
    return Hypothesis("inflation", verts, faces, iou, False, info={})
