"""Compiled (numba) CPU kernels: culled soft silhouette (forward, analytic backward), z-buffer.

Soft silhouette: same mathematics as the PyTorch kernel in :mod:`easyhoi.render.soft`, but
the (pixel, face) pairs are never materialised: every face walks the pixels of its grown
bounding box, and a pixel whose centre is farther than ``margin`` outside the triangle is
skipped before any transcendental function (its term is below ``cull_eps`` like every pair
outside the box). The backward pass recomputes each pair instead of saving it, so memory is
``O(pixels + faces)``.

The kernels are serial on purpose: the optimizer runs one torch thread, and numba's parallel
thread pool kept spinning after each call and slowed the surrounding torch operations several
times over on a 2-core machine (measured: projection 30x slower). Serial loops are also
deterministic (fixed summation order).

Arithmetic is done in float64 whatever the input dtype (the inputs are rounded once on output).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _edge(px, py, sx, sy, dx, dy, inv_len2):
    """Closest point of edge ``s -> s + d`` to ``p``: ``(d2, rx, ry, t, cross)``."""
    wx = px - sx
    wy = py - sy
    t = min(max((wx * dx + wy * dy) * inv_len2, 0.0), 1.0)
    rx = wx - t * dx
    ry = wy - t * dy
    return rx * rx + ry * ry, rx, ry, t, dx * wy - dy * wx


@numba.njit(cache=True, inline="always")
def _closest(px, py, geo):
    """Signed distance data of pixel ``p`` to a triangle ``geo`` (from :func:`_face`).

    Returns ``(inside, d2, rx, ry, t, e)``: the closest boundary point is on edge ``e`` (corner
    ``e`` to corner ``(e + 1) % 3``) at ``q = (1 - t) start + t end``; ``r = p - q``,
    ``d2 = |r|^2``.
    Written with selects rather than branches (the closest edge is unpredictable).
    """
    ax, ay, bx, by, cx, cy, d0x, d0y, d1x, d1y, d2x, d2y, i0, i1, i2 = geo
    e0, x0, y0, t0, k0 = _edge(px, py, ax, ay, d0x, d0y, i0)
    e1, x1, y1, t1, k1 = _edge(px, py, bx, by, d1x, d1y, i1)
    e2, x2, y2, t2, k2 = _edge(px, py, cx, cy, d2x, d2y, i2)
    c1 = e1 < e0
    d2 = e1 if c1 else e0
    rx = x1 if c1 else x0
    ry = y1 if c1 else y0
    t = t1 if c1 else t0
    e = 1 if c1 else 0
    c2 = e2 < d2
    d2 = e2 if c2 else d2
    rx = x2 if c2 else rx
    ry = y2 if c2 else ry
    t = t2 if c2 else t
    e = 2 if c2 else e
    inside = (k0 >= 0 and k1 >= 0 and k2 >= 0) or (k0 <= 0 and k1 <= 0 and k2 <= 0)
    return inside, d2, rx, ry, t, e


@numba.njit(cache=True, inline="always")
def _log1p_exp_neg(y):
    """``log(1 + exp(-y))`` for ``y >= 0``; a 3-term series below 1e-3 (error < 1e-13)."""
    z = math.exp(-y)
    if z < 1e-3:
        return z * (1.0 - z * (0.5 - z * (1.0 / 3.0)))
    return math.log1p(z)


@numba.njit(cache=True, inline="always")
def _face(tri, f, height, width, margin):
    """Corners, edge vectors, inverse squared edge lengths and the grown pixel box of face f."""
    ax, ay = np.float64(tri[f, 0]), np.float64(tri[f, 1])
    bx, by = np.float64(tri[f, 2]), np.float64(tri[f, 3])
    cx, cy = np.float64(tri[f, 4]), np.float64(tri[f, 5])
    d0x, d0y, d1x, d1y, d2x, d2y = bx - ax, by - ay, cx - bx, cy - by, ax - cx, ay - cy
    i0 = 1.0 / max(d0x * d0x + d0y * d0y, 1e-30)
    i1 = 1.0 / max(d1x * d1x + d1y * d1y, 1e-30)
    i2 = 1.0 / max(d2x * d2x + d2y * d2y, 1e-30)
    # clamp in floating point first: a far-away corner must not overflow the int cast
    c0 = int(min(max(math.ceil(min(ax, bx, cx) - margin - 0.5), 0.0), float(width)))
    c1 = int(max(min(math.floor(max(ax, bx, cx) + margin - 0.5), width - 1.0), -1.0))
    r0 = int(min(max(math.ceil(min(ay, by, cy) - margin - 0.5), 0.0), float(height)))
    r1 = int(max(min(math.floor(max(ay, by, cy) + margin - 0.5), height - 1.0), -1.0))
    geo = (ax, ay, bx, by, cx, cy, d0x, d0y, d1x, d1y, d2x, d2y, i0, i1, i2)
    return geo, c0, c1, r0, r1


@numba.njit(cache=True)
def soft_logsum_forward(tri, base, height, width, inv_sigma, margin, num_pix, out):
    """``out[pix] = sum_T log(1 - D_T)`` over culled pairs.

    Args:
        tri: (N, 6) corners ``ax ay bx by cx cy`` (pixels) of the kept faces.
        base: (N,) int64 pixel offset of each face's image (``b * H * W`` in a batch).
        height, width: image size.
        inv_sigma: 1 / sigma (px^-2).
        margin: culling distance (px); pixels farther outside a face are skipped.
        num_pix: length of ``out``.
        out: (num_pix,) output array (overwritten).
    """
    acc = np.zeros(num_pix)
    far2 = margin * margin
    for f in range(tri.shape[0]):
        geo, c0, c1, r0, r1 = _face(tri, f, height, width, margin)
        for row in range(r0, r1 + 1):
            py = row + 0.5
            off = base[f] + row * width
            for col in range(c0, c1 + 1):
                inside, d2, rx, ry, t, e = _closest(col + 0.5, py, geo)
                # log(1 - sigmoid(x)) = -softplus(x), x = +-d2 / sigma
                if inside:
                    x = d2 * inv_sigma
                    acc[off + col] -= x + _log1p_exp_neg(x)
                elif d2 <= far2:
                    acc[off + col] -= _log1p_exp_neg(d2 * inv_sigma)
    for i in range(num_pix):
        out[i] = acc[i]


@numba.njit(cache=True)
def soft_logsum_backward(tri, base, height, width, inv_sigma, margin, grad_out, grad):
    """Gradient of ``sum(grad_out * out)`` w.r.t. the corners, written to ``grad`` (N, 6).

    ``d log(1 - D) / d start = coef (1 - t) r`` and ``d / d end = coef t r`` for the closest edge
    (envelope theorem), ``coef = 2 sgn sigmoid(x) / sigma``.
    """
    far2 = margin * margin
    for f in range(tri.shape[0]):
        geo, c0, c1, r0, r1 = _face(tri, f, height, width, margin)
        g = np.zeros(6)
        for row in range(r0, r1 + 1):
            py = row + 0.5
            off = base[f] + row * width
            for col in range(c0, c1 + 1):
                go = grad_out[off + col]
                if go == 0.0:
                    continue
                inside, d2, rx, ry, t, e = _closest(col + 0.5, py, geo)
                if inside:
                    s = go * 2.0 * inv_sigma / (1.0 + math.exp(-d2 * inv_sigma))
                elif d2 <= far2:
                    z = math.exp(-d2 * inv_sigma)
                    s = -go * 2.0 * inv_sigma * z / (1.0 + z)
                else:
                    continue
                e1 = e + 1 if e < 2 else 0
                g[2 * e] += s * (1.0 - t) * rx
                g[2 * e + 1] += s * (1.0 - t) * ry
                g[2 * e1] += s * t * rx
                g[2 * e1 + 1] += s * t * ry
        for j in range(6):
            grad[f, j] = g[j]


@numba.njit(cache=True)
def zbuffer(tri, tri_z, height, width, out):
    """Nearest camera z per pixel (``out`` (H * W,), pre-filled with ``inf``), no gradients.

    Same rules as :func:`easyhoi.render.raster.rasterize`: pixel centres, bounding-box
    candidates, exact inside test with the top-left rule on the counter-clockwise-oriented
    triangle, degenerate triangles never hit, perspective-correct depth
    ``1 / sum_i (l_i / z_i)`` with screen barycentrics ``l``.

    Args:
        tri: (N, 6) corners ``ax ay bx by cx cy`` in pixels.
        tri_z: (N, 3) camera z of the corners.
    """
    for f in range(tri.shape[0]):
        ax, ay, bx, by, cx, cy = tri[f, 0], tri[f, 1], tri[f, 2], tri[f, 3], tri[f, 4], tri[f, 5]
        e0x, e0y = bx - ax, by - ay
        e1x, e1y = cx - bx, cy - by
        e2x, e2y = ax - cx, ay - cy
        area2 = e0x * (-e2y) - e0y * (-e2x)
        if area2 == 0:
            continue
        sg = -1.0 if area2 < 0 else 1.0
        tl0 = sg * e0y > 0 or (sg * e0y == 0 and sg * e0x < 0)
        tl1 = sg * e1y > 0 or (sg * e1y == 0 and sg * e1x < 0)
        tl2 = sg * e2y > 0 or (sg * e2y == 0 and sg * e2x < 0)
        iz0, iz1, iz2 = 1.0 / tri_z[f, 0], 1.0 / tri_z[f, 1], 1.0 / tri_z[f, 2]
        _, c0, c1, r0, r1 = _face(tri, f, height, width, 0.0)
        for row in range(r0, r1 + 1):
            py = row + 0.5
            for col in range(c0, c1 + 1):
                px = col + 0.5
                w0 = e0x * (py - ay) - e0y * (px - ax)
                w1 = e1x * (py - by) - e1y * (px - bx)
                w2 = e2x * (py - cy) - e2y * (px - cx)
                o0, o1, o2 = sg * w0, sg * w1, sg * w2
                if not (o0 > 0 or (o0 == 0 and tl0)):
                    continue
                if not (o1 > 0 or (o1 == 0 and tl1)):
                    continue
                if not (o2 > 0 or (o2 == 0 and tl2)):
                    continue
                # screen barycentrics: corner a <- w1, b <- w2, c <- w0
                q = (w1 * iz0 + w2 * iz1 + w0 * iz2) / area2
                d = 1.0 / q
                k = row * width + col
                if d < out[k]:
                    out[k] = d


@numba.njit(cache=True)
def _row_min(z, radius, out):
    """``out[i, j] = min z[i, j-r..j+r]`` (clipped at the borders)."""
    height, width = z.shape
    for i in range(height):
        for j in range(width):
            m = np.inf
            for d in range(max(j - radius, 0), min(j + radius + 1, width)):
                m = min(m, z[i, d])
            out[i, j] = m


@numba.njit(cache=True)
def min_filter(z, radius, out):
    """``out[i, j] = min z[i-r..i+r, j-r..j+r]`` (clipped at the borders), separable, (H, W)."""
    tmp = np.empty(z.shape)
    _row_min(z, radius, tmp)
    _row_min(tmp.T, radius, out.T)  # the column pass is a row pass on the transposes


def pair_count(tri: np.ndarray, height: int, width: int, margin: float) -> int:
    """Number of (pixel, face) pairs in the grown boxes (for benchmarks and docs)."""
    if tri.shape[0] == 0:
        return 0
    u = tri[:, 0::2]
    v = tri[:, 1::2]
    c0 = np.clip(np.ceil(u.min(1) - margin - 0.5), 0, None)
    c1 = np.clip(np.floor(u.max(1) + margin - 0.5), None, width - 1)
    r0 = np.clip(np.ceil(v.min(1) - margin - 0.5), 0, None)
    r1 = np.clip(np.floor(v.max(1) + margin - 0.5), None, height - 1)
    return int((np.clip(c1 - c0 + 1, 0, None) * np.clip(r1 - r0 + 1, 0, None)).sum())
