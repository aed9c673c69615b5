"""Iterative closest point with closed-form updates for four transform families.

The transform maps source to target: ``x -> s * R @ x + t``. Every iteration re-queries the
nearest target point of every *moved* source point (scipy cKDTree), optionally discards pairs
(normal compatibility, trimming of the worst residuals), and re-solves the transform:

============================  ==================================================================
mode                          update (point-to-point)
============================  ==================================================================
``"translation"``             ``t = mean(q - s R p)``
``"translation_scale"``       least squares of ``s * (R p) + t ~ q`` over (s, t), R fixed
``"rigid"``                   Kabsch (SVD) of ``s p -> q``, s fixed
``"rigid_scale"``             Umeyama (1991): rotation, translation and uniform scale
============================  ==================================================================

``point_to_plane=True`` replaces the update by the linearised point-to-plane step (Chen and
Medioni 1991) for ``"rigid"`` (small rotation + translation) and ``"translation"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from easyhoi.checks import check_finite
from easyhoi.errors import InvalidInputError

MODES = ("translation", "translation_scale", "rigid", "rigid_scale")
#: Nearest neighbours searched for a normal-compatible partner when normal_max_angle is set.
_NORMAL_CANDIDATES = 16


@dataclass(frozen=True)
class ICPResult:
    """Outcome of :func:`icp`; the transform is ``x -> s * R @ x + t``.

    Attributes:
        R ((3, 3) float64): Rotation (identity for the translation modes unless ``init`` had one).
        t ((3,) float64): Translation.
        s (float): Uniform scale (1 for the modes without scale unless ``init`` had one).
        transformed ((N, 3) float64): The source points after the final transform.
        rmse ((iterations + 1,) float64): Root mean square distance of the kept correspondences,
            before the first update and after each update.
        iterations (int): Number of updates applied.
        converged (bool): True when the RMSE changed by less than ``tol`` before ``max_iters`` was
            reached.
    """

    R: np.ndarray
    t: np.ndarray
    s: float
    transformed: np.ndarray
    rmse: np.ndarray
    iterations: int
    converged: bool

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (..., 3) ``s * R @ p + t``."""
        return self.s * np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix of the similarity."""
        m = np.eye(4)
        m[:3, :3] = self.s * self.R
        m[:3, 3] = self.t
        return m


def _as_points(x, name: str, allow_empty: bool = False) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (N, 3), got {a.shape}")
    if len(a) == 0 and not allow_empty:
        raise InvalidInputError(f"{name} must hold at least one point, got 0")
    check_finite(a, name)
    return a


def _kabsch(p: np.ndarray, q: np.ndarray, with_scale: bool) -> tuple[np.ndarray, float]:
    """Rotation (and Umeyama scale) best mapping centred p onto centred q."""
    cov = q.T @ p / len(p)
    u, sig, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    diag = np.array([1.0, 1.0, d])
    R = (u * diag) @ vt
    s = 1.0
    if with_scale:
        var = float((p * p).sum() / len(p))
        s = float((sig * diag).sum() / var) if var > 0 else 1.0
    return R, s


def _rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rodrigues: axis-angle (3,) -> (3, 3)."""
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _solve_point_to_point(mode, src, q, R, t, s):
    if mode == "translation":
        return R, (q - s * src @ R.T).mean(axis=0), s
    if mode == "translation_scale":
        y = src @ R.T
        yc, qc = y - y.mean(axis=0), q - q.mean(axis=0)
        den = float((yc * yc).sum())
        s_new = float((yc * qc).sum() / den) if den > 0 else s
        if not s_new > 0:  # degenerate pairing: keep the previous scale
            s_new = s
        return R, q.mean(axis=0) - s_new * y.mean(axis=0), s_new
    p = src if mode == "rigid_scale" else s * src
    pm, qm = p.mean(axis=0), q.mean(axis=0)
    R_new, s_fit = _kabsch(p - pm, q - qm, with_scale=mode == "rigid_scale")
    s_new = s_fit if mode == "rigid_scale" else s
    if mode == "rigid_scale":
        return R_new, qm - s_new * pm @ R_new.T, s_new
    return R_new, qm - pm @ R_new.T, s


