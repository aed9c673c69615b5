"""Surface of revolution: bottles, cans, cups, balls seen from the side.

The symmetry axis of a mirror-symmetric outline is near one of its two principal (PCA) axes,
so both are tried, each also searched nearby for the axis about which the pixels seen on both
sides are most symmetric (:func:`symmetry`, :func:`mirror_axis`): where the hand hides one side
or the photo's edge cuts it, the principal axes lean towards the side that is seen. The radius
``r(s)`` along the axis is the mean of the mask's extents on the two sides of the axis on the
line perpendicular to it at ``s`` (integrals of the bilinearly interpolated mask), along the
searched axis the longer one where the shorter side ends on a hidden pixel, the pixel staircase
averaged out (:func:`profile`); of each principal axis and its searched neighbour the one with
the better evidence is kept, and the profile is revolved into rings capped by flat disks. The
depth follows from the outline (round cross-sections), so the family has a rigid depth.
Evidence besides the silhouette IoU: the reflection IoU (the outline is mirror-symmetric about
the axis, counted over every pixel inside the photo), recorded as ``reflection_iou``; the
selector uses ``min(reflection IoU, profile IoU)``.

Tilt. A can, a cup or a bottle tilted out of the image by ``t`` has a shorter outline, and its
flat end disk of radius ``r_e`` is seen as an ellipse with semi-axes ``r_e`` across the axis and
``r_e sin(t)`` along it: the outline's tips are those ellipses' outer halves, and the inner half
of the end facing the camera is a rim inside the outline, an image edge (the end face and the
side meet at a sharp edge and are lit differently). The outline alone cannot tell a tilted flat
end from a rounded one, so the rim decides: for each tilt in :data:`TILTS_DEG`, each end's
body stops ``r_e sin(t)`` inside the tip and the predicted rim's mean gradient over the object's
median gradient is measured (:func:`rim_support`; samples a few pixels inside the visible object
only, since the outline is an edge too). The tilt with the strongest rim, at least
:data:`RIM_MIN_RATIO`, is kept when its re-projected outline fits within
:data:`TILT_IOU_TOLERANCE` of the untilted one; the body is then revolved about the tilted axis
(its length ``(s1 - s0) / cos(t)``) with flat ends. Without an image or a rim, the axis lies in
the image plane. Open cups, handles and labels also draw edges inside the outline, so the cue
misfires on them (module ``fit`` records ``tilt_deg`` and ``rim_ratio``).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    pixel_centres,
    principal_axes,
    rasterize,
    weighted_iou,
)

#: Axis tilts out of the image tried (degrees); see module docs.
TILTS_DEG = (10, 15, 20, 25, 30, 35, 40, 45, 50, 55, 60, 65, 70)
#: A tilted fit is kept when its silhouette IoU is within this of the untilted one's.
TILT_IOU_TOLERANCE = 0.015
#: Rim evidence needed for a tilt: mean gradient on the rim over the object's median gradient.
RIM_MIN_RATIO = 3.0
#: Rim samples needed well inside the visible object.
RIM_MIN_SAMPLES = 6
#: Gradient floor (grey levels in [0, 1] per pixel, about the noise of a camera): a uniformly
#: coloured object's median gradient is noise, not a scale for its edges.
GRADIENT_FLOOR = 0.01
#: Turns of the symmetry axis tried around each principal axis (degrees; :func:`symmetry`).
AXIS_TURNS_DEG = (-15.0, -7.5, 0.0, 7.5, 15.0)
#: Shifts of the symmetry axis tried across each principal axis, as shares of the mask's
#: extent on the farther side of it (:func:`symmetry`).
AXIS_SHIFTS = (-0.25, -0.125, 0.0, 0.125, 0.25)
#: Share of the outline whose mirror image must lie inside the photo for the photo's edge to be
#: left out of the symmetry evidence (:func:`symmetry`, :func:`mirror_seen`): judged on less, a
#: rectangle cut by the edge is symmetric about any axis across the cut (a board or a box
#: running out of the photo: 0.57-0.66 of it mirrored inside; a bowl with a fifth of one side
#: cut: 0.93).
MIN_MIRROR_SEEN = 0.8
#: Rounds of the local search that refines the best grid axis (each halves both steps).
AXIS_REFINE_ROUNDS = 4
#: Smallest depth of a rim's ellipse along the axis (working pixels) that is told from the tip.
RIM_MIN_DEPTH = 4.0
#: Profile denoising (:func:`denoise_profile`): reach along the axis and the size of a radius
#: step that is still pixel quantisation, both in working pixels.
PROFILE_SMOOTH_S = 3.0
PROFILE_SMOOTH_R = 0.75


@functools.lru_cache(maxsize=4)
def _pixel_centres(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) centres of every pixel of a map of ``shape`` (read-only, shared)."""
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    u.setflags(write=False)
    v.setflags(write=False)
    return u, v


