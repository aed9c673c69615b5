"""The hand's own colour model and the visible hand mask.

Skin colour differs between people, light and cameras, so no fixed skin range is used. The
21 keypoints say where the fingers are: the pixels under the thin bones of the skeleton are the
hand in almost every photo (a finger drawn over an object it hides is the exception, and the
robust statistics below ignore such a minority). A robust Gaussian in Lab fitted to them is the
skin model of *this* photo and *this* hand; a region that matches it is skin (the hand itself, the
forearm, the other hand or a face), not a held object.

Hand mask M_h (GrabCut seeded by the skeleton):
  * L = palm length (wrist -> middle MCP); S = hand scale, the larger of L and the palm width
    (index MCP -> pinky MCP) / ``PALM_WIDTH_RATIO`` (:func:`hand_scale`). A palm tilted about
    its width looks short while the fingers keep their width; one tilted about its length looks
    narrow: the larger of the two is the less foreshortened measure of the hand's size.
  * Bones drawn ``0.3 L`` wide and the palm polygon (wrist, thumb CMC, index/middle/ring/pinky
    MCP) filled: "probably foreground" (kept narrow: GrabCut starts these pixels as hand, and an
    object pressed against the fingers must not start as hand).
  * Thin bone cores (``0.08 L``) and the eroded palm that match the colour model: "sure
    foreground" (occluded fingers drawn over an object do not match and stay "probable").
    Farther than ``HAND_REACH`` S from the wide skeleton: "sure background" (in S: how far
    GrabCut may grow the hand follows the hand's true size).
  * GrabCut refines; pixels farther than 4 sigma from the colour model, or 3 sigma in chroma
    alone, are dropped (bone cores excepted); the component(s) overlapping the cores are kept,
    and the forearm is cut at ``0.25 L`` behind the wrist (the hand model ends at the wrist).
"""

from __future__ import annotations

import cv2
import numpy as np

#: Bones of the 21-keypoint OpenPose hand (parent, child): wrist -> finger base, then along.
BONES = tuple((0 if j % 4 == 1 else j - 1, j) for j in range(1, 21))
#: Palm polygon: wrist, thumb CMC, index, middle, ring, pinky MCP.
PALM = (0, 1, 5, 9, 13, 17)
#: Squared normalised colour distance below which a pixel matches the skin model (3 sigma).
SKIN_D2 = 9.0
#: Looser bound (4 sigma) a hand-mask pixel must meet: shading and blur widen the hand's colours.
SKIN_LOOSE = 16.0
#: Farthest a hand pixel lies outside the 0.3 L wide skeleton, in hand scales S: a finger is
#: about 0.2 S wide, so this leaves room for keypoint error without taking in a held object.
HAND_REACH = 0.3
#: Palm width (index MCP -> pinky MCP) / palm length (wrist -> middle MCP) of an adult hand
#: seen square to the camera (about 0.75-0.85); the upper end, so S never exceeds the true size.
PALM_WIDTH_RATIO = 0.85


def palm_length(kp: np.ndarray) -> float:
    """Wrist-to-middle-MCP distance of (21, 2) keypoints (floored at 1 px)."""
    return max(1.0, float(np.linalg.norm(kp[9] - kp[0])))


def hand_scale(kp: np.ndarray) -> float:
    """Size of the hand in px: the larger of the palm length and the palm width /
    ``PALM_WIDTH_RATIO`` of (21, 2) keypoints (see the module docstring)."""
    return max(palm_length(kp), float(np.linalg.norm(kp[5] - kp[17])) / PALM_WIDTH_RATIO)


def draw_skeleton(shape: tuple[int, int], kp: np.ndarray, width: float, palm: bool) -> np.ndarray:
    """(H, W) bool raster of the bones of (21, 2) keypoints ``width`` px wide (+ palm polygon)."""
    canvas = np.zeros(shape, np.uint8)
    w = max(1, int(round(width)))
    pts = np.round(kp).astype(np.int32)
    for a, b in BONES:
        cv2.line(canvas, tuple(map(int, pts[a])), tuple(map(int, pts[b])), 1, w, cv2.LINE_8)
    if palm:
        cv2.fillPoly(canvas, [pts[list(PALM)]], 1)
    return canvas.astype(bool)


