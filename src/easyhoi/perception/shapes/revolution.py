"""Surface of revolution: bottles, cans, cups, balls seen from the side.

The symmetry axis of a mirror-symmetric outline is one of its two principal (PCA) axes, so both
are tried. The radius ``r(s)`` along the axis is half the chord of the mask on the line
perpendicular to the axis at ``s`` (integral of the bilinearly interpolated mask), and the
profile is revolved into rings capped by flat disks. The depth follows from the outline (round
cross-sections), so the family has a rigid depth. Evidence besides the silhouette IoU: the
reflection IoU (the outline is mirror-symmetric about the axis), recorded as
``reflection_iou``; the selector uses ``min(reflection IoU, profile IoU)``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    principal_axes,
    rasterize,
)


def reflect_mask(mask: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The mask reflected about the line through ``c`` with unit direction ``a``."""
    H, W = mask.shape
    v, u = np.mgrid[0:H, 0:W] + 0.5
    p = np.stack([u - c[0], v - c[1]], axis=-1)
    refl = 2 * (p @ a)[..., None] * a - p + c  # reflection is its own inverse
    cu = np.floor(refl[..., 0]).astype(int)
    rv = np.floor(refl[..., 1]).astype(int)
    ok = (cu >= 0) & (cu < W) & (rv >= 0) & (rv < H)
    out = np.zeros_like(mask)
    out[ok] = mask[rv[ok], cu[ok]]
    return out


def profile(mask: np.ndarray, c: np.ndarray, a: np.ndarray, n_samples: int):
    """Chord half-lengths ``r(s)`` on lines perpendicular to ``a`` through the mask.

    Returns ``s`` (K,), ``r`` (K,) and the normal ``n`` (2,).
    """
    n = np.array([-a[1], a[0]])
    rows, cols = np.nonzero(mask)
    pts = np.stack([cols + 0.5, rows + 0.5], axis=1) - c
    s_all = pts @ a
    half = 0.5 * (abs(a[0]) + abs(a[1]))  # half pixel footprint along the axis
    s_lo, s_hi = s_all.min() - half, s_all.max() + half
    t_max = np.abs(pts @ n).max() + 2.0
    s = np.linspace(s_lo, s_hi, n_samples)
    dt = 0.25
    t = np.arange(-t_max, t_max + dt, dt)
    P = c + s[:, None, None] * a + t[None, :, None] * n  # (S, T, 2) in (u, v)
    coords = np.stack([P[..., 1] - 0.5, P[..., 0] - 0.5])
    vals = ndimage.map_coordinates(mask.astype(np.float64), coords, order=1, mode="constant")
    r = 0.5 * vals.sum(axis=1) * dt
    # the end samples sit on the outer pixel edge: use the nearest interior chord there
    r[0] = max(r[0], r[1])
    r[-1] = max(r[-1], r[-2])
    return s, r, n


def revolution_mesh(c, a, s, r, n_segments: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of the profile ``r(s)`` revolved about the axis through ``c``.

    Args:
        c: (2,) axis point (u, v). a : (2,) unit axis direction. s, r : (K,) profile samples.

    Returns:
        verts: (K * n_segments + 2, 3) float, faces : (2 * n_segments * K, 3) int, outward.
    """
    a = np.asarray(a, dtype=np.float64)
    n = np.array([-a[1], a[0]])
    K, M = len(s), n_segments
    th = 2 * np.pi * np.arange(M) / M
    ring_uv = c + s[:, None, None] * a + (r[:, None] * np.cos(th))[..., None] * n  # (K, M, 2)
    ring_z = r[:, None] * np.sin(th)
    verts = np.concatenate([ring_uv, ring_z[..., None]], axis=-1).reshape(-1, 3)
    ends = np.array([[*(c + s[0] * a), 0.0], [*(c + s[-1] * a), 0.0]])
    verts = np.concatenate([verts, ends])
    idx = np.arange(K * M).reshape(K, M)
    i0, i1 = idx[:-1], idx[1:]
    j0, j1 = i0, np.roll(i0, -1, axis=1)
    k0, k1 = i1, np.roll(i1, -1, axis=1)
    quads = np.concatenate(
        [np.stack([j0, k0, j1], -1).reshape(-1, 3), np.stack([j1, k0, k1], -1).reshape(-1, 3)]
    )
    first, last = K * M, K * M + 1
    cap0 = np.stack([np.full(M, first), idx[0], np.roll(idx[0], -1)], -1)
    cap1 = np.stack([np.full(M, last), np.roll(idx[-1], -1), idx[-1]], -1)
    return verts, np.concatenate([quads, cap0, cap1]).astype(np.int64)


def symmetry(mask: np.ndarray, n_rings: int = 64) -> dict:
    """Best revolution axis of ``mask``: ``score`` = min(reflection IoU, profile IoU), ...

    Ties within 0.02 go to the major axis (a bottle revolves about its length).
    """
    c, axes = principal_axes(mask)
    best = None
    for a in axes:
        refl = _iou(mask, reflect_mask(mask, c, a))
        s, r, n = profile(mask, c, a, n_rings)
        prof = _iou(mask, profile_mask(mask.shape, c, a, n, s, r))
        cand = dict(score=min(refl, prof), reflection_iou=refl, profile_iou=prof, center=c,
                    axis=a, s=s, r=r)  # fmt: skip
        if best is None or cand["score"] > best["score"] + 0.02:
            best = cand
    return best


def profile_mask(shape, c, a, n, s, r) -> np.ndarray:
    """Region covered by the revolved profile seen from the front: ``|t| <= r(s)``."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W] + 0.5
    p = np.stack([u - c[0], v - c[1]], axis=-1)
    ps, pt = p @ a, p @ n
    inside = (ps >= s[0]) & (ps <= s[-1])
    return inside & (np.abs(pt) <= np.interp(ps, s, r))


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 0.0


def fit(wf: WorkFrame, n_rings: int = 48, n_segments: int = 40) -> Hypothesis:
    """The surface-of-revolution hypothesis of the working frame's mask."""
    sym = symmetry(wf.mask, n_rings)
    verts, faces = revolution_mesh(sym["center"], sym["axis"], sym["s"], sym["r"], n_segments)
    iou = fit_iou(rasterize(verts[:, :2], faces, wf.mask.shape), wf)
    info = dict(reflection_iou=round(sym["reflection_iou"], 4),
                profile_iou=round(sym["profile_iou"], 4),
                axis=[round(float(x), 6) for x in sym["axis"]])  # fmt: skip
    return Hypothesis("revolution", verts, faces, min(iou, sym["reflection_iou"]), True, info=info)
