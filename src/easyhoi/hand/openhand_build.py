"""Procedural construction of the OpenHand rest mesh (a freely licensed adult right hand).

The hand is an implicit surface: a signed distance field (negative inside) made of a rounded
palm slab, a wrist stub, thenar / hypothenar pads, and one chain of tapered capsules per digit
(with a fingertip pad ellipsoid on every distal segment), joined with a polynomial smooth
minimum. The field is sampled on a regular grid, polygonised by marching cubes
(:func:`skimage.measure.marching_cubes`), decimated by shortest-edge collapse
(:func:`point_cloud_utils.decimate_triangle_mesh`) and lightly Taubin-smoothed. Every step is
deterministic. No data of any other hand model is used: the skeleton below is a set of
anthropometric guesses (adult hand, wrist to middle fingertip about 18.7 cm).

Frame (MANO's canonical right-hand frame, see :mod:`easyhoi.hand.openhand`): wrist joint at the
origin, fingers along -x, palm facing -y (back of the hand +y), thumb on the +z side; metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from easyhoi.errors import BackendError

#: Bumped whenever the geometry produced by this module changes (keys the on-disk cache).
BUILDER_VERSION = "openhand-1"

# Digit order used inside this module and its MANO joint ids (base, middle, distal joint).
DIGITS = ("index", "middle", "pinky", "ring", "thumb")
DIGIT_JOINTS = {"index": (1, 2, 3), "middle": (4, 5, 6), "pinky": (7, 8, 9), "ring": (10, 11, 12),
                "thumb": (13, 14, 15)}  # fmt: skip


@dataclass(frozen=True)
class Digit:
    """One digit of the skeleton: base joint, direction, segment lengths and radii.

    Attributes:
        base: (3,) position of the first joint (MCP; CMC for the thumb).
        direction: (3,) unit direction of the (straight) digit in the rest pose.
        lengths: (3,) joint-to-joint lengths; the last one ends at the fingertip surface.
        radii: (4,) capsule radii at the three joints and at the tip.
    """

    base: tuple[float, float, float]
    direction: tuple[float, float, float]
    lengths: tuple[float, float, float]
    radii: tuple[float, float, float, float]

    def joints(self) -> np.ndarray:
        """(4, 3) the three joints and the fingertip point (on the surface)."""
        d = np.asarray(self.direction) / np.linalg.norm(self.direction)
        s = np.concatenate([[0.0], np.cumsum(self.lengths)])
        return np.asarray(self.base) + s[:, None] * d


def _dir(deg_z: float, deg_y: float = 0.0) -> tuple[float, float, float]:
    """Unit vector tilted from -x by ``deg_z`` towards +z and ``deg_y`` towards -y (palm)."""
    a, b = np.radians(deg_z), np.radians(deg_y)
    v = np.array([-np.cos(a) * np.cos(b), -np.sin(b), np.sin(a) * np.cos(b)])
    return tuple(float(c) for c in v)


def default_skeleton() -> dict[str, Digit]:
    """The rest-pose skeleton of the default (betas = 0) hand, metres."""
    return {
        "index": Digit((-0.090, 0.0, 0.027), _dir(4.0), (0.040, 0.023, 0.022),
                       (0.0102, 0.0093, 0.0083, 0.0076)),
        "middle": Digit((-0.094, 0.0, 0.005), _dir(0.0), (0.044, 0.027, 0.0235),
                        (0.0104, 0.0095, 0.0085, 0.0078)),
        "ring": Digit((-0.089, 0.0, -0.016), _dir(-4.5), (0.041, 0.026, 0.022),
                      (0.0099, 0.0091, 0.0081, 0.0074)),
        "pinky": Digit((-0.080, 0.0, -0.035), _dir(-10.0), (0.032, 0.020, 0.020),
                       (0.0089, 0.0082, 0.0074, 0.0068)),
        "thumb": Digit((-0.024, -0.009, 0.022), _dir(44.0, 12.0), (0.044, 0.032, 0.028),
                       (0.0130, 0.0110, 0.0100, 0.0090)),
    }  # fmt: skip


def rest_joints(skeleton: dict[str, Digit] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rest joints and fingertip points of a skeleton.

    Returns:
        joints: (16, 3) MANO-ordered joints (wrist at the origin).
        tips: (5, 3) fingertip surface points in ``base.TIP_ORDER`` (thumb, index, middle, ring,
            pinky).
    """
    sk = skeleton or default_skeleton()
    joints = np.zeros((16, 3))
    for name in DIGITS:
        joints[list(DIGIT_JOINTS[name])] = sk[name].joints()[:3]
    tips = np.stack([sk[n].joints()[3] for n in ("thumb", "index", "middle", "ring", "pinky")])
    return joints, tips


