"""Compiled (numba) CPU kernels: culled soft silhouette (forward, analytic backward), z-buffer
(depth, and optionally the nearest face's index, of every pixel).

Soft silhouette: same mathematics as the PyTorch kernel in :mod:`easyhoi.render.soft`, but
the (pixel, face) pairs are never materialised: every face walks the pixels of its grown
bounding box, and a pixel whose centre is farther than ``margin`` outside the triangle adds
nothing (its term is below ``cull_eps`` like every pair outside the box). The backward pass
recomputes each pair instead of saving it, so memory is ``O(pixels + faces)``.

The soft-silhouette loops are written for SIMD: a box row is processed in blocks of
``_LANES`` columns with a constant trip count and a branch-free body (selects, lane masks
that make the lanes past the box contribute exactly 0), and ``exp`` / ``log1p`` are
polynomials (llvmlite has no vector libm, and a libm call keeps a loop scalar). LLVM compiles
a block into 512-bit (AVX-512) or 256-bit vector instructions, whichever the CPU has.

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
from numba.extending import intrinsic

#: Pixels per block of the soft-silhouette loops: one 256-bit register of float64. The
#: block loops have this constant trip count, so LLVM turns a block into vector instructions.
#: Four, not eight: at the optimizer's sharpness a face's grown box is 4-5 columns wide, so
#: blocks of eight left about half of their lanes empty (on the faces of a reconstruction the
#: forward took 0.051 s instead of 0.077 s and the backward 0.061 s instead of 0.104 s, the
#: same values; at sigma 1, boxes about 10 columns wide, 0.231 / 0.261 s against 0.241 / 0.415 s).
_LANES = 4
#: Compiler options of the vectorized kernels: ``error_model="numpy"`` removes the
#: division-by-zero check (a branch per division, which stops vectorization; the divisors are
#: never zero); ``contract`` allows fused multiply-adds. No other fast-math flag: the results
#: do not depend on reassociation and are the same at every call.
_VEC = {"error_model": "numpy", "fastmath": {"contract"}}
_LN2 = math.log(2.0)
_SQRT2_M1 = math.sqrt(2.0) - 1.0


@intrinsic
def _select(typingctx, cond, a, b):
    """``a if cond else b`` as one LLVM ``select`` instruction.

    A Python conditional expression compiles to a branch; LLVM folds a branch back into selects
    only when few values depend on it, so the closest-edge choice (five values) would stay a
    branch and the block loop would not vectorize.
    """
    if a != b:
        return None

    def codegen(context, builder, signature, args):
        return builder.select(*args)

    return a(numba.types.boolean, a, b), codegen


@numba.njit(cache=True, inline="always", **_VEC)
def _exp_neg(y):
    """``exp(-y)`` for ``y >= 0`` without libm (a libm call cannot be vectorized).

    ``y`` is clamped to 40 (``exp(-40) = 4e-18``: below every use), ``u = y / 256 <= 0.157``,
    ``exp(-u)`` by its degree-10 Taylor polynomial (truncation ``u^11 / 11! < 4e-17``), then
    squared 8 times. Relative error < 1e-13 (tested against ``math.exp``).
    """
    u = min(y, 40.0) * (1.0 / 256.0)
    p = 1.0 / 3628800.0
    p = 1.0 / 362880.0 - u * p
    p = 1.0 / 40320.0 - u * p
    p = 1.0 / 5040.0 - u * p
    p = 1.0 / 720.0 - u * p
    p = 1.0 / 120.0 - u * p
    p = 1.0 / 24.0 - u * p
    p = 1.0 / 6.0 - u * p
    p = 0.5 - u * p
    p = 1.0 - u * p
    p = 1.0 - u * p
    for _ in range(8):
        p = p * p
    return p


@numba.njit(cache=True, inline="always", **_VEC)
def _log1p_unit(z):
    """``log(1 + z)`` for ``0 <= z <= 1`` without libm: ``2 atanh(s)`` with ``s = z / (2 + z)``.

    Above ``sqrt(2) - 1``, ``log(1 + z) = log(2) + log((1 + z) / 2)`` with ``s = (z - 1) / (z + 3)``
    instead, so ``|s| <= 0.172`` and the odd series ``s + s^3/3 + ... + s^19/19`` truncates below
    ``2e-17`` relative. Relative error < 1e-15 (tested against ``math.log1p``).
    """
    big = z > _SQRT2_M1
    s = _select(big, z - 1.0, z) / _select(big, z + 3.0, z + 2.0)
    s2 = s * s
    q = 1.0 / 19.0
    q = 1.0 / 17.0 + s2 * q
    q = 1.0 / 15.0 + s2 * q
    q = 1.0 / 13.0 + s2 * q
    q = 1.0 / 11.0 + s2 * q
    q = 1.0 / 9.0 + s2 * q
    q = 1.0 / 7.0 + s2 * q
    q = 1.0 / 5.0 + s2 * q
    q = 1.0 / 3.0 + s2 * q
    q = 1.0 + s2 * q
    return _select(big, _LN2, 0.0) + 2.0 * s * q


@numba.njit(cache=True, inline="always", **_VEC)
def _lane(px, py, geo):
    """Signed distance data of pixel centre ``p`` to a triangle ``geo`` (from :func:`_face`).

    Returns ``(inside, d2, rx, ry, t, on1, on2)``: the closest boundary point is on edge ``e``
    (corner ``e`` to corner ``(e + 1) % 3``) at ``q = (1 - t) start + t end``; ``r = p - q``,
    ``d2 = |r|^2``; ``e`` is 2 if ``on2``, else 1 if ``on1``, else 0 (ties to the lower edge).
    Branch-free (selects only).
    """
    ax, ay, bx, by, cx, cy, d0x, d0y, d1x, d1y, d2x, d2y, i0, i1, i2 = geo
    wx, wy = px - ax, py - ay
    t0 = min(max((wx * d0x + wy * d0y) * i0, 0.0), 1.0)
    x0, y0 = wx - t0 * d0x, wy - t0 * d0y
    k0 = d0x * wy - d0y * wx
    wx, wy = px - bx, py - by
    t1 = min(max((wx * d1x + wy * d1y) * i1, 0.0), 1.0)
    x1, y1 = wx - t1 * d1x, wy - t1 * d1y
    k1 = d1x * wy - d1y * wx
    wx, wy = px - cx, py - cy
    t2 = min(max((wx * d2x + wy * d2y) * i2, 0.0), 1.0)
    x2, y2 = wx - t2 * d2x, wy - t2 * d2y
    k2 = d2x * wy - d2y * wx
    e0, e1, e2 = x0 * x0 + y0 * y0, x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
    on1 = e1 < e0
    d2 = _select(on1, e1, e0)
    rx, ry, t = _select(on1, x1, x0), _select(on1, y1, y0), _select(on1, t1, t0)
    on2 = e2 < d2
    d2 = _select(on2, e2, d2)
    rx, ry, t = _select(on2, x2, rx), _select(on2, y2, ry), _select(on2, t2, t)
    inside = ((k0 >= 0.0) & (k1 >= 0.0) & (k2 >= 0.0)) | ((k0 <= 0.0) & (k1 <= 0.0) & (k2 <= 0.0))
    return inside, d2, rx, ry, t, on1, on2


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


@numba.njit(cache=True, **_VEC)
def soft_logsum_forward(tri, base, height, width, inv_sigma, margin, num_pix, out):
    """``out[pix] = sum_T log(1 - D_T)`` over culled pairs.

    Every face walks the rows of its grown box in blocks of ``_LANES`` columns (one vector
    each); lanes past the box's last column, and pixels farther than ``margin`` outside the
    triangle, add exactly 0 (the accumulator is padded so the last block of a row may spill).

    Args:
        tri: (N, 6) corners ``ax ay bx by cx cy`` (pixels) of the kept faces.
        base: (N,) int64 pixel offset of each face's image (``b * H * W`` in a batch).
        height, width: image size.
        inv_sigma: 1 / sigma (px^-2).
        margin: culling distance (px); pixels farther outside a face add nothing.
        num_pix: length of ``out``.
        out: (num_pix,) output array (overwritten).
    """
    acc = np.zeros(num_pix + _LANES)
    far2 = margin * margin
    for f in range(tri.shape[0]):
        geo, c0, c1, r0, r1 = _face(tri, f, height, width, margin)
        for row in range(r0, r1 + 1):
            py = row + 0.5
            off = base[f] + row * width
            for cb in range(c0, c1 + 1, _LANES):
                o = off + cb
                for k in range(_LANES):
                    col = cb + k
                    inside, d2, _, _, _, _, _ = _lane(col + 0.5, py, geo)
                    # log(1 - sigmoid(x)) = -softplus(x), x = +-d2 / sigma
                    x = d2 * inv_sigma
                    sp = _log1p_unit(_exp_neg(x))
                    v = _select(inside, x + sp, _select(d2 <= far2, sp, 0.0))
                    # unsigned index: no negative-index wraparound select (o >= 0)
                    acc[np.uint64(o + k)] -= _select(col <= c1, v, 0.0)
    for i in range(num_pix):
        out[i] = acc[i]


@numba.njit(cache=True, **_VEC)
def soft_logsum_backward(tri, base, height, width, inv_sigma, margin, grad_out, grad):
    """Gradient of ``sum(grad_out * out)`` w.r.t. the corners, written to ``grad`` (N, 6).

    ``d log(1 - D) / d start = coef (1 - t) r`` and ``d / d end = coef t r`` for the closest edge
    (envelope theorem), ``coef = 2 sgn sigmoid(x) / sigma``. Same blocks as the forward; each
    lane accumulates the six corner gradients of its face separately and the lanes are summed
    once per face, in a fixed order.
    """
    far2 = margin * margin
    two = 2.0 * inv_sigma
    num_pix = grad_out.shape[0]
    go = np.zeros(num_pix + _LANES)  # padded: the last block of a row may read past the end
    for i in range(num_pix):
        go[i] = grad_out[i]
    # acc[j * _LANES + lane]: the six corner gradients; acc[6 * _LANES + lane]: the block's
    # grad_out. One array at constant offsets, so LLVM needs no aliasing checks (reading
    # grad_out from its own array inside the block loop made it give up vectorizing).
    acc = np.empty(7 * _LANES)
    for f in range(tri.shape[0]):
        geo, c0, c1, r0, r1 = _face(tri, f, height, width, margin)
        acc[: 6 * _LANES] = 0.0
        for row in range(r0, r1 + 1):
            py = row + 0.5
            off = base[f] + row * width
            for cb in range(c0, c1 + 1, _LANES):
                o = off + cb
                for k in range(_LANES):
                    acc[6 * _LANES + k] = go[o + k]
                for k in range(_LANES):
                    col = cb + k
                    inside, d2, rx, ry, t, on1, on2 = _lane(col + 0.5, py, geo)
                    z = _exp_neg(d2 * inv_sigma)
                    # inside: sigmoid(x) = 1 / (1 + z); outside: -sigmoid(-x) = -z / (1 + z)
                    s = acc[6 * _LANES + k] * two * _select(inside, 1.0, -z) / (1.0 + z)
                    s = _select((inside | (d2 <= far2)) & (col <= c1), s, 0.0)
                    ws, we = s * (1.0 - t), s * t  # weights of the edge's start and end
                    on0 = not (on1 | on2)
                    on1 = on1 & (not on2)
                    # corner j starts edge j and ends edge j - 1
                    w0 = _select(on0, ws, 0.0) + _select(on2, we, 0.0)
                    w1 = _select(on1, ws, 0.0) + _select(on0, we, 0.0)
                    w2 = _select(on2, ws, 0.0) + _select(on1, we, 0.0)
                    acc[0 * _LANES + k] += w0 * rx
                    acc[1 * _LANES + k] += w0 * ry
                    acc[2 * _LANES + k] += w1 * rx
                    acc[3 * _LANES + k] += w1 * ry
                    acc[4 * _LANES + k] += w2 * rx
                    acc[5 * _LANES + k] += w2 * ry
        for j in range(6):
            g = 0.0
            for k in range(_LANES):
                g += acc[j * _LANES + k]
            grad[f, j] = g


@numba.njit(cache=True)
def zbuffer(tri, tri_z, height, width, out, ids=None):
    """Nearest camera z per pixel (``out`` (H * W,), pre-filled with ``inf``), no gradients.

    Same rules as :func:`easyhoi.render.raster.rasterize`: pixel centres, bounding-box
    candidates, exact inside test with the top-left rule on the counter-clockwise-oriented
    triangle, degenerate triangles never hit, perspective-correct depth
    ``1 / sum_i (l_i / z_i)`` with screen barycentrics ``l``. Of faces at exactly the same
    depth the first one (lowest index) is kept, as the stable sort of ``rasterize`` does.

    Args:
        tri: (N, 6) corners ``ax ay bx by cx cy`` in pixels.
        tri_z: (N, 3) camera z of the corners.
        ids: (H * W,) int64, pre-filled with -1, or None: receives the index (into ``tri``) of
            the nearest face. Without it the kernel is compiled without the id writes.
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
                    if ids is not None:
                        ids[k] = f


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