def hand_axis(shape: tuple[int, int], kp: np.ndarray) -> np.ndarray:
    """(H, W) coordinate of every pixel along the wrist -> middle-MCP axis, 0 at the wrist."""
    L = palm_length(kp)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    axis = (kp[9] - kp[0]) / L
    return (xx - kp[0, 0]) * axis[0] + (yy - kp[0, 1]) * axis[1]


class ColourModel:
    """Robust Gaussian in Lab fitted to sample pixels (median and 1.4826 x MAD per channel).

    The lightness spread is floored at 25 (shading varies across a hand) and the chroma spread
    at ``min_sigma``.
    """

    def __init__(self, lab_samples: np.ndarray, min_sigma: float = 6.0):
        self.mu = np.median(lab_samples, axis=0)
        mad = np.median(np.abs(lab_samples - self.mu), axis=0) * 1.4826
        self.sigma = np.maximum(mad, min_sigma)
        self.sigma[0] = max(self.sigma[0], 25.0)

    def d2(self, lab: np.ndarray) -> np.ndarray:
        """Squared normalised distance of every pixel to the model (< SKIN_D2: skin)."""
        return (((lab - self.mu) / self.sigma) ** 2).sum(-1)

    def chroma_d2(self, lab: np.ndarray) -> np.ndarray:
        """Squared normalised distance in chroma (a*, b*) alone."""
        return (((lab[..., 1:] - self.mu[1:]) / self.sigma[1:]) ** 2).sum(-1)


def skin_model(lab: np.ndarray, kp: np.ndarray) -> ColourModel:
    """The colour model of the hand with (21, 2) keypoints in a Lab image."""
    L = palm_length(kp)
    shape = lab.shape[:2]
    samples = lab[draw_skeleton(shape, kp, 0.12 * L, palm=False)]
    if len(samples) < 10:
        samples = lab[draw_skeleton(shape, kp, 0.3 * L, palm=True)]
    if len(samples) < 1:
        samples = lab.reshape(-1, 3)
    return ColourModel(samples)


def grabcut(img: np.ndarray, init: np.ndarray, iterations: int, seed: int) -> np.ndarray:
    """GrabCut from an initial label map; (h, w) bool foreground. Its colour models start from
    :func:`gmm_model` of each side of ``init`` (``seed``: the k-means runs' random draw)."""
    fg = (init == cv2.GC_FGD) | (init == cv2.GC_PR_FGD)
    if not fg.any():
        return np.zeros(init.shape, bool)
    if not ((init == cv2.GC_BGD) | (init == cv2.GC_PR_BGD)).any():
        return np.ones(init.shape, bool)
    m = init.copy()
    bgd = gmm_model(img[~fg], seed)
    fgd = gmm_model(img[fg], seed)
    if bgd is None or fgd is None:
        cv2.setRNGSeed(seed)
        bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
        cv2.grabCut(img, m, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    else:
        cv2.grabCut(img, m, None, bgd, fgd, iterations, cv2.GC_EVAL)
    return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)


#: Colour clusters of a GrabCut model (OpenCV's fixed component count).
GMM_COMPONENTS = 5
#: k-means starts of :func:`gmm_model`; the most compact clustering is kept.
GMM_ATTEMPTS = 8
#: Samples the model is made of at most (a regular subsample).
GMM_SAMPLES = 2000


