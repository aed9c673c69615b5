"""Prompted held-object segmentation: the object is the region containing the user's points
or filling the user's box.

Points alone go to :func:`clicked_object`: candidates grown from the points by GrabCut and the
region proposals that contain them, scored together (:mod:`easyhoi.perception.click`).

With a box (and optional points), hypotheses of the proposal hierarchy must lie mostly inside
the box and contain every point; they are favoured by how well they fill it (share of the region
inside the box times share of the box it covers) and ranked by :func:`prompt_score` (outline
contrast, solidity, size, not another hand). The best distinct levels (up to four) each seed
GrabCut with the points as sure foreground, the hands and everything outside the box as sure
background (GrabCut's colour mixtures gather the parts of a textured object the proposals
split); the refined masks are scored again, the best one is kept, restricted to the parts that
contain the points.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from easyhoi.perception import held_object as ho
from easyhoi.perception.click import click_object, click_proposals
from easyhoi.perception.not_object import encloses, enclosing_regions
from easyhoi.perception.proposals import Proposals
from easyhoi.perception.skin import components_at, fill_holes


def _point_disks(shape: tuple[int, int], pts: np.ndarray, radius: float) -> np.ndarray:
    out = np.zeros(shape, np.uint8)
    for u, v in pts:
        cv2.circle(out, (int(round(u)), int(round(v))), max(1, int(round(radius))), 1, -1)
    return out.astype(bool)


#: Weights of the prompted score: the user vouches that the object is there, so the grasp cues
#: drop out and what remains is whether the region is a whole object: a closed outline with
#: contrast, compact, not another hand, of a size people hold (a wider range than automatic: the
#: user may point at a large or a tiny object). Skin colour and the picture's edge weigh little:
#: the user may point at a beige object or one that runs out of the photo.
PROMPT_WEIGHTS = {
    "contrast": 3.0,
    "solidity": 1.0,
    "skin": -1.0,
    "other_hand": -3.0,
    "border": -0.2,
    "size": -3.0,
}
PROMPT_AREA = (0.02, 4.0)


def prompt_score(cues: np.ndarray) -> np.ndarray:
    """Score of hypotheses containing the prompt (higher: more likely the whole object)."""
    c = {k: cues[:, j] for j, k in enumerate(ho.CUES)}
    lo, hi = PROMPT_AREA
    area = np.maximum(c["area"], 1e-6)
    w = PROMPT_WEIGHTS
    return (
        w["contrast"] * c["contrast"]
        + w["solidity"] * c["solidity"]
        + w["skin"] * c["skin"]
        + w["other_hand"] * c["other_hand"]
        + w["border"] * np.minimum(c["border"], 3.0)
        + w["size"] * np.abs(np.log(area / np.clip(area, lo, hi)))
    )


def prompted_object(
    img: np.ndarray,
    props: Proposals,
    scene: ho.Scene,
    points: np.ndarray,
    box: tuple[float, float, float, float],
    iterations: int,
    seed: int,
) -> tuple[np.ndarray, ho.Hypotheses | None, int | None]:
    """(object mask, hypotheses, index of the chosen one) in working-crop pixels.

    ``box`` (u0, v0, u1, v1) and the optional ``points`` (N, 2) (u, v) are in working-crop
    pixels. Points without a box go to :func:`clicked_object` instead.
    """
    shape = img.shape[:2]
    h, w = shape
    L = scene.palm
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = np.clip(pts, 0, [w - 1, h - 1])
    sure = _point_disks(shape, pts, max(1.0, 0.04 * L))
    forbidden = (scene.hand | scene.other_hands) & ~sure
    u0, v0, u1, v1 = (int(round(b)) for b in box)
    boxmask = np.zeros(shape, bool)
    boxmask[max(0, v0) : max(0, v1), max(0, u0) : max(0, u1)] = True
    if not props.regions:
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), None, None
    cues = ho.describe(props, scene)
    n = len(props.regions)
    ok = np.ones(n, bool)
    labels_at = [int(props.labels[int(v), int(u)]) for u, v in pts]
    for lab in labels_at:
        if lab >= 0:
            ok &= np.array([lab in r for r in props.regions])
    fit = np.zeros(n)
    inside = ho.segment_sums(props.labels, boxmask, props.n_base)
    box_area = max(1.0, float(boxmask.sum()))
    for i, r in enumerate(props.regions):
        idx = np.fromiter(r, int, len(r))
        a_in = float(inside[idx].sum())
        size = float(props.sizes[idx].sum())
        fit[i] = (a_in / max(size, 1.0)) * (a_in / box_area)
    ok &= fit > 0.05
    ok &= ~enclosing_regions(props, scene.background_rings)
    if not ok.any():
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), None, None
    exclude = cv2.dilate(forbidden.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    codes = ho.colour_codes(scene.lab)
    width = max(3, int(0.2 * L))
    j, k = ho.CUES.index("contrast"), ho.CUES.index("solidity")
    cand = np.flatnonzero(ok)
    if len(cand) > 40:  # the largest chains: keep the 40 best by the cheap cues
        cand = cand[np.argsort(-prompt_score(cues[cand]) - 4.0 * fit[cand], kind="stable")[:40]]
    for i in cand:
        m = props.mask(props.regions[i])
        cues[i, j] = ho.outline_contrast(m, exclude, codes, width)
        cues[i, k] = ho.solidity(m)
    s = prompt_score(cues) + 4.0 * fit
    s = np.where(np.isin(np.arange(n), cand), s, -np.inf)
    hyp = ho.Hypotheses(props, cues, s)
    forbidden = forbidden | ~boxmask
    # the proposals break textured objects into parts: each of the best distinct levels seeds
    # GrabCut (whose colour mixtures gather an object's several colours), and the refined
    # masks are scored again
    best, obj, best_s = None, None, -np.inf
    seeds = [
        (i, (props.mask(props.regions[i]) | sure) & ~forbidden) for i in ho.distinct_best(hyp, 4)
    ]
    for i, raw in seeds:
        m = ho.refine(
            img, raw, forbidden, iterations, seed, sure=sure, margin=0.5 * L, fallback=False
        ) | (sure & ~forbidden)
        m = fill_holes(m) & ~forbidden
        if sure.any():  # the object is the part that contains the user's points
            m = components_at(m, sure)
        if encloses(m, scene.background_rings):
            continue
        c = ho.mask_cues(m, scene)[None]
        a_in = float((m & boxmask).sum())
        f = (a_in / max(1.0, float(m.sum()))) * (a_in / max(1.0, float(boxmask.sum())))
        sc = float(prompt_score(c)[0]) + 4.0 * f
        if sc > best_s:
            best, obj, best_s = i, m, sc
    if obj is None:  # every refined level took in a background point
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), hyp, None
    return obj, hyp, best


def clicked_object(
    img: np.ndarray,
    scene: ho.Scene,
    points: np.ndarray,
    make_proposals: Callable[[], Proposals],
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
) -> tuple[np.ndarray, ho.Hypotheses, int | None, Proposals | None, float | None]:
    """The object from object points alone.

    The candidates are the GrabCut masks grown from the first point
    (:func:`easyhoi.perception.click.click_candidates`) and every region proposal containing it,
    from ``make_proposals`` and from a finer segmentation of the crop
    (:func:`easyhoi.perception.click.click_proposals`); :func:`click_object` keeps the best.

    Args:
        img (np.ndarray): (h, w, 3) uint8 RGB working crop.
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.
        points (np.ndarray): (N, 2) object points (u, v) in crop pixels.
        make_proposals (Callable[[], Proposals]): Makes the region proposals of the crop.
        iterations (int): GrabCut iterations.
        seed (int): Seed of OpenCV's RNG.
        inside (tuple | None): Whether the photo goes on beyond the crop's left, top, right
            and bottom side (the ``frame`` cue of :func:`easyhoi.perception.click.click_score`;
            None: the crop is the whole photo).

    Returns:
        tuple: (h, w) bool object mask, the hypotheses (the output mask alone), the index of
        the chosen one, the proposals, and the first click's score margin over another region
        (:func:`easyhoi.perception.click.click_margin`; None when there is none).
    """
    h, w = img.shape[:2]
    pts = np.clip(np.asarray(points, np.float64).reshape(-1, 2), 0, [w - 1, h - 1])
    props = make_proposals()
    fallback = click_proposals(img, scene, pts[0], props)
    obj, _, margin = click_object(img, scene, pts, fallback, iterations, seed, inside)
    return obj, mask_hypothesis(obj, scene), 0, props, margin


def mask_hypothesis(mask: np.ndarray, scene: ho.Scene) -> ho.Hypotheses:
    """Hypotheses holding one mask, with its cues and prompted score."""
    props = Proposals(
        labels=np.where(mask, 0, -1),
        regions=(frozenset((0,)),),
        sizes=np.array([float(mask.sum())]),
    )
    cues = ho.mask_cues(mask, scene)[None]
    return ho.Hypotheses(props, cues, prompt_score(cues))


def _grabcut_only(img, sure, boxmask, forbidden, iterations, seed) -> np.ndarray:
    """GrabCut from the prompts alone (no proposal contains them)."""
    from easyhoi.perception.skin import grabcut

    init = np.full(img.shape[:2], cv2.GC_PR_BGD, np.uint8)
    if boxmask is not None:
        init[~boxmask] = cv2.GC_BGD
        init[boxmask] = cv2.GC_PR_FGD
    init[forbidden] = cv2.GC_BGD
    init[sure] = cv2.GC_FGD
    return grabcut(img, init, iterations, seed) & ~forbidden