# ----------------------------------------------------------------------------------------------
# Signed distance primitives (points (N, 3) -> (N,) distances, negative inside)
# ----------------------------------------------------------------------------------------------


def smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum with blend radius ``k``."""
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k * 0.25


def sd_tapered_capsule(p: np.ndarray, a, b, ra: float, rb: float) -> np.ndarray:
    """Distance to a capsule from ``a`` (radius ra) to ``b`` (radius rb), linear taper."""
    a, b = np.asarray(a), np.asarray(b)
    ba = b - a
    t = np.clip((p - a) @ ba / (ba @ ba), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ba), axis=1) - (ra + t * (rb - ra))


def sd_ellipsoid(p: np.ndarray, centre, axes, semi) -> np.ndarray:
    """Approximate distance to an ellipsoid with orthonormal ``axes`` (3, 3) rows and semi-axes."""
    q = (p - np.asarray(centre)) @ np.asarray(axes).T
    semi = np.asarray(semi)
    k0 = np.linalg.norm(q / semi, axis=1)
    k1 = np.linalg.norm(q / semi**2, axis=1)
    return np.where(k1 > 1e-12, k0 * (k0 - 1.0) / np.maximum(k1, 1e-12), -semi.min())


def sd_polygon2(p2: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance of (N, 2) points to a closed convex-or-not polygon (M, 2)."""
    d = np.full(len(p2), np.inf)
    inside = np.zeros(len(p2), dtype=bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        e = b - a
        w = p2 - a
        t = np.clip(w @ e / (e @ e), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(w - t[:, None] * e, axis=1))
        c1 = p2[:, 1] >= a[1]
        c2 = p2[:, 1] < b[1]
        c3 = e[0] * w[:, 1] - e[1] * w[:, 0] > 0
        flip = (c1 & c2 & c3) | (~c1 & ~c2 & ~c3)
        inside ^= flip
    return np.where(inside, -d, d)


#: Inner outline of the palm slab in the (x, z) plane (the surface lies ``_PALM_ROUND`` outside).
_PALM_OUTLINE = np.array([
    [0.004, -0.022], [-0.030, -0.032], [-0.062, -0.035], [-0.079, -0.032], [-0.086, -0.014],
    [-0.088, 0.004], [-0.085, 0.022], [-0.070, 0.031], [-0.040, 0.031], [-0.012, 0.025],
    [0.004, 0.018],
])  # fmt: skip
_PALM_ROUND = 0.0085


def _frame(direction) -> np.ndarray:
    """Rows: unit ``direction`` and two unit vectors orthogonal to it (second one nearest y)."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    y = np.array([0.0, 1.0, 0.0]) - d[1] * d
    y /= np.linalg.norm(y)
    return np.stack([d, y, np.cross(d, y)])


def hand_sdf(p: np.ndarray, skeleton: dict[str, Digit] | None = None) -> np.ndarray:
    """Signed distance (approximate, metres, negative inside) of the hand at (N, 3) points."""
    sk = skeleton or default_skeleton()
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    # Palm: rounded slab, thicker at the wrist (2.7 cm) than at the knuckles (2.2 cm), centred
    # slightly palmar of the finger axes.
    d2 = sd_polygon2(np.stack([x, z], axis=1), _PALM_OUTLINE)
    half = np.interp(-x, [0.0, 0.09], [0.0150, 0.0120]) - _PALM_ROUND
    dy = np.abs(y + 0.0015) - half
    palm = (
        np.hypot(np.clip(d2, 0, None), np.clip(dy, 0, None))
        + np.minimum(np.maximum(d2, dy), 0.0)
        - _PALM_ROUND
    )
    # Wrist stub: a flattened round-ended cylinder reaching about 1 cm past the wrist joint.
    wrist = sd_ellipsoid(p, (-0.012, 0.0, 0.0), np.eye(3), (0.026, 0.0160, 0.029))
    body = smin(palm, wrist, 0.01)
    # Hypothenar pad (pinky side) and thenar pad (around the thumb metacarpal).
    hypo = sd_ellipsoid(p, (-0.045, -0.006, -0.032), np.eye(3), (0.033, 0.010, 0.011))
    body = smin(body, hypo, 0.008)
    th = sk["thumb"]
    then_c = (
        np.asarray(th.base) + 0.012 * np.asarray(th.direction) + np.array([-0.008, -0.002, -0.004])
    )
    thenar = sd_ellipsoid(p, then_c, _frame(th.direction), (0.028, 0.013, 0.016))
    body = smin(body, thenar, 0.010)
    for name in DIGITS:
        dg = sk[name]
        pts = dg.joints()
        r = dg.radii
        dirn = pts[3] - pts[2]
        dirn /= np.linalg.norm(dirn)
        end = pts[3] - r[3] * dirn  # capsule end: the tip surface lies one radius further
        dist = sd_tapered_capsule(p, pts[0], pts[1], r[0], r[1])
        dist = np.minimum(dist, sd_tapered_capsule(p, pts[1], pts[2], r[1], r[2]))
        dist = smin(dist, sd_tapered_capsule(p, pts[2], end, r[2], r[3]), 0.002)
        # Fingertip pad: an ellipsoid on the palmar side of the distal segment.
        fr = _frame(dirn)
        if name == "thumb":
            fr = np.stack([fr[0], *_roll(fr[1], fr[2], np.radians(-60.0))])
        seg = np.linalg.norm(end - pts[2])
        pad_c = pts[2] + 0.55 * seg * dirn - 0.35 * r[3] * fr[1]
        pad = sd_ellipsoid(p, pad_c, fr, (0.55 * seg + 0.3 * r[3], 0.75 * r[3], 0.95 * r[3]))
        dist = smin(dist, pad, 0.003)
        blend = 0.012 if name == "thumb" else 0.007
        body = smin(body, dist, blend)
    return body


def _roll(u: np.ndarray, v: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(angle), np.sin(angle)
    return c * u + s * v, -s * u + c * v


# ----------------------------------------------------------------------------------------------
# Meshing
# ----------------------------------------------------------------------------------------------


_GRID_LO = np.array([-0.20, -0.055, -0.055])
_GRID_HI = np.array([0.025, 0.03, 0.115])


def _sample_field(skeleton: dict[str, Digit] | None, voxel: float, coarsen: int = 3) -> np.ndarray:
    """The SDF on the regular grid of spacing ``voxel`` over the builder's bounding box.

    Evaluated exactly only in a narrow band around the surface: a coarse grid (``coarsen`` times
    sparser) is sampled first; where the nearest coarse value is farther from zero than the
    coarse cell's half-diagonal plus a margin, the field (being ~1-Lipschitz) cannot change sign
    within the cell and the coarse value is kept.
    """
    n = np.ceil((_GRID_HI - _GRID_LO) / voxel).astype(int) + 1
    nc = (n - 1) // coarsen + 2
    cvox = voxel * coarsen
    caxes = [_GRID_LO[i] + cvox * np.arange(nc[i]) for i in range(3)]
    cpts = np.stack(np.meshgrid(*caxes, indexing="ij"), axis=-1).reshape(-1, 3)
    coarse = hand_sdf(cpts, skeleton).reshape(nc)
    idx = [np.rint(np.arange(n[i]) / coarsen).astype(int) for i in range(3)]
    field = coarse[np.ix_(*idx)]
    band = np.abs(field) < 1.5 * cvox
    ii = np.nonzero(band)
    pts = _GRID_LO + voxel * np.stack(ii, axis=1)
    field[ii] = hand_sdf(pts, skeleton)
    return field


def build_mesh(
    skeleton: dict[str, Digit] | None = None,
    voxel: float = 0.0016,
    target_faces: int = 3800,
    smooth_iterations: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Polygonise the hand's implicit surface.

    Args:
        skeleton: digits (default :func:`default_skeleton`).
        voxel: grid spacing of the marching cubes (metres).
        target_faces: face budget after decimation.
        smooth_iterations: Taubin smoothing passes after decimation.
    Returns:
        vertices (V, 3) float64 and faces (F, 3) int64 of a closed, outward-oriented mesh.
    Raises:
        BackendError: if the result is not a single watertight, consistently oriented surface.
    """
    import point_cloud_utils as pcu
    import trimesh
    from skimage.measure import marching_cubes

    field = _sample_field(skeleton, voxel)
    lo = _GRID_LO
    verts, faces, _, _ = marching_cubes(field, 0.0, spacing=(voxel,) * 3, allow_degenerate=False)
    verts = verts.astype(np.float64) + lo
    faces = faces.astype(np.int64)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    v, f, _, _ = pcu.decimate_triangle_mesh(
        np.ascontiguousarray(mesh.vertices),
        np.ascontiguousarray(mesh.faces, dtype=np.int32),
        int(target_faces),
    )
    mesh = trimesh.Trimesh(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64),
                           process=True)  # fmt: skip
    if smooth_iterations:
        trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=-0.53, iterations=smooth_iterations)
    mesh.fix_normals()
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise BackendError("OpenHand mesh construction did not produce a closed oriented surface")
    if len(mesh.split(only_watertight=False)) != 1:
        raise BackendError("OpenHand mesh construction produced several disconnected parts")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
