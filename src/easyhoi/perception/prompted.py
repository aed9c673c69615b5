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
split). A fifth candidate is GrabCut of the box alone, seen at the box's own resolution
(:func:`box_grabcut`). The candidates are scored again, now by how tightly the box fits them
(:func:`box_tightness`) in place of the size range, and the best one is kept, restricted to the
parts that contain the points. A box drawn round an object touches it on every side, whatever
its shape or size relative to the hand; a background point inside the box says the box holds
more than the object, and then the area fit and the size range score them as for the seeds.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from easyhoi.geometry.masks import mask_iou
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


def prompt_score(cues: np.ndarray, sized: bool = True) -> np.ndarray:
    """Score of hypotheses containing the prompt (higher: more likely the whole object).
    ``sized=False`` leaves out the size range (a box says how large the object is)."""
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
        + (w["size"] * np.abs(np.log(area / np.clip(area, lo, hi))) if sized else 0.0)
    )


def box_tightness(mask: np.ndarray, box: tuple[int, int, int, int]) -> float:
    """How well ``mask`` fills the user's box (u0, v0, u1, v1) as an object drawn round by it
    does: the share of the mask inside the box times the IoU of the mask's bounding box with
    the box. A box drawn round an object touches it on every side whatever its shape (a pen
    lying diagonally fills a few per cent of its box and still spans it), so the bounding
    box, not the area covered, is what the box says."""
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return 0.0
    u0, v0, u1, v1 = box
    a0, b0, a1, b1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
    iw = max(0, min(a1, u1) - max(a0, u0))
    ih = max(0, min(b1, v1) - max(b0, v0))
    inter = iw * ih
    union = (a1 - a0) * (b1 - b0) + (u1 - u0) * (v1 - v0) - inter
    inside = float(mask[max(0, v0) : max(0, v1), max(0, u0) : max(0, u1)].sum()) / len(xs)
    return inside * inter / max(union, 1)


