"""Object reconstruction metrics: Chamfer distance and F-score (docs/method.md section 3).

Convention ("moho", the one MOHO and EasyHOI report): sample 30,000 points on each surface,
convert metres to centimetres, take squared nearest-neighbour distances,
``C.D. = mean(gt -> pred) + mean(pred -> gt)``, then divide by 10. The "raw" convention keeps the
sum in cm^2 without the /10 (gSDF, AlignSDF). Before measuring, the prediction is aligned to the
ground truth: match centroid and RMS radius, then refine translation + uniform scale by ICP
(no rotation).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from easyhoi.errors import InvalidInputError
from easyhoi.metrics._common import M_TO_CM, as_mesh

logger = logging.getLogger(__name__)

Align = Literal["translation_scale", "none", "rigid"]
Convention = Literal["moho", "raw"]

#: divisor applied to the cm^2 Chamfer sum under each convention
CHAMFER_DIVISOR = {"moho": 10.0, "raw": 1.0}


@dataclass(frozen=True)
class Alignment:
    """Similarity applied to the prediction: ``x_aligned = scale * R @ x + translation``.

    Attributes:
        mode (str): "none", "translation_scale" or "rigid".
        scale (float): Uniform scale (1 for "none" and "rigid").
        rotation ((3, 3) float): Rotation (identity unless "rigid").
        translation ((3,) float): Translation in metres.
        iterations (int): ICP iterations run.
    """

    mode: str
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    iterations: int = 0

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) metres -> (N, 3) metres."""
        return self.scale * points @ self.rotation.T + self.translation


@dataclass(frozen=True)
class ObjectMetrics:
    """Object metrics of one prediction against its ground truth.

    Attributes:
        chamfer (float): Chamfer distance, squared cm (divided by 10 under the "moho" convention).
        fscore, precision, recall (dict[float, float]): Keyed by threshold in millimetres; values in
            [0, 1]. Precision: fraction of predicted samples within the threshold of the ground
            truth; recall: the converse.
        alignment (Alignment): The transform applied to the prediction before measuring.
        convention (str): "moho" or "raw".
        n_samples (int): Surface samples per mesh.
    """

    chamfer: float
    fscore: dict[float, float]
    precision: dict[float, float]
    recall: dict[float, float]
    alignment: Alignment
    convention: str
    n_samples: int

    def f_at(self, threshold_mm: float) -> float:
        """F-score at ``threshold_mm`` (must be one of the thresholds measured)."""
        key = float(threshold_mm)
        if key not in self.fscore:
            raise InvalidInputError(
                f"F-score at {threshold_mm} mm was not computed; available: {sorted(self.fscore)}"
            )
        return self.fscore[key]