def gmm_model(samples: np.ndarray, seed: int) -> np.ndarray | None:
    """GrabCut's (1, 65) colour model of ``samples`` (N, 3): weights, means, covariances of
    :data:`GMM_COMPONENTS` clusters, from the most compact of :data:`GMM_ATTEMPTS` k-means runs
    on a regular subsample of at most :data:`GMM_SAMPLES`.

    OpenCV's own initialisation runs k-means once from a random start; which of several similar
    colour clusterings it lands in then decides where GrabCut draws its outline, so the result
    depends on the random draw. The most compact of several starts is a far more repeatable
    clustering. The model only starts GrabCut: its first iteration assigns every pixel to a
    component and learns the components from all of them, so the subsample suffices. None when
    there are fewer than two samples per cluster (OpenCV's own start is used then).
    """
    x = np.asarray(samples, dtype=np.float32).reshape(-1, 3)
    k = GMM_COMPONENTS
    if len(x) < 2 * k:
        return None
    x = x[:: max(1, len(x) // GMM_SAMPLES)]
    cv2.setRNGSeed(seed)
    crit = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 10, 0.0)
    _, labels, _ = cv2.kmeans(x, k, None, crit, GMM_ATTEMPTS, cv2.KMEANS_PP_CENTERS)
    x, lab = x.astype(np.float64), labels.ravel()
    weights, means, covs = np.zeros(k), np.zeros((k, 3)), np.zeros((k, 3, 3))
    for j in range(k):
        xj = x[lab == j]
        if len(xj) == 0:
            continue
        weights[j] = len(xj) / len(x)
        means[j] = xj.mean(0)
        d = xj - means[j]
        cov = d.T @ d / len(xj)
        if np.linalg.eigvalsh(cov).min() < 1e-3:
            # a cluster of one or two colours (flat or drawn areas) is singular or nearly so,
            # which GrabCut refuses: OpenCV's own regularisation, 0.01 on the diagonal
            cov = cov + 0.01 * np.eye(3)
        covs[j] = cov
    return np.concatenate([weights, means.ravel(), covs.ravel()])[None, :]


def components(mask: np.ndarray, min_area: int = 1) -> list[np.ndarray]:
    """8-connected components of a bool mask with at least ``min_area`` pixels."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return [lab == i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= min_area]


def components_at(mask: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """The 8-connected components of ``mask`` that contain a pixel of ``seed`` (all False when
    none does)."""
    n, cc = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    keep = np.unique(cc[seed & mask])
    return np.isin(cc, keep[keep > 0])


def hand_mask(
    img: np.ndarray,
    lab: np.ndarray,
    kp: np.ndarray,
    d2: np.ndarray,
    iterations: int,
    seed: int,
    not_hand: np.ndarray | None = None,
) -> np.ndarray:
    """(h, w) bool visible hand mask (see the module docstring); ``d2`` from the skin model.

    ``not_hand`` pixels (the user's object points) are sure background: GrabCut then learns the
    object's colours from them and keeps a skin-coloured object the fingers cover out of the
    hand."""
    shape = img.shape[:2]
    L, S = palm_length(kp), hand_scale(kp)
    core = draw_skeleton(shape, kp, 0.08 * L, palm=False)
    wide = draw_skeleton(shape, kp, 0.3 * L, palm=True)
    dist = cv2.distanceTransform((~wide).astype(np.uint8), cv2.DIST_L2, 5)
    init = np.full(shape, cv2.GC_PR_BGD, np.uint8)
    init[dist > HAND_REACH * S] = cv2.GC_BGD
    init[wide] = cv2.GC_PR_FGD
    init[wide & (d2 > 25.0)] = cv2.GC_PR_BGD
    palm_core = cv2.erode(
        draw_skeleton(shape, kp, 1, palm=True).astype(np.uint8),
        cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (int(0.3 * L) | 1,) * 2),
    ).astype(bool)
    init[(core | palm_core) & (d2 < SKIN_D2)] = cv2.GC_FGD
    if not_hand is not None:
        init[not_hand] = cv2.GC_BGD
    fg = grabcut(img, init, iterations, seed)
    # GrabCut's colour mixture also takes an object the fingers press on when its colour is
    # closer to the hand's than to the crop's background; the hand is skin wherever it is not
    # drawn over something (the bone cores are kept: a finger may cross an object). Shading
    # moves a hand's colours along lightness, so the lightness spread is wide; the chroma of
    # skin stays, and a pale neutral surface (paper, a screen, a white cup) that passes the
    # joint bound on its lightness is still off the hand's chroma
    skin = (d2 < SKIN_LOOSE) & (skin_model(lab, kp).chroma_d2(lab) < SKIN_D2)
    fg &= skin | core | palm_core
    if not_hand is not None:
        fg &= ~not_hand
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    fg &= hand_axis(shape, kp) > -0.25 * L  # forearm cut: the hand model ends at the wrist
    keep = [c for c in components(fg) if (c & (core | palm_core)).any()]
    return np.any(keep, axis=0) if keep else (fg & wide)


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool ``mask`` with enclosed background regions filled."""
    m = np.pad(mask.astype(np.uint8), 1)
    flood = m.copy()
    cv2.floodFill(flood, np.zeros((m.shape[0] + 2, m.shape[1] + 2), np.uint8), (0, 0), 1)
    return (m | (1 - flood)).astype(bool)[1:-1, 1:-1]