def _mirror_index(shape: tuple[int, int], c: np.ndarray, a: np.ndarray):
    """(rows, cols, ok) of every pixel's mirror image about the line through ``c`` along ``a``,
    as :func:`reflect_mask` samples them (``ok``: it lies on the map; off the map, the rows
    and columns are clamped to the nearest pixel on it)."""
    H, W = shape
    u, v = _pixel_centres((H, W))
    pu, pv = u - c[0], v - c[1]
    along = 2.0 * (pu * a[0] + pv * a[1])
    cu = np.floor(along * a[0] - pu + c[0]).astype(np.intp)
    rv = np.floor(along * a[1] - pv + c[1]).astype(np.intp)
    ok = (cu >= 0) & (cu < W) & (rv >= 0) & (rv < H)
    return np.clip(rv, 0, H - 1), np.clip(cu, 0, W - 1), ok


def reflect_mask(mask: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The mask (or any per-pixel map) reflected about the line through ``c`` with unit
    direction ``a``; pixels whose mirror image lies off the map get 0."""
    rows, cols, ok = _mirror_index(mask.shape, c, a)
    return np.where(ok, mask[rows, cols], 0).astype(mask.dtype)


def mirror_seen(mask: np.ndarray, weight: np.ndarray, c: np.ndarray, a: np.ndarray) -> float:
    """Share of ``mask``'s weight whose mirror image about the line through ``c`` along ``a``
    is known (weight of the pixel times that of its mirror image, off the map that of the
    nearest pixel on it as in :func:`reflection_iou`, over the weight of the pixel)."""
    rows, cols, _ = _mirror_index(mask.shape, c, a)
    w = weight[mask]
    total = float(w.sum())
    return float((w * weight[rows, cols][mask]).sum()) / total if total else 0.0


def reflection_iou(mask: np.ndarray, weight: np.ndarray, c: np.ndarray, a: np.ndarray) -> float:
    """How mirror-symmetric ``mask`` is about the line through ``c`` along ``a``: the IoU of the
    mask and its reflection (:func:`reflect_mask`), over the pixels known on both sides
    (``weight`` of the pixel times that of its mirror image; a mirror image off the map is
    empty, with the weight of the nearest pixel on it: beyond the working frame's margin lies
    what lies at its edge, the background seen or what is beyond the photo's edge). Where the
    hand or the photo's edge hides the outline on one side (weight 0), that side says nothing
    about the symmetry, and the other side's pixels mirrored there are not counted against it.
    With every weight 1 it is the plain IoU of the mask and :func:`reflect_mask`."""
    rows, cols, ok = _mirror_index(mask.shape, c, a)
    w = weight * weight[rows, cols]
    return weighted_iou(mask, mask[rows, cols] & ok, w)


def profile(mask: np.ndarray, c: np.ndarray, a: np.ndarray, n_samples: int, weight=None):
    """Radii ``r(s)`` on lines perpendicular to ``a`` through the mask.

    On each line the mask's extent on either side of the axis is measured (the integral of the
    bilinearly interpolated mask from the axis outwards); ``r`` is their mean, or the longer
    one where the shorter side ends on a pixel of zero ``weight`` (the hand or the photo's edge
    hides it there: occlusion only shortens an outline). Without ``weight`` it is half the chord.
    The radii are then cleared of the pixel staircase (:func:`denoise_profile`).

    Returns ``s`` (K,), ``r`` (K,) and the normal ``n`` (2,).
    """
    n = np.array([-a[1], a[0]])
    pts = pixel_centres(mask, c)
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
    on_axis = 0.5 * (t == 0)  # a sample on the axis counts half to each side
    r_plus = (vals * ((t > 0) + on_axis)).sum(axis=1) * dt
    r_minus = (vals * ((t < 0) + on_axis)).sum(axis=1) * dt
    r = 0.5 * (r_plus + r_minus)
    if weight is not None:
        H, W = mask.shape

        def hidden_beyond(side: np.ndarray, sign: float) -> np.ndarray:
            q = c + s[:, None] * a + sign * (side + 1.0)[:, None] * n
            iu = np.clip(np.floor(q[:, 0]).astype(int), -1, W)
            iv = np.clip(np.floor(q[:, 1]).astype(int), -1, H)
            off = (iu < 0) | (iu >= W) | (iv < 0) | (iv >= H)
            w = weight[np.clip(iv, 0, H - 1), np.clip(iu, 0, W - 1)]
            return off | (w <= 0)

        cut_plus = (r_plus < r_minus) & hidden_beyond(r_plus, 1.0)
        cut_minus = (r_minus < r_plus) & hidden_beyond(r_minus, -1.0)
        r = np.where(cut_plus | cut_minus, np.maximum(r_plus, r_minus), r)
    r[1:-1] = denoise_profile(s[1:-1], r[1:-1])
    # the end samples sit on the outer pixel edge: use the nearest interior chord there
    r[0] = max(r[0], r[1])
    r[-1] = max(r[-1], r[-2])
    return s, r, n


def denoise_profile(s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``r(s)`` with the working frame's pixel staircase averaged out, steps kept.

    A binary outline at the working frame's resolution whose edge runs at an angle to the pixel
    grid measures its chord in whole-pixel steps: a straight side gives radii that ripple by up
    to a pixel (1.5-2.5 % on a can about 30 px wide), and the revolved surface shows them as
    rings. A bilateral average (weights fall with the distance along the axis, scale
    :data:`PROFILE_SMOOTH_S`, and with the difference of the radii, scale
    :data:`PROFILE_SMOOTH_R`) averages the ripple along the side, while a step of several pixels
    (a bottle's shoulder, a lid) gets almost no weight from the other side of it and stays.
    """
    ds = (s[:, None] - s[None]) / PROFILE_SMOOTH_S
    dr = (r[:, None] - r[None]) / PROFILE_SMOOTH_R
    w = np.exp(-0.5 * (ds * ds + dr * dr))
    return (w @ r) / w.sum(axis=1)


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
    return verts, _ring_faces(K, M)


def mirror_axis(
    mask: np.ndarray, weight: np.ndarray, c0: np.ndarray, a0: np.ndarray, across: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """(reflection IoU, axis point, unit axis direction) of the most mirror-symmetric axis near
    the line through ``c0`` along ``a0``: turned by :data:`AXIS_TURNS_DEG` and shifted across
    by :data:`AXIS_SHIFTS` x ``across`` (the mask's extent across ``a0``), the best of that
    grid refined by :data:`AXIS_REFINE_ROUNDS` rounds of a pattern search whose steps halve
    each round."""
    n0 = np.array([-a0[1], a0[0]])

    def axis(deg: float, f: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.radians(deg)
        return c0 + f * across * n0, np.cos(t) * a0 + np.sin(t) * n0

    def mirror(deg: float, f: float) -> float:
        return reflection_iou(mask, weight, *axis(deg, f))

    refl, d, f = max(((mirror(d, f), d, f) for d in AXIS_TURNS_DEG for f in AXIS_SHIFTS),
                     key=lambda g: g[0])  # fmt: skip
    step_d, step_f = AXIS_TURNS_DEG[1] - AXIS_TURNS_DEG[0], AXIS_SHIFTS[1] - AXIS_SHIFTS[0]
    for _ in range(AXIS_REFINE_ROUNDS):
        step_d, step_f = 0.5 * step_d, 0.5 * step_f
        for dd, ff in ((step_d, 0.0), (-step_d, 0.0), (0.0, step_f), (0.0, -step_f)):
            r = mirror(d + dd, f + ff)
            if r > refl + 1e-9:
                refl, d, f = r, d + dd, f + ff
    return (refl, *axis(d, f))


def searched_axes(mask: np.ndarray, weight: np.ndarray | None = None) -> list[tuple]:
    """For each principal axis of ``mask`` (major first): ``(c0, a0, c, a)``, the principal axis
    (centroid, unit direction) and the most mirror-symmetric axis near it (:func:`mirror_axis`,
    weighed by ``weight``; None: every pixel counts)."""
    w = np.ones(mask.shape) if weight is None else weight
    c0, axes = principal_axes(mask)
    pts = pixel_centres(mask, c0)
    out = []
    for a0 in axes:
        n0 = np.array([-a0[1], a0[0]])
        _, c, a = mirror_axis(mask, w, c0, a0, float(np.abs(pts @ n0).max()))
        out.append((c0, a0, c, a))
    return out


def symmetry(
    mask: np.ndarray,
    n_rings: int = 64,
    weight: np.ndarray | None = None,
    evidence_weight: np.ndarray | None = None,
    axes: list[tuple] | None = None,
) -> dict:
    """Best revolution axis of ``mask``: ``score`` = min(reflection IoU, profile IoU), ...

    An axis is searched around each principal axis for the most mirror-symmetric outline
    (:func:`mirror_axis`, :func:`reflection_iou`): where the hand or the photo's edge hides one
    side, the mask's centroid and principal axes lean towards the side that is seen, while the
    symmetry axis of what is seen on both sides does not. ``weight`` (the working frame's: 0
    where the outline is hidden, lower on completed pixels) weighs that search and its profile
    (:func:`profile`); without it every pixel counts the same. The searched axis and the
    principal axis itself (with the plain half-chord) are scored by the evidence below, and the
    better one is kept: the amodal completion may have drawn the hidden part so that the
    principal axis explains the outline better.

    The IoUs returned, the family's evidence, are weighted by ``evidence_weight`` instead (the
    photo's edge alone as unknown: 1 inside the photo, 0 beyond; None: every pixel counts),
    when at least :data:`MIN_MIRROR_SEEN` of the outline's mirror image is known, else by 1. Where
    the hand hides the outline, the amodal completion has drawn it, and how symmetric the
    completed outline is stays evidence: counted as unknown there as well, nearly every held
    outline is symmetric enough that boxes seen face-on come out as cylinders
    (docs/object_shape.md). Between the axes kept near the two principal axes, ties within 0.02
    (of the evidence) go to the major axis (a bottle revolves about its length). ``axes``:
    :func:`searched_axes` of ``mask`` and ``weight`` when already found.
    """
    ev = np.ones(mask.shape) if evidence_weight is None else evidence_weight
    best = None
    for c0, a0, c, a in searched_axes(mask, weight) if axes is None else axes:
        # the searched axis with the profile that knows the hidden pixels, and the principal
        # axis with the plain half-chord: whichever the outline as seen supports better
        cands = [_axis_evidence(mask, ev, c, a, profile(mask, c, a, n_rings, weight)),
                 _axis_evidence(mask, ev, c0, a0, profile(mask, c0, a0, n_rings))]  # fmt: skip
        cand = max(cands, key=lambda d: d["score"])
        if best is None or cand["score"] > best["score"] + 0.02:
            best = cand
    return best


def _axis_evidence(mask, ev, c, a, prof) -> dict:
    """The evidence of one axis and profile (module docs): reflection and profile IoU weighted
    by ``ev`` when at least :data:`MIN_MIRROR_SEEN` of the mirror image is known, else plain."""
    s, r, n = prof
    if mirror_seen(mask, ev, c, a) < MIN_MIRROR_SEEN:
        ev = np.ones(mask.shape)  # too little of the mirror image is in the photo to judge by
    pm = profile_mask(mask.shape, c, a, n, s, r)
    refl, piou = reflection_iou(mask, ev, c, a), weighted_iou(mask, pm, ev)
    return dict(score=min(refl, piou), reflection_iou=refl, profile_iou=piou, center=c,
                axis=a, s=s, r=r)  # fmt: skip


def profile_mask(shape, c, a, n, s, r) -> np.ndarray:
    """Region covered by the revolved profile seen from the front: ``|t| <= r(s)``."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W] + 0.5
    p = np.stack([u - c[0], v - c[1]], axis=-1)
    ps, pt = p @ a, p @ n
    inside = (ps >= s[0]) & (ps <= s[-1])
    return inside & (np.abs(pt) <= np.interp(ps, s, r))


def tilted_revolution_mesh(c, a, s, r, tilt: float, n_segments: int = 48):
    """Vertices (u, v, z) and faces of the profile ``r(s)`` revolved about an axis through ``c``
    that rises out of the image by ``tilt`` radians towards ``+a``; ``s`` is the axial position
    seen in the image (the axial length is ``s / cos(tilt)``), the ends are flat disks."""
    a = np.asarray(a, dtype=np.float64)
    n = np.array([-a[1], a[0]])
    ct, st = np.cos(tilt), np.sin(tilt)
    ax3 = np.array([a[0] * ct, a[1] * ct, st])
    n3 = np.array([n[0], n[1], 0.0])
    m3 = np.cross(ax3, n3)
    K, M = len(s), n_segments
    th = 2 * np.pi * np.arange(M) / M
    centre = np.array([c[0], c[1], 0.0]) + (s / ct)[:, None] * ax3  # (K, 3)
    ring = r[:, None, None] * (np.cos(th)[None, :, None] * n3 + np.sin(th)[None, :, None] * m3)
    verts = (centre[:, None, :] + ring).reshape(-1, 3)
    verts = np.concatenate([verts, centre[[0, -1]]])
    return verts, _ring_faces(K, M)


def end_centre(s: np.ndarray, r: np.ndarray, k: float, from_start: bool) -> float:
    """Axial position (image units) of a flat end disk whose ellipse, ``k r`` deep along the
    axis, just reaches the outline's tip: the first ``x`` from the tip with ``x >= k r(x)``."""
    x = s - s[0] if from_start else s[-1] - s
    ok = np.nonzero(x >= k * r)[0]
    if not len(ok):
        return float("nan")
    i = ok[0] if from_start else ok[-1]
    j = i - 1 if from_start else i + 1
    if 0 <= j < len(s):  # linear crossing between the last sample short of it and this one
        f0, f1 = x[j] - k * r[j], x[i] - k * r[i]
        w = f1 / (f1 - f0) if f1 != f0 else 0.0
        return float(s[i] + w * (s[j] - s[i]))
    return float(s[i])


def rim_support(wf: WorkFrame, c, a, s, r, tilt: float) -> tuple[float, float, float]:
    """(edge ratio, s0, s1): image gradient on the visible rims of flat end disks on an axis
    tilted by ``tilt``, relative to the object's median gradient, and the body's end positions.

    The end disk of radius ``r_e`` is seen as an ellipse with semi-axes ``r_e`` across the axis
    and ``r_e sin(tilt)`` along it; the half towards the body lies inside the outline, where the
    end face meets the side at a sharp rim (the two are lit differently). Only samples a few
    pixels inside the visible object count (the outline itself is an edge), and the better end
    is kept: only the end facing the camera shows its rim.
    """
    k = np.sin(tilt)
    s0, s1 = end_centre(s, r, k, True), end_centre(s, r, k, False)
    if not (np.isfinite(s0) and np.isfinite(s1)) or s1 - s0 < 0.1 * (s[-1] - s[0]):
        return 0.0, s0, s1
    if wf.gray is None:
        return 0.0, s0, s1
    mag, base, inner = _gradient(wf)
    if base <= 0:
        return 0.0, s0, s1
    n = np.array([-a[1], a[0]])
    phi = np.linspace(0.15 * np.pi, 0.85 * np.pi, 24)
    best = 0.0
    for se, inward in ((s0, 1.0), (s1, -1.0)):
        re = float(np.interp(se, s, r))
        if k * re < RIM_MIN_DEPTH:  # a rim this close to the tip is not told from the outline
            continue
        pts = c + se * a + (re * np.cos(phi))[:, None] * n
        pts = pts + (inward * k * re * np.sin(phi))[:, None] * a
        ij = np.floor(pts).astype(int)
        ok = (
            (ij[:, 0] >= 0)
            & (ij[:, 0] < mag.shape[1])
            & (ij[:, 1] >= 0)
            & (ij[:, 1] < mag.shape[0])
        )
        ij = ij[ok]
        ij = ij[inner[ij[:, 1], ij[:, 0]]]
        if len(ij) >= RIM_MIN_SAMPLES:
            best = max(best, float(mag[ij[:, 1], ij[:, 0]].mean() / base))
    return best, s0, s1


def _gradient(wf: WorkFrame):
    """(3x3-max gradient magnitude, its median inside the object, pixels well inside)."""
    g = cv2.GaussianBlur(wf.gray, (0, 0), 0.8)
    mag = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_64F, 0, 1, ksize=3))
    inner = cv2.erode(wf.visible.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    base = max(float(np.median(mag[inner])), GRADIENT_FLOOR) if inner.sum() > 20 else 0.0
    return cv2.dilate(mag, np.ones((3, 3), np.uint8)), base, inner


def fit(
    wf: WorkFrame, n_rings: int = 48, n_segments: int = 40, axes: list[tuple] | None = None
) -> Hypothesis:
    """The surface-of-revolution hypothesis of the working frame's mask (module docs: tilt);
    ``axes``: :func:`searched_axes` of its mask and weight when already found."""
    in_photo = None if wf.in_photo is None else wf.in_photo.astype(np.float64)
    sym = symmetry(wf.mask, n_rings, wf.weight, in_photo, axes)
    c, a, s, r = sym["center"], sym["axis"], sym["s"], sym["r"]
    verts, faces = tilted_revolution_mesh(c, a, s, r, 0.0, n_segments)
    iou = fit_iou(rasterize(verts[:, :2], faces, wf.mask.shape), wf)
    tilt_deg, rim = 0.0, 0.0
    for deg in TILTS_DEG:
        ratio, s0, s1 = rim_support(wf, c, a, s, r, np.radians(deg))
        if ratio < RIM_MIN_RATIO or ratio <= rim:
            continue
        sb = np.linspace(s0, s1, n_rings)
        v, f = tilted_revolution_mesh(c, a, sb, np.interp(sb, s, r), np.radians(deg), n_segments)
        i = fit_iou(rasterize(v[:, :2], f, wf.mask.shape), wf)
        if i >= iou - TILT_IOU_TOLERANCE:
            tilt_deg, rim, verts, faces, best_iou = float(deg), ratio, v, f, i
    if tilt_deg:
        iou = best_iou
    info = dict(reflection_iou=round(sym["reflection_iou"], 4),
                profile_iou=round(sym["profile_iou"], 4),
                axis=[round(float(x), 6) for x in sym["axis"]], tilt_deg=tilt_deg,
                rim_ratio=round(rim, 3))  # fmt: skip
    return Hypothesis("revolution", verts, faces, min(iou, sym["reflection_iou"]), True, info=info)


def _ring_faces(K: int, M: int) -> np.ndarray:
    """Faces of ``K`` rings of ``M`` vertices (ring-major) capped by two fans around the end
    centres stored after them (vertex indices ``K M`` and ``K M + 1``)."""
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
    return np.concatenate([quads, cap0, cap1]).astype(np.int64)