def prompted_object(
    img: np.ndarray,
    props: Proposals,
    scene: ho.Scene,
    points: np.ndarray,
    box: tuple[float, float, float, float],
    iterations: int,
    seed: int,
    box_cut: Callable[[], np.ndarray] | None = None,
) -> tuple[np.ndarray, ho.Hypotheses | None, int | None, int]:
    """(object mask, hypotheses, index of the chosen one, agreement) in working-crop pixels.

    ``box`` (u0, v0, u1, v1) and the optional ``points`` (N, 2) (u, v) are in working-crop
    pixels. Points without a box go to :func:`clicked_object` instead. ``box_cut`` returns one
    more candidate, GrabCut of the box alone at the box's own resolution (:func:`box_grabcut`,
    in working-crop pixels); it competes with the proposal-seeded ones by the same score. The
    agreement is how many of the other candidates reach the chosen outline (IoU >= 0.5): they
    start from different regions, so several arriving at one outline is what the photo shows,
    and one standing alone is a guess (:func:`easyhoi.perception.seg_confidence.
    object_confidence`).
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
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), None, None, 0
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
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), None, None, 0
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
    # A box drawn round an object touches it on every side, which says more than the region's
    # size or how much of the box it covers; unless the user has marked background inside the
    # box, which says the box holds more than the object
    tight = not any((r & boxmask).any() for r in scene.background_rings)
    # the proposals break textured objects into parts: each of the best distinct levels seeds
    # GrabCut (whose colour mixtures gather an object's several colours), and the refined
    # masks are scored again
    best, obj, best_s, scored = None, None, -np.inf, []
    seeds = [
        (i, (props.mask(props.regions[i]) | sure) & ~forbidden) for i in ho.distinct_best(hyp, 4)
    ]
    cands = [
        (i, ho.refine(img, raw, forbidden, iterations, seed, sure=sure, margin=0.5 * L,
                      fallback=False))
        for i, raw in seeds
    ]  # fmt: skip
    if box_cut is not None:  # the box's own GrabCut (no proposal: index None)
        cands.append((None, box_cut()))
    for i, m in cands:
        m = fill_holes(m | (sure & ~forbidden)) & ~forbidden
        if sure.any():  # the object is the part that contains the user's points
            m = components_at(m, sure)
        if not m.any() or encloses(m, scene.background_rings):
            continue
        c = ho.mask_cues(m, scene)[None]
        if tight:
            f = box_tightness(m, (u0, v0, u1, v1))
        else:
            a_in = float((m & boxmask).sum())
            f = (a_in / max(1.0, float(m.sum()))) * (a_in / max(1.0, float(boxmask.sum())))
        sc = float(prompt_score(c, sized=not tight)[0]) + 4.0 * f
        scored.append(m)
        if sc > best_s:
            best, obj, best_s = i, m, sc
    if obj is None:  # every refined level took in a background point
        return _grabcut_only(img, sure, boxmask, forbidden, iterations, seed), hyp, None, 0
    agree = sum(m is not obj and mask_iou(m, obj, empty=0.0) >= 0.5 for m in scored)
    if best is None:  # the box's own GrabCut won: it is no proposal, so it stands alone
        return obj, mask_hypothesis(obj, scene), 0, agree
    return obj, hyp, best, agree


def box_grabcut(
    image: np.ndarray,
    box: tuple[float, float, float, float],
    points: np.ndarray,
    excl_at: Callable[[tuple[int, int, int, int], tuple[int, int]], np.ndarray],
    side: int,
    iterations: int,
    seed: int,
) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """GrabCut of a user's box at the box's own resolution: (window, mask in the window).

    The window is the box grown by half its size on every side (GrabCut's background colours
    come from around the object, not from the whole hand crop), resampled to ``side`` pixels on
    its longer side, so that a small box is seen at the detail a box drawn on a large object
    gets. Everything outside the box is sure background, as are the hands (``excl_at(window,
    (w, h))``: the hands and other excluded pixels resampled to the window); the points
    (N, 2, photo pixels) are sure object.

    Args:
        image (np.ndarray): (H, W, 3) uint8 RGB photo.
        box (tuple): (x0, y0, x1, y1) in photo pixels.
        points (np.ndarray): (N, 2) object points (x, y) in photo pixels (may be empty).
        excl_at (Callable): The excluded pixels over a window (x0, y0, x1, y1) at a size (w, h).
        side (int): Longer side of the resampled window.
        iterations (int): GrabCut iterations.
        seed (int): Seed of OpenCV's RNG.

    Returns:
        tuple: The window (x0, y0, x1, y1) in photo pixels and the (h, w) bool object mask at
        the window's resampled size.
    """
    from easyhoi.perception.skin import grabcut

    H, W = image.shape[:2]
    bx0, by0, bx1, by1 = box
    gx, gy = 0.5 * (bx1 - bx0), 0.5 * (by1 - by0)
    x0, y0 = max(0, int(np.floor(bx0 - gx))), max(0, int(np.floor(by0 - gy)))
    x1, y1 = min(W, int(np.ceil(bx1 + gx))), min(H, int(np.ceil(by1 + gy)))
    s = side / max(x1 - x0, y1 - y0)
    size = (max(8, round((x1 - x0) * s)), max(8, round((y1 - y0) * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    img = np.ascontiguousarray(cv2.resize(image[y0:y1, x0:x1], size, interpolation=interp))
    sx, sy = size[0] / (x1 - x0), size[1] / (y1 - y0)
    init = np.full(img.shape[:2], cv2.GC_BGD, np.uint8)
    u0, v0 = int(np.floor((bx0 - x0) * sx)), int(np.floor((by0 - y0) * sy))
    u1, v1 = int(np.ceil((bx1 - x0) * sx)), int(np.ceil((by1 - y0) * sy))
    init[max(0, v0) : v1, max(0, u0) : u1] = cv2.GC_PR_FGD
    excl = excl_at((x0, y0, x1, y1), size)
    init[excl] = cv2.GC_BGD
    pts = (np.asarray(points, np.float64).reshape(-1, 2) - [x0, y0]) * [sx, sy]
    sure = _point_disks(init.shape, pts, max(1.0, 0.01 * max(size))) & ~excl
    init[sure] = cv2.GC_FGD
    return (x0, y0, x1, y1), grabcut(img, init, iterations, seed) & ~excl


def clicked_object(
    img: np.ndarray,
    scene: ho.Scene,
    points: np.ndarray,
    make_proposals: Callable[[], Proposals],
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
    choice: int = 1,
) -> tuple[np.ndarray, ho.Hypotheses, int | None, Proposals | None, float | None, list]:
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
        choice (int): The first click's distinct region that becomes the object (1: the
            best-scored; :func:`easyhoi.perception.click.distinct_regions`).

    Returns:
        tuple: (h, w) bool object mask, the hypotheses (the output mask alone), the index of
        the chosen one, the proposals, the first click's score margin over another region
        (:func:`easyhoi.perception.click.click_margin`; None when there is none or a region
        was picked), and the first click's distinct regions (the chosen one as the object
        mask).
    """
    h, w = img.shape[:2]
    pts = np.clip(np.asarray(points, np.float64).reshape(-1, 2), 0, [w - 1, h - 1])
    props = make_proposals()
    fallback = click_proposals(img, scene, pts[0], props)
    obj, _, margin, regions = click_object(
        img, scene, pts, fallback, iterations, seed, inside, choice
    )
    return obj, mask_hypothesis(obj, scene), 0, props, margin, regions


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
