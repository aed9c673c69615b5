"""Generalised cylinder along a curved axis: pens, markers, tools, bananas, handles.

The axis is the longest path through the mask's skeleton (the medial axis of an elongated
outline), smoothed and extended at both ends to the outline along its end tangents (a skeleton
stops one radius short of a round tip). The radius ``r(s)`` is the distance to the contour
along the axis (smoothed); circles of radius ``r(s)`` perpendicular to the axis, in the plane
spanned by the in-image normal and the view direction, are swept along it and capped. The
axis lies in a plane parallel to the image — elongated held objects are mostly seen side-on,
their long side being what a photographer frames — and the cross-sections are round, so the
depth follows from the outline.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    rasterize,
    signed_distance_2d,
)


def _longest_path(skel: np.ndarray) -> np.ndarray:
    """(K, 2) (row, col) pixels of the longest shortest-path in an 8-connected skeleton."""
    pix = np.argwhere(skel)
    index = {tuple(p): i for i, p in enumerate(pix)}
    nbrs = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]

    def bfs(start):
        dist = np.full(len(pix), -1)
        prev = np.full(len(pix), -1)
        dist[start] = 0
        q = deque([start])
        while q:
            i = q.popleft()
            r, c = pix[i]
            for dr, dc in nbrs:
                j = index.get((r + dr, c + dc))
                if j is not None and dist[j] < 0:
                    dist[j], prev[j] = dist[i] + 1, i
                    q.append(j)
        return dist, prev

    d0, _ = bfs(0)
    a = int(np.argmax(d0))
    d1, prev = bfs(a)
    b = int(np.argmax(d1))
    path = [b]
    while path[-1] != a:
        path.append(int(prev[path[-1]]))
    return pix[path]


def tube_mesh(axis: np.ndarray, radius: np.ndarray, n_segments: int = 24):
    """Vertices (u, v, z) and faces of circles of ``radius`` (K,) swept along ``axis`` (K, 2)."""
    K, M = len(axis), n_segments
    tang = np.gradient(axis, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True).clip(1e-9)
    nrm = np.stack([-tang[:, 1], tang[:, 0]], axis=1)
    th = 2 * np.pi * np.arange(M) / M
    ring_uv = axis[:, None, :] + (radius[:, None] * np.cos(th))[..., None] * nrm[:, None, :]
    ring_z = radius[:, None] * np.sin(th)
    verts = np.concatenate([ring_uv, ring_z[..., None]], axis=-1).reshape(-1, 3)
    verts = np.concatenate([verts, [[*axis[0], 0.0], [*axis[-1], 0.0]]])
    idx = np.arange(K * M).reshape(K, M)
    i0, i1 = idx[:-1], idx[1:]
    j1, k1 = np.roll(i0, -1, axis=1), np.roll(i1, -1, axis=1)
    quads = np.concatenate([np.stack([i0, i1, j1], -1).reshape(-1, 3),
                            np.stack([j1, i1, k1], -1).reshape(-1, 3)])  # fmt: skip
    cap0 = np.stack([np.full(M, K * M), idx[0], np.roll(idx[0], -1)], -1)
    cap1 = np.stack([np.full(M, K * M + 1), np.roll(idx[-1], -1), idx[-1]], -1)
    return verts, np.concatenate([quads, cap0, cap1]).astype(np.int64)


def fit(wf: WorkFrame, n_samples: int = 40) -> Hypothesis | None:
    """The generalised-cylinder hypothesis, or None when the mask has no usable skeleton."""
    from skimage.morphology import skeletonize

    m = wf.mask
    smooth = ndimage.binary_opening(m, iterations=1) if m.sum() > 200 else m
    skel = skeletonize(smooth if smooth.any() else m)
    if skel.sum() < 3:
        return None
    path = _longest_path(skel)[:, ::-1].astype(np.float64) + 0.5  # (u, v) pixel centres
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    if s[-1] < 2:
        return None
    t = np.linspace(0, s[-1], n_samples)
    axis = np.stack([np.interp(t, s, path[:, 0]), np.interp(t, s, path[:, 1])], axis=1)
    axis = ndimage.gaussian_filter1d(axis, 1.5, axis=0, mode="nearest")
    d = signed_distance_2d(m)
    coords = np.stack([axis[:, 1] - 0.5, axis[:, 0] - 0.5])
    r = ndimage.map_coordinates(d, coords, order=1, mode="nearest") + 0.5
    r = ndimage.gaussian_filter1d(np.maximum(r, 0.5), 1.0, mode="nearest")
    # extend both ends to the outline along the end tangents
    ext = []
    for end, prev, rad in ((axis[0], axis[min(3, len(axis) - 1)], r[0]),
                           (axis[-1], axis[max(-4, -len(axis))], r[-1])):  # fmt: skip
        dirn = end - prev
        dirn = dirn / max(np.linalg.norm(dirn), 1e-9)
        steps = np.arange(0.5, 3 * rad + 2, 0.5)
        pts = end + steps[:, None] * dirn
        vals = ndimage.map_coordinates(d, np.stack([pts[:, 1] - 0.5, pts[:, 0] - 0.5]),
                                       order=1, mode="constant", cval=-1.0)  # fmt: skip
        out = np.nonzero(vals <= 0)[0]
        L = steps[out[0]] if len(out) else steps[-1]
        ext.append(end + L * dirn)
    k = max(2, n_samples // 10)
    head = ext[0] + (axis[0] - ext[0]) * np.linspace(0, 1, k + 1)[:-1, None]
    tail = axis[-1] + (ext[1] - axis[-1]) * np.linspace(0, 1, k + 1)[1:, None]
    axis = np.concatenate([head, axis, tail])
    # radii shrink as a round cap over the extension: r = r_end * sqrt(1 - (x / L)^2)
    xh = np.linspace(1, 0, k + 1)[:-1]
    xt = np.linspace(0, 1, k + 1)[1:]
    r = np.concatenate([r[0] * np.sqrt(np.clip(1 - xh**2, 0.05, 1)), r,
                        r[-1] * np.sqrt(np.clip(1 - xt**2, 0.05, 1))])  # fmt: skip
    verts, faces = tube_mesh(axis, r)
    iou = fit_iou(rasterize(verts[:, :2], faces, m.shape), wf)
    chord = np.linalg.norm(axis[-1] - axis[0])
    info = dict(length=round(float(s[-1]), 2), straightness=round(float(chord / max(
        np.linalg.norm(np.diff(axis, axis=0), axis=1).sum(), 1e-9)), 4))  # fmt: skip
    return Hypothesis("tube", verts, faces, iou, True, info=info)