def _solve_point_to_plane(mode, cur, q, n, R, t, s):
    """One linearised point-to-plane step applied on top of the current transform."""
    r = -np.einsum("ij,ij->i", cur - q, n)
    if mode == "rigid":
        A = np.concatenate([np.cross(cur, n), n], axis=1)  # (K, 6): [w | dt]
    else:
        A = n
    x, *_ = np.linalg.lstsq(A, r, rcond=None)
    if mode == "rigid":
        dR = _rotation_from_vector(x[:3])
        return dR @ R, dR @ t + x[3:], s
    return R, t + x, s


def icp(
    source,
    target,
    mode: str = "rigid",
    max_iters: int = 50,
    tol: float = 1e-8,
    point_to_plane: bool = False,
    target_normals=None,
    source_normals=None,
    normal_max_angle: float | None = None,
    trim_fraction: float = 0.0,
    init: tuple[np.ndarray, np.ndarray, float] | None = None,
) -> ICPResult:
    """Register ``source`` onto ``target`` by iterative closest point.

    Args:
        source ((N, 3) array or tensor): Points to move.
        target ((M, 3) array or tensor): Fixed points.
        mode (str): ``"translation"``, ``"translation_scale"``, ``"rigid"`` or ``"rigid_scale"``;
            the parameters a mode does not fit stay at their ``init`` value.
        max_iters (int): Maximum number of updates, >= 1.
        tol (float): Stop when the RMSE of two successive iterations differs by less than this (same
            units).
        point_to_plane (bool): Use the linearised point-to-plane update (needs ``target_normals``;
            modes ``"rigid"`` and ``"translation"`` only).
        target_normals ((M, 3), optional): Unit normals of the target points.
        source_normals ((N, 3), optional): Unit normals of the source points (rotated with the
            source).
        normal_max_angle (float, optional): Radians; pair each source point with the nearest of its
            16 nearest targets whose normal differs by at most this angle, and drop it when there is
            none (needs both normal sets).
        trim_fraction (float): In [0, 1): discard this fraction of the pairs with the largest
            distances each iteration.
        init ((R (3, 3), t (3,), s), optional): Initial transform; identity by default.

    Returns:
        ICPResult
    """
    src = _as_points(source, "source")
    tgt = _as_points(target, "target")
    if mode not in MODES:
        raise InvalidInputError(f"mode must be one of {MODES}, got {mode!r}")
    if not isinstance(max_iters, int | np.integer) or max_iters < 1:
        raise InvalidInputError(f"max_iters must be a positive integer, got {max_iters!r}")
    if not (0.0 <= trim_fraction < 1.0):
        raise InvalidInputError(f"trim_fraction must be in [0, 1), got {trim_fraction}")
    tn = None if target_normals is None else _as_points(target_normals, "target_normals")
    sn = None if source_normals is None else _as_points(source_normals, "source_normals")
    if tn is not None and len(tn) != len(tgt):
        raise InvalidInputError(f"target_normals must have {len(tgt)} rows, got {len(tn)}")
    if sn is not None and len(sn) != len(src):
        raise InvalidInputError(f"source_normals must have {len(src)} rows, got {len(sn)}")
    if point_to_plane:
        if mode not in ("rigid", "translation"):
            raise InvalidInputError(
                f"point_to_plane supports modes 'rigid' and 'translation', got {mode!r}"
            )
        if tn is None:
            raise InvalidInputError("point_to_plane=True needs target_normals of shape (M, 3)")
    if normal_max_angle is not None and (tn is None or sn is None):
        raise InvalidInputError("normal_max_angle needs both source_normals and target_normals")
    if init is None:
        R, t, s = np.eye(3), np.zeros(3), 1.0
    else:
        R = np.asarray(init[0], dtype=np.float64).reshape(3, 3)
        t = np.asarray(init[1], dtype=np.float64).reshape(3)
        s = float(init[2])
        if not s > 0:
            raise InvalidInputError(f"init scale must be positive, got {s}")
    if tn is not None:
        tn = tn / np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-300)
    cos_max = None if normal_max_angle is None else float(np.cos(normal_max_angle))
    tree = cKDTree(tgt)
    rmse: list[float] = []
    converged = False
    it = 0
    while True:
        cur = s * src @ R.T + t
        if cos_max is None:
            dist, idx = tree.query(cur)
            keep = np.ones(len(src), dtype=bool)
        else:
            # nearest target among the k nearest whose normal is compatible
            k = min(_NORMAL_CANDIDATES, len(tgt))
            dk, ik = tree.query(cur, k=k)
            dk, ik = dk.reshape(len(src), k), ik.reshape(len(src), k)
            rn = sn @ R.T
            cos = np.einsum("nd,nkd->nk", rn, tn[ik])
            ok = cos >= cos_max * np.linalg.norm(rn, axis=1, keepdims=True)
            first = np.argmax(ok, axis=1)
            rows = np.arange(len(src))
            dist, idx, keep = dk[rows, first], ik[rows, first], ok[rows, first]
        if trim_fraction > 0 and keep.sum() > 1:
            n_keep = max(1, int(round((1.0 - trim_fraction) * keep.sum())))
            cut = np.sort(dist[keep])[n_keep - 1]
            keep &= dist <= cut
        if not keep.any():
            rmse.append(float("nan"))
            break
        rmse.append(float(np.sqrt(np.mean(dist[keep] ** 2))))
        if it > 0 and abs(rmse[-2] - rmse[-1]) < tol:
            converged = True
            break
        if it >= max_iters:
            break
        q = tgt[idx[keep]]
        if point_to_plane:
            R, t, s = _solve_point_to_plane(mode, cur[keep], q, tn[idx[keep]], R, t, s)
        else:
            R, t, s = _solve_point_to_point(mode, src[keep], q, R, t, s)
        it += 1
    return ICPResult(
        R=R,
        t=t,
        s=float(s),
        transformed=s * src @ R.T + t,
        rmse=np.asarray(rmse),
        iterations=it,
        converged=converged,
    )