def sample_surface(mesh, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points sampled uniformly by area on a mesh surface (metres, deterministic)."""
    import trimesh

    m = as_mesh(mesh, "mesh")
    pts, _ = trimesh.sample.sample_surface(m, int(n), seed=seed)
    return np.asarray(pts, dtype=np.float64)


def _rms_radius(points: np.ndarray) -> float:
    return float(np.sqrt(((points - points.mean(0)) ** 2).sum(1).mean()))


def align_points(
    source: np.ndarray,
    target: np.ndarray,
    mode: Align = "translation_scale",
    max_iterations: int = 50,
    tol: float = 1e-9,
) -> Alignment:
    """Align a point set to another by ICP (private stand-in for ``easyhoi.geometry.icp``).

    Args:
        source, target ((N, 3), (M, 3) float): Points in metres; ``source`` is moved onto
            ``target``.
        mode ({"translation_scale", "rigid", "none"}): "translation_scale": initialise by matching
            centroid and RMS radius, then iterate nearest-neighbour correspondences with the
            closed-form uniform scale + translation. "rigid": initialise by matching centroids, then
            rotation + translation (Kabsch).
        max_iterations (int): ICP iteration cap.
        tol (float): Stop when the mean squared correspondence distance (m^2) improves by less than
            this.

    Returns:
        Alignment
    """
    eye = np.eye(3)
    if mode == "none":
        return Alignment("none", 1.0, eye, np.zeros(3))
    if mode not in ("translation_scale", "rigid"):
        raise InvalidInputError(
            f"align must be 'translation_scale', 'rigid' or 'none', got {mode!r}"
        )
    tree = cKDTree(target)
    mu_s, mu_t = source.mean(0), target.mean(0)
    s, R = 1.0, eye
    if mode == "translation_scale":
        rs = _rms_radius(source)
        if rs <= 0:
            raise InvalidInputError("prediction is degenerate: its samples have zero RMS radius")
        s = _rms_radius(target) / rs
    t = mu_t - s * mu_s
    prev = np.inf
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007
        moved = s * source @ R.T + t
        d, idx = tree.query(moved, workers=1)
        err = float((d**2).mean())
        if prev - err < tol:
            break
        prev = err
        corr = target[idx]
        mc = corr.mean(0)
        if mode == "translation_scale":
            # minimise sum |s p + t - q|^2 over s, t (p are the ORIGINAL source points)
            ps = source - mu_s
            s = float((ps * (corr - mc)).sum() / (ps**2).sum())
            t = mc - s * mu_s
        else:
            ms = moved.mean(0)
            H = (moved - ms).T @ (corr - mc)
            U, _, Vt = np.linalg.svd(H)
            D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
            dR = Vt.T @ D @ U.T
            R = dR @ R
            t = dR @ (t - ms) + mc
    return Alignment(mode, float(s), R, t, iterations=it)


def chamfer_fscore(
    pred_mesh,
    gt_mesh,
    n_samples: int = 30000,
    seed: int = 0,
    align: Align = "translation_scale",
    convention: Convention = "moho",
    thresholds_mm: Sequence[float] = (5, 10),
) -> ObjectMetrics:
    """Chamfer distance and F-scores between a predicted and a ground-truth object mesh.

    Args:
        pred_mesh, gt_mesh (trimesh.Trimesh or (vertices (V, 3), faces (F, 3))): Meshes in metres.
        n_samples (int): Points sampled on each surface (30,000 in the published protocol).
        seed (int): Sampling seed, used for both meshes (identical meshes then give exactly 0).
        align ({"translation_scale", "none", "rigid"}): Alignment of the prediction to the ground
            truth before measuring (see module doc).
        convention ({"moho", "raw"}): "moho": cm^2 sum divided by 10 (MOHO / EasyHOI); "raw": cm^2
            sum (gSDF, AlignSDF).
        thresholds_mm (sequence of float): F-score thresholds in millimetres.

    Returns:
        ObjectMetrics
    """
    if convention not in CHAMFER_DIVISOR:
        raise InvalidInputError(f"convention must be 'moho' or 'raw', got {convention!r}")
    if int(n_samples) < 1:
        raise InvalidInputError(f"n_samples must be >= 1, got {n_samples}")
    thresholds = [float(t) for t in thresholds_mm]
    if not thresholds or any(not (t > 0) for t in thresholds):
        raise InvalidInputError(f"thresholds_mm must be positive numbers, got {thresholds_mm}")
    gt_pts = sample_surface(as_mesh(gt_mesh, "gt_mesh"), n_samples, seed)
    pred_pts = sample_surface(as_mesh(pred_mesh, "pred_mesh"), n_samples, seed)
    alignment = align_points(pred_pts, gt_pts, align)
    pred_pts = alignment.apply(pred_pts)

    d_gp = cKDTree(pred_pts).query(gt_pts, workers=1)[0] * M_TO_CM  # gt -> pred, cm
    d_pg = cKDTree(gt_pts).query(pred_pts, workers=1)[0] * M_TO_CM  # pred -> gt, cm
    chamfer = float((d_gp**2).mean() + (d_pg**2).mean()) / CHAMFER_DIVISOR[convention]

    fs, ps, rs = {}, {}, {}
    for thr in thresholds:
        thr_cm = thr / 10.0
        p = float((d_pg < thr_cm).mean())
        r = float((d_gp < thr_cm).mean())
        ps[thr], rs[thr] = p, r
        fs[thr] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    logger.debug("chamfer=%.4g (%s) fscore=%s align=%s", chamfer, convention, fs, alignment)
    return ObjectMetrics(chamfer, fs, ps, rs, alignment, convention, int(n_samples))


@dataclass(frozen=True)
class FScoreSummary:
    """Mean F-score over a dataset, with and without the reference evaluation's skipping.

    Attributes:
        mean_all (float): Mean over every sample.
        mean_skip_zero (float): Mean over samples whose F-score is not 0 (the reference evaluation
            skips samples with F@5 = 0); NaN when every sample is 0.
        n_total, n_skipped (int): Number of samples and of samples with F = 0.
    """

    mean_all: float
    mean_skip_zero: float
    n_total: int
    n_skipped: int


def aggregate_fscore(
    results: Iterable[ObjectMetrics | float], threshold_mm: float = 5.0
) -> FScoreSummary:
    """Aggregate F-scores at ``threshold_mm`` with and without skipping zero samples.

    Args:
        results (iterable of ObjectMetrics or float): Per-sample results (or per-sample F-scores
            directly).
        threshold_mm (float): Threshold whose F-score is aggregated (5 mm in the reference skipping
            rule).

    Returns:
        FScoreSummary
    """
    vals = np.array(
        [r.f_at(threshold_mm) if isinstance(r, ObjectMetrics) else float(r) for r in results],
        dtype=np.float64,
    )
    if vals.size == 0:
        raise InvalidInputError("aggregate_fscore needs at least one result, got 0")
    if not np.isfinite(vals).all():
        raise InvalidInputError("F-scores contain NaN or infinite values")
    nonzero = vals[vals != 0]
    skip = float(nonzero.mean()) if nonzero.size else float("nan")
    return FScoreSummary(float(vals.mean()), skip, int(vals.size), int(vals.size - nonzero.size))
