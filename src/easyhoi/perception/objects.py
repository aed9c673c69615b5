"""Offline single-view object reconstruction from the amodal silhouette.

:class:`SilhouetteReconstructor` (registered as ``("object", "silhouette")``) is the offline
stand-in for an image-to-3D model (InstantMesh, Tripo3D). It sees only the amodal mask:

- **surface of revolution** when the silhouette is mirror-symmetric about a line. The symmetry
  axis of a symmetric shape is always one of its two principal (PCA) axes, so both are tried;
  an axis is accepted when ``min(IoU(mask, reflected mask), IoU(mask, revolved profile)) >=
  symmetry_threshold`` (0.9 by default). The second term rejects shapes that are symmetric but
  whose cross-sections are not single intervals (an L with equal arms is symmetric about its
  diagonal). The radius ``r(s)`` along the axis is half the chord length of the mask on the line
  perpendicular to the axis at ``s`` (integral of the bilinearly interpolated mask), and the
  profile is revolved into rings capped by flat disks at both ends.
- **inflation** otherwise: a height field over the mask, mirrored front and back and closed at
  the contour. With ``d`` the distance to the contour and ``R`` the local half-width (radius
  of the largest inscribed disk containing the pixel, smoothed), the half-thickness is
  ``h = sqrt(d (2R - d))``, a circular cross-section: a disk inflates to a sphere, a bar to a
  cylinder-like tube. The closed surface is the zero level set of ``h^2 - (z - c)^2``
  (``c`` = mid-surface, 0 here) extracted by marching cubes.

Output frame (as InstantMesh's, arbitrary scale): centred at the bounding-box centre, x right and
y down as in the image, z away from the camera (right-handed), unit max extent.
``mesh.metadata["easyhoi"]`` records the method, the symmetry score and the map back to pixels:
``u = x * pixels_per_unit + center_px[0]`` (pixel centres at integer + 0.5), likewise ``v``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

from easyhoi.errors import BackendError, InvalidInputError
from easyhoi.perception.base import register

#: Default acceptance threshold of the surface-of-revolution branch (see module docs).
SYMMETRY_THRESHOLD = 0.9


# ----------------------------------------------------------------------------------------------
# input checks and crops
# ----------------------------------------------------------------------------------------------


def _check_mask(mask, image=None) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 2:
        raise InvalidInputError(f"object mask must have shape (H, W), got {m.shape}")
    m = m > 0.5 if m.dtype.kind == "f" else m.astype(bool)
    if image is not None:
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InvalidInputError(f"image must have shape (H, W, 3), got {img.shape}")
        if img.shape[:2] != m.shape:
            raise InvalidInputError(
                f"object mask is {m.shape[0]}x{m.shape[1]} but the image is "
                f"{img.shape[0]}x{img.shape[1]}"
            )
    if m.sum() < 16:
        raise InvalidInputError(
            f"object mask has {int(m.sum())} pixels; at least 16 are needed to build a mesh"
        )
    return m


@dataclass(frozen=True)
class ObjectCrop:
    """A square, background-free crop of the object (what an image-to-3D model consumes).

    Attributes:
        image: (S, S, 3) uint8 RGB, white outside the mask.
        mask: (S, S) bool.
        box: (u0, v0, u1, v1) int, the crop window in the source image (may exceed it; pixels
            outside the source are white / False).
    """

    image: np.ndarray
    mask: np.ndarray
    box: tuple[int, int, int, int]


def object_crop(image: np.ndarray, mask: np.ndarray, pad: float = 0.1) -> ObjectCrop:
    """Square crop around the mask with a white background.

    Parameters
    ----------
    image : (H, W, 3) uint8
    mask : (H, W) bool
    pad : float
        Margin on each side as a fraction of the mask's larger bounding-box side, >= 0.
    """
    m = _check_mask(mask, image)
    if not (np.isfinite(pad) and pad >= 0):
        raise InvalidInputError(f"pad must be a finite number >= 0, got {pad}")
    img = np.asarray(image)
    rows, cols = np.nonzero(m)
    v0, v1, u0, u1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    side = int(np.ceil(max(v1 - v0, u1 - u0) * (1 + 2 * pad)))
    cu, cv = (u0 + u1) // 2, (v0 + v1) // 2
    bu, bv = cu - side // 2, cv - side // 2
    out = np.full((side, side, 3), 255, dtype=np.uint8)
    out_m = np.zeros((side, side), dtype=bool)
    H, W = m.shape
    su0, sv0, su1, sv1 = max(bu, 0), max(bv, 0), min(bu + side, W), min(bv + side, H)
    sub_m = m[sv0:sv1, su0:su1]
    dst = (slice(sv0 - bv, sv1 - bv), slice(su0 - bu, su1 - bu))
    out_m[dst] = sub_m
    out[dst][sub_m] = img[sv0:sv1, su0:su1][sub_m]
    return ObjectCrop(out, out_m, (int(bu), int(bv), int(bu + side), int(bv + side)))


# ----------------------------------------------------------------------------------------------
# shared helpers
# ----------------------------------------------------------------------------------------------


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 0.0


def signed_distance_2d(mask: np.ndarray) -> np.ndarray:
    """(H, W) float signed distance (pixels) to the mask's contour, positive inside.

    The contour lies on pixel edges: a pixel whose 4-neighbour is outside is at +0.5.
    """
    inside = ndimage.distance_transform_edt(mask) - 0.5
    outside = ndimage.distance_transform_edt(~mask) - 0.5
    return np.where(mask, inside, -outside)


def canonical_mesh(verts_px: np.ndarray, faces: np.ndarray, meta: dict) -> trimesh.Trimesh:
    """(V, 3) pixel-unit (u, v, z) vertices and (F, 3) faces -> the canonical frame.

    Repairs the surface if it is not closed (pymeshfix), orients it outwards, centres it on
    its bounding box and scales it to unit max extent; ``meta`` plus ``pixels_per_unit``,
    ``center_px`` (u, v) and ``depth_center_px`` go to ``metadata["easyhoi"]``.
    """
    mesh = trimesh.Trimesh(verts_px, faces, process=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        mesh = _repair(mesh)  # TODO: swap for geometry.watertight.make_watertight
    if mesh.volume < 0:
        mesh.invert()
    lo, hi = mesh.bounds
    center = 0.5 * (lo + hi)
    scale = float((hi - lo).max())
    if not np.isfinite(scale) or scale <= 0:
        raise BackendError("silhouette reconstruction produced a degenerate mesh")
    mesh.vertices = (mesh.vertices - center) / scale
    meta = dict(meta, pixels_per_unit=scale, center_px=[float(center[0]), float(center[1])])
    meta["depth_center_px"] = float(center[2])
    mesh.metadata["easyhoi"] = meta
    return mesh


def _repair(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    import pymeshfix

    v, f = pymeshfix.clean_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    fixed = trimesh.Trimesh(v, f, process=True)
    if not fixed.is_watertight:
        raise BackendError("could not make the reconstructed object mesh watertight")
    return fixed


# ----------------------------------------------------------------------------------------------
# surface of revolution
# ----------------------------------------------------------------------------------------------


def _principal_axes(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (u, v) in pixel-centre coordinates and (2, 2) axes (rows, major first)."""
    rows, cols = np.nonzero(mask)
    pts = np.stack([cols + 0.5, rows + 0.5], axis=1)
    c = pts.mean(axis=0)
    cov = np.cov((pts - c).T)
    w, vec = np.linalg.eigh(cov)
    axes = vec[:, ::-1].T.copy()
    for i in range(2):  # deterministic sign: largest component positive
        if axes[i][np.argmax(np.abs(axes[i]))] < 0:
            axes[i] = -axes[i]
    return c, axes


