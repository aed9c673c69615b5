"""One-click held-object segmentation: candidates containing the user's point, the best kept.

A click says where the object is, not how far it extends. Two generators, which fail on
different objects, give candidates that contain it:

* GrabCut grown from the click in several working windows around it: a small disk around the
  click is sure object, a larger disk probable object, the rest of the window probable
  background, the other hands, the hand's skin-coloured bone cores and everything beyond a
  margin around the window sure background (GrabCut learns the background colours there). The
  window sizes are multiples of the hand's palm length L (a held object is from a fraction of a
  hand to a few hands across), so nothing depends on the photo's resolution. Each result is the
  component containing the click (holes filled, hands removed), also joined with the pieces on
  the other side of the fingers (:func:`join_across_hand`).
* The region proposals containing the click, at two segmentation scales
  (:func:`click_proposals`): they group the differently coloured parts of an object (a lid and
  a sleeve) at which GrabCut stops.

Every candidate is scored by cues that hold for objects in photos in general
(:func:`click_score`). The best one gets back what the hand mask took of it
(:func:`take_back_from_hand`) and its outline is settled by one GrabCut seeded by it
(:func:`settle`); a mask that stops short of the hand is joined to it by what lies between
them (:func:`bridge_to_hand`: a held object touches the hand that holds it).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.masks import mask_iou
from easyhoi.perception import held_object as ho
from easyhoi.perception.not_object import encloses
from easyhoi.perception.proposals import Proposals, propose
from easyhoi.perception.skin import SKIN_D2, components_at, draw_skeleton, fill_holes, grabcut

#: Working windows: half-sides in palm lengths. From a small object next to the fingers to one
#: a few hands across.
WINDOWS = (0.6, 1.0, 1.6, 2.5)
#: Radii of the probable-object disk, as shares of the window's half-side (1.5: the whole
#: window, the classic GrabCut box).
SEED_SHARES = (0.35, 1.5)
#: GrabCut iterations per click candidate at most: grown from a sure disk in a small window,
#: GrabCut settles in a few iterations (3 and 5 pick the same objects on the development photos,
#: 3 in 60 % of the time).
CLICK_ITERATIONS = 3
#: Radius of the sure-object disk around the click, in palm lengths.
SURE = 0.06
#: Felzenszwalb scale of the finer click proposals at a 256 px crop (the automatic path's
#: is 150): a finer segmentation keeps apart an object and a background of similar colour.
FINE_SCALE = 75.0
#: Width of the hand's rim left out of the click proposals, in palm lengths: about a finger
#: and a half (a finger is about 0.2 L wide).
RIM = 0.3
#: Working windows of a further click (half-sides in palm lengths): the part it marks lies
#: within a hand or so of it.
ADD_WINDOWS = WINDOWS[:2]
#: Smallest piece joined across the hand, as a share of the clicked piece.
JOIN_MIN = 0.05
#: Width of the probable-background band of :func:`settle`, in palm lengths.
SETTLE_BAND = 0.3
#: GrabCut iterations of :func:`settle` at most.
SETTLE_ITERATIONS = 2
#: Variance added to every Lab channel of the colour Gaussians of :func:`take_back_from_hand`
#: (8-bit Lab units squared): keeps a flat-coloured sample from giving a degenerate model.
COLOUR_FLOOR = 4.0
#: Fewest pixels a colour sample of :func:`take_back_from_hand` needs.
MIN_SAMPLES = 30
#: Score weights of :func:`click_score`.
CLICK_WEIGHTS = {
    "contrast": 3.8,
    "edge": 1.4,
    "solidity": 0.2,
    "depth": 3.4,
    "window": -1.6,
    "skin": -0.55,
    "size": -0.45,
    "log_area": 0.35,
    "frame": -0.4,
}
#: Length along the crop's inner edges (those inside the photo) beyond which the ``frame`` cue
#: stops growing, in palm lengths.
FRAME_CAP = 4.0
#: Object area range, x hand area, outside which the size penalty grows with the log-ratio.
CLICK_AREA = (0.02, 4.0)
#: Largest share of what :func:`bridge_to_hand` adds that may lie outside the hull of the mask
#: and the hand's nearest pixel.
BRIDGE_OUTSIDE = 0.1
#: Candidates overlapping less than this (IoU) are other regions (:func:`distinct_regions`).
OTHER_REGION_IOU = 0.5


def _disk(shape, p, r) -> np.ndarray:
    out = np.zeros(shape, np.uint8)
    cv2.circle(out, (int(round(p[0])), int(round(p[1]))), max(1, int(round(r))), 1, -1)
    return out.astype(bool)


def edge_strength(mask: np.ndarray, grad: np.ndarray, exclude: np.ndarray) -> float:
    """Mean image gradient along the mask's outline (off ``exclude``), relative to the mean
    gradient of the whole working crop, squashed to [0, 1): an object's outline is an edge of
    the photo, a cut through a uniform region is not."""
    er = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    line = mask & ~er & ~exclude
    if line.sum() < 4:
        return 0.0
    rel = float(grad[line].mean()) / max(1e-6, float(grad.mean()))
    return rel / (1.0 + rel)


def click_score(c: dict[str, float]) -> float:
    """Score of a one-click candidate from its cues (higher: more likely the whole object)."""
    w = CLICK_WEIGHTS
    lo, hi = CLICK_AREA
    a = max(c["area"], 1e-6)
    return (
        w["contrast"] * c["contrast"]
        + w["edge"] * c["edge"]
        + w["solidity"] * c["solidity"]
        + w["depth"] * c["depth"]
        + w["window"] * c["window"]
        + w["skin"] * c["skin"]
        + w["size"] * abs(np.log(a / np.clip(a, lo, hi)))
        + w["log_area"] * np.log(a)
        + w["frame"] * min(c.get("frame", 0.0), FRAME_CAP)
    )


def inner_edges(shape: tuple[int, int], inside: tuple[bool, bool, bool, bool] | None):
    """(h, w) bool one-pixel border of the working crop on the sides that lie inside the photo.

    ``inside`` says, for the left, top, right and bottom side of the crop, whether the photo
    goes on beyond it (None: the crop is the whole photo)."""
    out = np.zeros(shape, bool)
    if inside is None:
        return out
    left, top, right, bottom = inside
    out[:, 0] |= bool(left)
    out[0, :] |= bool(top)
    out[:, -1] |= bool(right)
    out[-1, :] |= bool(bottom)
    return out


def candidate_cues(
    m: np.ndarray,
    p: np.ndarray,
    window: np.ndarray | None,
    scene: ho.Scene,
    exclude: np.ndarray,
    codes: np.ndarray,
    grad: np.ndarray,
    inner: np.ndarray | None = None,
) -> dict[str, float]:
    """Cues of one candidate mask for a click.

    Args:
        m (np.ndarray): (h, w) bool candidate mask.
        p (np.ndarray): (2,) click (u, v) in crop pixels, or (N, 2) clicks (``depth`` is then
            their mean).
        window (np.ndarray | None): (h, w) bool GrabCut window (None for a proposal).
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.
        exclude (np.ndarray): (h, w) bool pixels left out of the outline cues (the hands).
        codes (np.ndarray): (h, w) int colour bins (:func:`ho.colour_codes`).
        grad (np.ndarray): (h, w) float gradient magnitude of the lightness.
        inner (np.ndarray | None): (h, w) bool pixels of the crop's edges that lie inside the
            photo (:func:`inner_edges`; None: none do).

    Returns:
        dict[str, float]: contrast, edge, solidity, depth, window, skin, area (x hand area) and
        frame (length along ``inner``, in palm lengths).
    """
    L = scene.palm
    h, w = m.shape
    dt = cv2.distanceTransform(np.pad(m, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    pts = np.rint(np.asarray(p, np.float64).reshape(-1, 2)).astype(int)
    pts = np.clip(pts, 0, [w - 1, h - 1])
    depth = float(dt[pts[:, 1], pts[:, 0]].mean()) / max(1.0, float(dt.max()))
    return {
        "contrast": ho.outline_contrast(m, exclude, codes, max(3, int(0.2 * L))),
        "edge": edge_strength(m, grad, exclude),
        "solidity": ho.solidity(m),
        "depth": depth,
        "window": window_share(m, window),
        "skin": float((scene.skin_d2[m] < SKIN_D2).mean()),
        "area": float(m.sum()) / scene.hand_area,
        "frame": 0.0 if inner is None else float((m & inner).sum()) / L,
    }


def window_share(m: np.ndarray, window: np.ndarray | None) -> float:
    """Share of the GrabCut window's inner outline that the mask runs into (0 without a
    window). The crop's own edge does not count: the object may leave the photo."""
    if window is None:
        return 0.0
    ring = window & ~cv2.erode(window.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    frame = np.zeros(m.shape, bool)
    frame[[0, -1], :], frame[:, [0, -1]] = True, True
    ring &= ~frame
    return float((ring & m).sum()) / max(1.0, float(ring.sum()))


def click_candidates(
    img: np.ndarray,
    scene: ho.Scene,
    p: np.ndarray,
    forbidden: np.ndarray,
    iterations: int,
    seed: int,
    windows: tuple[float, ...] = WINDOWS,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """GrabCut candidates grown from one click, one per window and start.

    Args:
        img (np.ndarray): (h, w, 3) uint8 RGB working crop.
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.
        p (np.ndarray): (2,) click (u, v) in crop pixels.
        forbidden (np.ndarray): (h, w) bool hand and other-hand pixels.
        iterations (int): GrabCut iterations (at most :data:`CLICK_ITERATIONS`).
        seed (int): Seed of OpenCV's RNG.
        windows (tuple[float, ...]): Window half-sides in palm lengths.

    Returns:
        list[tuple[np.ndarray, np.ndarray]]: (mask, window) pairs of (h, w) bool arrays.
    """
    h, w = img.shape[:2]
    L = scene.palm
    sure = _disk((h, w), p, max(1.5, SURE * L)) & ~scene.other_hands
    # the hand mask may have absorbed part of the object (a skin-coloured or shadowed part
    # next to the fingers): only the cores of its visible bones and the other hands are sure
    # background, the rest of it is probable background
    # an object in front of a finger covers its bone: only skin-coloured bone pixels are sure
    # to be the hand
    core = (
        draw_skeleton((h, w), scene.kp, 0.12 * L, palm=False)
        & scene.hand
        & (scene.skin_d2 < SKIN_D2)
    ) | scene.other_hands
    core &= ~sure
    n_iter = min(iterations, CLICK_ITERATIONS)
    out = []
    for k, share in [(k, sh) for k in windows for sh in SEED_SHARES]:
        R = k * L
        u0, v0 = int(max(0, p[0] - R)), int(max(0, p[1] - R))
        u1, v1 = int(min(w, p[0] + R + 1)), int(min(h, p[1] + R + 1))
        window = np.zeros((h, w), bool)
        window[v0:v1, u0:u1] = True
        # GrabCut on the window plus a margin of half its size (the background model's sample)
        mg = 0.5 * R
        a0, b0 = int(max(0, u0 - mg)), int(max(0, v0 - mg))
        a1, b1 = int(min(w, u1 + mg)), int(min(h, v1 + mg))
        init = np.full((h, w), cv2.GC_BGD, np.uint8)
        init[window] = cv2.GC_PR_BGD
        init[_disk((h, w), p, share * R) & window] = cv2.GC_PR_FGD
        init[forbidden & window] = cv2.GC_PR_BGD
        init[core] = cv2.GC_BGD
        init[sure] = cv2.GC_FGD
        sub = (slice(b0, b1), slice(a0, a1))
        fg = np.zeros((h, w), bool)
        fg[sub] = grabcut(np.ascontiguousarray(img[sub]), init[sub], n_iter, seed)
        fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
        m = fill_holes(components_at(fg | sure, sure)) & ~core
        if m.sum() > sure.sum():
            out.append((m, window))
            j = join_across_hand(fg & ~core, m, scene.hand, L)
            if j is not None:
                out.append((j, window))
    return out


def join_across_hand(fg: np.ndarray, m: np.ndarray, hand: np.ndarray, L: float):
    """``m`` joined with the other foreground pieces that, like ``m``, touch the hand: the
    fingers wrapped around a held object hide a band of it, so its visible parts often lie on
    both sides of them (None when there is no such piece)."""
    k = max(3, int(0.1 * L)) | 1
    band = cv2.dilate(hand.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    if not (m & band).any():
        return None
    n, cc, stats, _ = cv2.connectedComponentsWithStats((fg & ~m).astype(np.uint8), connectivity=8)
    touch = np.unique(cc[band & (cc > 0)])
    touch = [i for i in touch if stats[i, cv2.CC_STAT_AREA] >= JOIN_MIN * m.sum()]
    if not touch:
        return None
    return fill_holes(m | np.isin(cc, touch))


def _gaussian(px: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean, inverse covariance and log-determinant of a full-covariance Gaussian fitted to
    (n, 3) Lab samples (covariance widened by :data:`COLOUR_FLOOR` per channel)."""
    mu = px.mean(0)
    cov = np.cov(px.T) + np.eye(3) * COLOUR_FLOOR
    return mu, np.linalg.inv(cov), float(np.linalg.slogdet(cov)[1])


def _nll(x: np.ndarray, g: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
    """Twice the negative log-likelihood (up to a constant) of (n, 3) samples under ``g``."""
    mu, inv, logdet = g
    d = x - mu
    return np.einsum("ni,ij,nj->n", d, inv, d) + logdet


def take_back_from_hand(m: np.ndarray, scene: ho.Scene) -> np.ndarray:
    """``m`` plus the pixels of the hand mask that look like the object rather than the hand
    and join it.

    The hand mask is grown from the skeleton and is wider than the fingers: where a held object
    touches them, the mask takes in a band of the object (the part of a cup below the fingers,
    a pen under the thumb). Inside the hand mask, a pixel is given to the object when its colour
    is more likely under a Gaussian of the object's visible pixels (outside the hand) than under
    one of the hand's skin-coloured bone cores (the pixels surely the hand). Full covariances,
    not a skin threshold: an orange cup and a beige hand both pass a loose skin test, but their
    colours still separate when the two models are compared. The pixels taken back are opened
    (3 x 3) and kept only where they connect to ``m``; the other hands are never taken.

    Args:
        m (np.ndarray): (h, w) bool object mask.
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.

    Returns:
        np.ndarray: (h, w) bool mask (``m`` itself when either colour sample is too small).
    """
    h, w = m.shape
    L = scene.palm
    core = (
        draw_skeleton((h, w), scene.kp, 0.12 * L, palm=False)
        & scene.hand
        & (scene.skin_d2 < SKIN_D2)
    )
    visible = m & ~scene.hand
    zone = scene.hand & ~scene.other_hands & ~m
    if core.sum() < MIN_SAMPLES or visible.sum() < MIN_SAMPLES or not zone.any():
        return m
    g_obj, g_hand = _gaussian(scene.lab[visible]), _gaussian(scene.lab[core])
    ys, xs = np.nonzero(zone)
    px = scene.lab[ys, xs]
    ok = _nll(px, g_obj) < _nll(px, g_hand)
    add = np.zeros((h, w), np.uint8)
    add[ys[ok], xs[ok]] = 1
    add = cv2.morphologyEx(add, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    return components_at(m | add, m)


def settle(
    img: np.ndarray, m: np.ndarray, scene: ho.Scene, p: np.ndarray, iterations: int, seed: int
) -> np.ndarray:
    """The chosen mask redrawn by one GrabCut seeded by it (:func:`ho.refine`): its eroded core
    and the click sure object, the mask probable object, a band of :data:`SETTLE_BAND` L around
    it probable background, the other hands and the rest of the hand mask sure background.

    The candidates' outlines come from a window's GrabCut or from superpixel boundaries; a
    GrabCut whose colour models are learnt from the chosen object and its immediate
    surroundings alone moves the outline onto the object's own edge (a superpixel that straddles
    it, a strip of background taken along). ``m`` itself is kept when the redrawn mask differs
    from it by more than half (IoU < 0.5)."""
    L = scene.palm
    forbidden = (scene.hand & ~m) | scene.other_hands
    sure = _disk(m.shape, p, max(1.5, SURE * L)) & ~forbidden
    n_iter = min(iterations, SETTLE_ITERATIONS)
    r = ho.refine(img, m, forbidden, n_iter, seed, sure=sure, margin=SETTLE_BAND * L)
    r = fill_holes(r) & ~forbidden
    return m if encloses(r, scene.background_rings) else r


def finish_candidate(
    img: np.ndarray, scene: ho.Scene, m: np.ndarray, p: np.ndarray, iterations: int, seed: int
) -> np.ndarray:
    """What a click keeps of its candidate ``m``: the pixels the hand mask took of it given back
    (:func:`take_back_from_hand`), its outline settled by GrabCut (:func:`settle`)."""
    return settle(img, take_back_from_hand(m, scene), scene, p, iterations, seed)


def click_proposals(
    img: np.ndarray, scene: ho.Scene, p: np.ndarray, props: Proposals
) -> list[np.ndarray]:
    """Every region proposal containing the click, from ``props`` and from a finer
    segmentation of the crop (Felzenszwalb scale :data:`FINE_SCALE`).

    GrabCut grown from a click stops at the strongest colour change, which on a multi-coloured
    object (a cup with a lid and a sleeve) is often inside it; the proposal hierarchy groups
    such parts by adjacency and colour similarity, and the finer segmentation keeps apart an
    object and a background of similar colour that the coarser one merges.

    Args:
        img (np.ndarray): (h, w, 3) uint8 RGB working crop.
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.
        p (np.ndarray): (2,) click (u, v) in crop pixels.
        props (Proposals): The crop's region proposals at the default scale.

    Returns:
        list[np.ndarray]: (h, w) bool masks (the sure disk at the click added, hands removed).
    """
    h, w = img.shape[:2]
    L = scene.palm
    forbidden = scene.hand | scene.other_hands
    fine = propose(
        img,
        scene.lab,
        forbidden,
        FINE_SCALE * max(h, w) / 256.0,
        max(8, int((0.12 * L) ** 2)),
        max_size=10.0 * scene.hand_area,
    )
    sure = _disk((h, w), p, max(1.5, SURE * L)) & ~scene.other_hands
    rim = hand_rim(scene, p)
    u, v = int(round(p[0])), int(round(p[1]))
    out = []
    for pr in (props, fine):
        lab = int(pr.labels[v, u])
        if lab < 0:
            continue
        for r in pr.regions:
            if lab in r:
                m = (pr.mask(r) | sure) & ~forbidden & ~rim
                out.append(components_at(m | sure, sure))
    return out


def hand_rim(scene: ho.Scene, p: np.ndarray) -> np.ndarray:
    """(h, w) bool skin-coloured pixels within :data:`RIM` L of the hand mask, unless the click
    itself is on something skin-coloured (then nothing).

    The hand mask, grown from the skeleton, often misses the hand's rim (the sides of the
    fingers, a palm the keypoints foreshorten), and a region proposal next to the hand then
    takes it in; the rim is the hand's colour and touches it. A click on a skin-coloured object
    (a beige cup) says that colour is the object's, so nothing is taken away then."""
    h, w = scene.hand.shape
    if point_skin(scene, p) > 0.5:
        return np.zeros((h, w), bool)
    dist = cv2.distanceTransform((~scene.hand).astype(np.uint8), cv2.DIST_L2, 5)
    return (scene.skin_d2 < SKIN_D2) & (dist < RIM * scene.palm)


def point_skin(scene: ho.Scene, p: np.ndarray) -> float:
    """Share of the pixels within 0.15 L of the point ``p`` (working pixels), off the hand
    mask, that have this hand's skin colour (0 when the disk lies on the hand): how much of
    what the user pointed at has the hand's colour."""
    at = _disk(scene.hand.shape, p, max(2.0, 0.15 * scene.palm)) & ~scene.hand
    return float((scene.skin_d2[at] < SKIN_D2).mean()) if at.any() else 0.0


def click_object(
    img: np.ndarray,
    scene: ho.Scene,
    points: np.ndarray,
    regions: list[np.ndarray],
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
    choice: int = 1,
) -> tuple[np.ndarray, list[tuple[float, dict]], float | None, list[np.ndarray]]:
    """The object mask from one or more clicks.

    Args:
        img (np.ndarray): (h, w, 3) uint8 RGB working crop.
        scene (ho.Scene): The hand, its keypoints and colour model in the crop.
        points (np.ndarray): (N, 2) clicks (u, v) in crop pixels; the first one is grown, the
            object then grown to take in each further one (:func:`add_click`).
        regions (list[np.ndarray]): (h, w) bool region masks containing the first click
            (:func:`click_proposals`), scored with the GrabCut candidates.
        iterations (int): GrabCut iterations.
        seed (int): Seed of OpenCV's RNG.
        inside (tuple | None): Whether the photo goes on beyond the crop's left, top, right
            and bottom side (:func:`inner_edges`).
        choice (int): Which of the first click's distinct regions (:func:`distinct_regions`,
            1-based) becomes the object: 1 is the best-scored one.

    Returns:
        tuple: The (h, w) bool object mask, the (score, cues) of every candidate tried for the
        first click, the :func:`click_margin` of its own choice (None for a region picked
        with ``choice`` > 1), and the distinct regions (best first, as scored, the chosen one
        replaced by the object mask).
    """
    h, w = img.shape[:2]
    pts = np.clip(np.asarray(points, np.float64).reshape(-1, 2), 0, [w - 1, h - 1])
    forbidden = scene.hand | scene.other_hands
    p = pts[0]
    scored = scored_candidates(img, scene, p, regions, iterations, seed, inside)
    if not scored:
        if choice > 1:
            raise InvalidInputError(_no_choice(choice, 0))
        obj = _disk((h, w), p, max(1.5, SURE * scene.palm)) & ~forbidden
        return obj, [], None, [obj]
    distinct = distinct_regions(scored)
    if choice > len(distinct):
        raise InvalidInputError(_no_choice(choice, len(distinct)))
    best = distinct[choice - 1]
    # the margin says whether the click's own choice is a guess; a region the user picked is not
    margin = click_margin(scored, distinct) if choice == 1 else None
    obj = finish_candidate(img, scene, scored[best][2], p, iterations, seed)
    obj = bridge_to_hand(img, scene, obj, p, iterations, seed, inside)
    for k in range(1, len(pts)):  # further clicks: the object grown to take each in
        obj = add_click(img, scene, obj, pts[: k + 1], iterations, seed, inside)
    shown = [obj if i == best else scored[i][2] for i in distinct]
    return obj, [(s, c) for s, c, _ in scored], margin, shown


def distinct_regions(scored: list[tuple[float, dict, np.ndarray]]) -> list[int]:
    """Indices of up to :data:`~easyhoi.perception.prompts.N_CHOICES` candidates, best score
    first, each another region than the ones before it (IoU < :data:`OTHER_REGION_IOU`).

    Why they are offered (``--object-choice K`` with an object point): around one point the
    scores of the whole object and of a part of it (a label, a lid) or of the object with what
    lies behind it lie within about half a point of each other, and which one wins moves with
    the pixels (the same photo resampled or saved again as JPEG); the right region is more
    often among the first few than first (docs/perception.md), and a user tells them apart at
    a glance in ``masks.png``.
    """
    from easyhoi.perception.prompts import N_CHOICES

    out: list[int] = []
    for i in sorted(range(len(scored)), key=lambda i: -scored[i][0]):
        if all(mask_iou(scored[i][2], scored[j][2], empty=1.0) < OTHER_REGION_IOU for j in out):
            out.append(i)
            if len(out) == N_CHOICES:
                break
    return out


def _no_choice(choice: int, n: int) -> str:
    return (
        f"--object-choice {choice}: the object point has {n} distinct object region(s) "
        "(masks.png numbers them)"
    )


def bridge_to_hand(
    img: np.ndarray,
    scene: ho.Scene,
    obj: np.ndarray,
    p: np.ndarray,
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
) -> np.ndarray:
    """``obj`` joined to the hand when it stops short of it.

    A held object touches the hand that holds it in the photo: it borders the hand where the
    fingers grip it, or the hand covers part of it. A clicked mask with a gap between it and
    the hand misses the part between them (a bottle's neck, a lollipop's stick, a handle),
    which often has a colour of its own. A further point is placed midway across the narrowest
    gap and grown as :func:`add_click` grows a user's further point; the result is kept when it
    is one piece that reaches the hand, what it adds is no larger than the clicked mask, and
    what it adds lies between the mask and the hand (within the convex hull of the mask and the
    hand's nearest pixel: a neck or a stick, not the surface the object lies on, which runs out
    beside the gap).
    """
    if not obj.any() or not scene.hand.any():
        return obj
    near = cv2.dilate(scene.hand.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if (obj & near).any():
        return obj
    dist, idx = ndimage.distance_transform_edt(~scene.hand, return_indices=True)
    d = np.where(obj, dist, np.inf)
    a = np.unravel_index(int(np.argmin(d)), d.shape)
    b = (idx[0][a], idx[1][a])
    q = np.array([(a[1] + b[1]) / 2.0, (a[0] + b[0]) / 2.0])
    qi = (int(round(q[1])), int(round(q[0])))
    if scene.hand[qi] or scene.other_hands[qi]:
        return obj
    u = add_click(img, scene, obj, np.stack([p, q]), iterations, seed, inside)
    added = u & ~obj
    if not (u & near).any() or int(added.sum()) > int(obj.sum()):
        return obj
    if cv2.connectedComponents(u.astype(np.uint8), connectivity=8)[0] != 2:
        return obj
    # what joins the two lies between them: within the hull of the mask and the hand's
    # nearest pixel (a stick, a neck), not beside the gap (a surface the object lies on)
    corner = np.array([[b[1], b[0]]])
    hull_pts = np.concatenate([np.argwhere(obj)[:, ::-1], corner]).astype(np.int32)
    hull = np.zeros(obj.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(hull_pts), 1)
    hull = cv2.dilate(hull, np.ones((5, 5), np.uint8)) > 0
    if int((added & ~hull).sum()) > BRIDGE_OUTSIDE * int(added.sum()):
        return obj
    return u


def click_margin(
    scored: list[tuple[float, dict, np.ndarray]], distinct: list[int] | None = None
) -> float | None:
    """Score of the best-scored candidate less that of the best-scored candidate that is another
    region (regions 1 and 2 of :func:`distinct_regions`, given as ``distinct`` when already
    found); None when every candidate is about the same region. The scores of different
    regions lie this close when the choice between them is a guess: the same photo saved again
    as JPEG reorders candidates within about half a point (docs/perception.md)."""
    d = distinct_regions(scored) if distinct is None else distinct
    return float(scored[d[0]][0] - scored[d[1]][0]) if len(d) > 1 else None


def add_click(
    img: np.ndarray,
    scene: ho.Scene,
    obj: np.ndarray,
    pts: np.ndarray,
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
) -> np.ndarray:
    """``obj`` joined with the candidate grown from the last of ``pts`` whose union with it
    scores best as one object (:func:`click_score`, ``depth`` averaged over all ``pts``).

    A further click marks a part the object lacks. Judged alone, the best region grown from it
    can be the background around a small part (a dark button on a pale object leaks into a dark
    background); judged as part of the whole, the union that still looks like one object wins.
    """
    q = pts[-1]
    if obj[int(round(q[1])), int(round(q[0]))]:
        return obj
    forbidden, exclude, codes, grad, inner = _cue_inputs(img, scene, inside)
    best, best_score = None, -np.inf
    for m, window in click_candidates(img, scene, q, forbidden, iterations, seed, ADD_WINDOWS):
        u = fill_holes(obj | take_back_from_hand(m, scene))
        if encloses(u, scene.background_rings):  # around a point marked not the object
            continue
        c = candidate_cues(u, pts, None, scene, exclude, codes, grad, inner)
        # a grown part that runs into its window leaks (the object around it is not)
        c["window"] = window_share(m, window)
        sc = click_score(c)
        if sc > best_score:
            best, best_score = u, sc
    if best is None:
        return obj | (_disk(obj.shape, q, max(1.5, SURE * scene.palm)) & ~forbidden)
    return best


def _cue_inputs(img: np.ndarray, scene: ho.Scene, inside) -> tuple:
    """What :func:`candidate_cues` needs besides the mask, computed once per click: the hands
    (forbidden), the pixels left out of the outline cues, the colour bins, the lightness
    gradient and the crop's inner edges."""
    forbidden = scene.hand | scene.other_hands
    exclude = cv2.dilate(forbidden.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    codes = ho.colour_codes(scene.lab)
    gray = cv2.GaussianBlur(scene.lab[..., 0].astype(np.float32), (3, 3), 0)
    grad = np.hypot(cv2.Sobel(gray, cv2.CV_32F, 1, 0), cv2.Sobel(gray, cv2.CV_32F, 0, 1))
    return forbidden, exclude, codes, grad, inner_edges(img.shape[:2], inside)


def scored_candidates(
    img: np.ndarray,
    scene: ho.Scene,
    p: np.ndarray,
    regions: list[np.ndarray],
    iterations: int,
    seed: int,
    inside: tuple[bool, bool, bool, bool] | None = None,
) -> list[tuple[float, dict[str, float], np.ndarray]]:
    """(score, cues, mask) of every candidate for the click ``p``: the GrabCut candidates
    grown from it and the (non-empty) ``regions`` containing it."""
    forbidden, exclude, codes, grad, inner = _cue_inputs(img, scene, inside)
    cands = click_candidates(img, scene, p, forbidden, iterations, seed)
    cands += [(m, None) for m in regions if m.any()]
    scored = []
    for m, window in cands:
        if encloses(m, scene.background_rings):  # around a point marked not the object
            continue
        c = candidate_cues(m, p, window, scene, exclude, codes, grad, inner)
        scored.append((click_score(c), c, m))
    return scored