def align_translation_scale(
    pred_pts, gt_pts, max_iters: int = 100, tol: float = 1e-10
) -> ICPResult:
    """Evaluation alignment of docs/method.md section 3: translation + uniform scale, no rotation.

    First match centroids and RMS radii (``s0 = rms(gt - c_gt) / rms(pred - c_pred)``,
    ``t0 = c_gt - s0 * c_pred``), then refine by translation + scale ICP of ``pred`` onto ``gt``.

    Args:
        pred_pts ((N, 3)): Predicted surface samples.
        gt_pts ((M, 3)): Ground-truth surface samples.

    Returns:
        ICPResult: ``R`` is the identity; ``transformed`` holds the aligned prediction.
    """
    pred = _as_points(pred_pts, "pred_pts")
    gt = _as_points(gt_pts, "gt_pts")
    cp, cg = pred.mean(axis=0), gt.mean(axis=0)
    rp = float(np.sqrt(((pred - cp) ** 2).sum(axis=1).mean()))
    rg = float(np.sqrt(((gt - cg) ** 2).sum(axis=1).mean()))
    if not rp > 0:
        raise InvalidInputError("pred_pts are all the same point: expected a spread-out cloud")
    s0 = rg / rp
    t0 = cg - s0 * cp
    return icp(
        pred,
        gt,
        mode="translation_scale",
        max_iters=max_iters,
        tol=tol,
        init=(np.eye(3), t0, s0),
    )