def _reflect(mask: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
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


def _profile(mask: np.ndarray, c: np.ndarray, a: np.ndarray, n_samples: int):
    """Chord half-lengths r(s) on lines perpendicular to ``a`` through the mask."""
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
    # pixel-centre coordinates -> array indices (row = v - 0.5, col = u - 0.5)
    coords = np.stack([P[..., 1] - 0.5, P[..., 0] - 0.5])
    vals = ndimage.map_coordinates(mask.astype(np.float64), coords, order=1, mode="constant")
    r = 0.5 * vals.sum(axis=1) * dt
    # the end samples sit on the outer pixel edge: use the nearest interior chord there
    r[0] = max(r[0], r[1])
    r[-1] = max(r[-1], r[-2])
    return s, r, n


def _profile_mask(shape, c, a, n, s, r) -> np.ndarray:
    """Region covered by the revolved profile seen from the front: |t| <= r(s)."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W] + 0.5
    p = np.stack([u - c[0], v - c[1]], axis=-1)
    ps, pt = p @ a, p @ n
    inside = (ps >= s[0]) & (ps <= s[-1])
    return inside & (np.abs(pt) <= np.interp(ps, s, r))


def revolution_mesh(c, a, s, r, n_segments: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (pixel units) and faces of the profile ``r(s)`` revolved about the axis.

    Parameters
    ----------
    c : (2,) axis point (u, v). a : (2,) unit axis direction. s, r : (K,) profile samples.

    Returns
    -------
    verts : (K * n_segments + 2, 3) float, faces : (2 * n_segments * K, 3) int, outward.
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


# ----------------------------------------------------------------------------------------------
# inflation
# ----------------------------------------------------------------------------------------------


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
    by ``smooth`` pixels), so every cross-section is locally a circle of radius ``R``: a disk
    inflates to a sphere, a bar of half-width ``w`` to a tube of radius ``w``.
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

    Parameters
    ----------
    mask : (H, W) bool, the silhouette (sets the grid's extent).
    h2 : (H, W) float squared half-thickness (negative outside the mask), pixels^2.
    mid : (H, W) float mid-surface depth in pixels (z away from the camera), or None for 0.
    max_faces : the grid is coarsened until the mesh has at most this many faces.
    resolution : grid cells across the mask's larger side at the first attempt.

    Returns
    -------
    verts : (V, 3) float (u, v, z) pixel units, faces : (F, 3) int.
    """
    from skimage.measure import marching_cubes

    rows, cols = np.nonzero(mask)
    lo = np.array([cols.min(), rows.min()], dtype=np.float64)
    hi = np.array([cols.max() + 1, rows.max() + 1], dtype=np.float64)
    mid = np.zeros_like(h2) if mid is None else mid
    h_in = np.sqrt(np.maximum(h2[mask], 0))
    zlo, zhi = float((mid[mask] - h_in).min()), float((mid[mask] + h_in).max())
    step = float((hi - lo).max()) / resolution
    for _ in range(6):
        pad = 2 * step
        gu = np.arange(lo[0] - pad, hi[0] + pad + step, step)
        gv = np.arange(lo[1] - pad, hi[1] + pad + step, step)
        gz = np.arange(zlo - pad, zhi + pad + step, step)
        V, U = np.meshgrid(gv - 0.5, gu - 0.5, indexing="ij")
        coords = np.stack([V, U])
        h2g = ndimage.map_coordinates(h2, coords, order=1, mode="nearest").T  # (U, V)
        midg = ndimage.map_coordinates(mid, coords, order=1, mode="nearest").T
        vol = h2g[..., None] - (gz[None, None, :] - midg[..., None]) ** 2
        vol[[0, -1]] = vol[:, [0, -1]] = vol[:, :, [0, -1]] = -1.0  # closed at the border
        verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(step, step, step))
        if len(faces) <= max_faces:
            break
        step *= float(np.sqrt(len(faces) / max_faces)) * 1.05
    verts = verts + np.array([gu[0], gv[0], gz[0]])
    return verts, faces.astype(np.int64)


# ----------------------------------------------------------------------------------------------
# the backend
# ----------------------------------------------------------------------------------------------


@register("object", "silhouette")
class SilhouetteReconstructor:
    """Object mesh from the amodal silhouette alone (see module docs).

    Parameters
    ----------
    symmetry_threshold : float in (0, 1]; >1 disables the surface-of-revolution branch.
    n_rings, n_segments : resolution of a surface of revolution (faces = 2 n_rings n_segments).
    max_faces : face budget of the inflation branch.
    """

    def __init__(
        self,
        symmetry_threshold: float = SYMMETRY_THRESHOLD,
        n_rings: int = 64,
        n_segments: int = 48,
        max_faces: int = 8000,
    ):
        if not symmetry_threshold > 0:
            raise InvalidInputError(f"symmetry_threshold must be > 0, got {symmetry_threshold}")
        if n_rings < 3 or n_segments < 8 or max_faces < 500:
            raise InvalidInputError(
                "need n_rings >= 3, n_segments >= 8 and max_faces >= 500, got "
                f"{n_rings}, {n_segments}, {max_faces}"
            )
        self.symmetry_threshold = float(symmetry_threshold)
        self.n_rings = int(n_rings)
        self.n_segments = int(n_segments)
        self.max_faces = int(max_faces)

    def symmetry(self, mask: np.ndarray) -> dict:
        """Best revolution axis of ``mask`` and its scores.

        Returns
        -------
        dict with ``score`` (min of the reflection IoU and the profile IoU), ``reflection_iou``,
        ``profile_iou``, ``center`` (2,), ``axis`` (2,) unit (u, v), ``s`` and ``r`` (profile).
        Ties within 0.02 go to the major axis (a bottle revolves about its length).
        """
        m = _check_mask(mask)
        c, axes = _principal_axes(m)
        best = None
        for a in axes:
            refl = _iou(m, _reflect(m, c, a))
            s, r, n = _profile(m, c, a, self.n_rings)
            prof = _iou(m, _profile_mask(m.shape, c, a, n, s, r))
            cand = dict(
                score=min(refl, prof), reflection_iou=refl, profile_iou=prof, center=c, axis=a,
                s=s, r=r,
            )  # fmt: skip
            if best is None or cand["score"] > best["score"] + 0.02:
                best = cand
        return best

    def reconstruct(self, image: np.ndarray | None, mask: np.ndarray) -> trimesh.Trimesh:
        """Closed mesh of the object seen as ``mask``.

        Parameters
        ----------
        image : (H, W, 3) uint8 or None (only checked: the reconstruction uses the mask).
        mask : (H, W) bool amodal object mask.

        Returns
        -------
        trimesh.Trimesh, watertight, outward winding, canonical frame (module docs);
        ``metadata["easyhoi"]["method"]`` is ``"revolution"`` or ``"inflation"``.
        """
        m = _check_mask(mask, image)
        sym = self.symmetry(m)
        meta = dict(
            symmetry_score=sym["score"],
            reflection_iou=sym["reflection_iou"],
            profile_iou=sym["profile_iou"],
        )
        if sym["score"] >= self.symmetry_threshold:
            verts, faces = revolution_mesh(
                sym["center"], sym["axis"], sym["s"], sym["r"], self.n_segments
            )
            meta.update(method="revolution", axis=[float(x) for x in sym["axis"]])
        else:
            verts, faces = implicit_slab_mesh(m, half_thickness_sq(m), max_faces=self.max_faces)
            meta.update(method="inflation")
        return canonical_mesh(verts, faces, meta)
