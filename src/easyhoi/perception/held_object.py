"""Which region proposal is the object the hand holds: cues, a score, a ranking.

Every hypothesis from :mod:`easyhoi.perception.proposals` is described by cues that hold in any
photo of a hand holding something (why each holds is in ``docs/perception.md``). All lengths are
in palm lengths L and all areas relative to the hand's area (its mask, floored at 2 L^2), so no
cue depends on the photo's resolution or on how large the hand appears.

=================  ========================================================================
cue                measure
=================  ========================================================================
``fingers``        number of fingers (of five) whose last two bones have the region within
                   ``TOUCH`` L: a held object is pressed by the finger pads
``thumb``          1 when the thumb is among them: a grasp opposes the thumb to the fingers
``grasp``          share of the grasp zone (the keypoints' convex hull, not the hand) covered
``contact``        length of the region's contact with the hand on the fingers/palm side, in L
``skin``           share of pixels matching this hand's colour model (hand, arm, face, hand 2)
``other_hand``     share of pixels on another detected hand
``border``         length of the region along the working crop's edge, in L
``area``           region area / hand area
``far``            share of pixels farther than 2 L from the hand
``contrast``       how much the region's colours differ from those of a band around it
``solidity``       region area / area of its convex hull
=================  ========================================================================

:func:`score` combines them linearly (weights :data:`WEIGHTS`), a log-odds style sum: the
evidence that a region is a held object at all. :mod:`easyhoi.perception.ranker` ranks the
hypotheses (that score and the further cues of :mod:`easyhoi.perception.grasp_cues`, with weights
fitted on photos); the best is refined by :func:`refine` (GrabCut seeded by the hypothesis).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from easyhoi.perception import grasp_cues as gc
from easyhoi.perception.proposals import Proposals, membership, segment_minima, segment_sums
from easyhoi.perception.skin import SKIN_D2, components_at, grabcut, hand_axis, palm_length

#: A finger touches a region closer than this to its last two bones, in palm lengths (a finger
#: is about 0.2 L wide, so its pad surface lies about 0.1 L from the bone).
TOUCH = 0.3
#: The contact band around the hand mask, in palm lengths.
CONTACT = 0.12

#: Score weights (log-odds per unit of each cue).
WEIGHTS = {
    "fingers": 0.45,
    "thumb": 0.6,
    "grasp": 2.0,
    "contact": 0.6,
    "skin": -3.0,
    "other_hand": -3.0,
    "border": -1.0,
    "size": -2.0,
    "far": -1.5,
    "contrast": 1.5,
    "solidity": 1.5,
}
#: Border lengths (in L) beyond this add no penalty: by then the region surrounds the crop.
BORDER_CAP = 8.0
#: Area range (x hand area) of held objects; outside it the size penalty grows with log-ratio.
AREA_RANGE = (0.08, 2.5)
#: Cue columns in :attr:`Hypotheses.cues`.
CUES = (
    "fingers",
    "thumb",
    "grasp",
    "contact",
    "skin",
    "other_hand",
    "border",
    "area",
    "far",
    "contrast",
    "solidity",
    *gc.EXTRA,
)


@dataclass(frozen=True)
class Scene:
    """What the cues need to know about the working crop.

    Attributes:
        lab: (h, w, 3) float Lab image.
        hand: (h, w) bool mask of the hand whose object is sought.
        kp: (21, 2) its keypoints in crop pixels.
        skin_d2: (h, w) squared normalised distance to its colour model.
        other_hands: (h, w) bool pixels of the other detected hands (and the disks of the
            user's background points, which are never the object either).
        background_rings: (h, w) bool rings around the user's background points: a candidate
            covering most of one encloses the point and is not the object
            (:mod:`easyhoi.perception.not_object`).
    """

    lab: np.ndarray
    hand: np.ndarray
    kp: np.ndarray
    skin_d2: np.ndarray
    other_hands: np.ndarray
    background_rings: tuple[np.ndarray, ...] = ()

    @property
    def palm(self) -> float:
        return palm_length(self.kp)

    @property
    def hand_area(self) -> float:
        return max(float(self.hand.sum()), 2.0 * self.palm**2)


@dataclass(frozen=True)
class Hypotheses:
    """Cues and scores of every hypothesis (rows follow ``proposals.regions``).

    ``scores`` rank the hypotheses; ``evidence`` (the hand-set :func:`score`, on the scale of
    ``min_score`` and the confidence's calibration) says how much the region looks like a held
    object at all; when absent it is ``scores``."""

    proposals: Proposals
    cues: np.ndarray  # (n, len(CUES))
    scores: np.ndarray  # (n,)
    evidence: np.ndarray | None = None  # (n,)

    def strength(self, i: int) -> float:
        """Held-object evidence of hypothesis ``i``."""
        return float((self.scores if self.evidence is None else self.evidence)[i])

    def cue(self, i: int) -> dict:
        return {k: round(float(v), 3) for k, v in zip(CUES, self.cues[i], strict=True)}


def grasp_zone(shape: tuple[int, int], kp: np.ndarray, hand: np.ndarray) -> np.ndarray:
    """(h, w) bool: the convex hull of the finger keypoints (thumb CMC to tips), minus the hand.

    A grasped object fills the space the fingers and the thumb close around."""
    hull = cv2.convexHull(np.round(kp[1:]).astype(np.int32))
    zone = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(zone, hull, 1)
    return zone.astype(bool) & ~hand


def finger_distances(shape: tuple[int, int], kp: np.ndarray) -> np.ndarray:
    """(5, h, w) distance of every pixel to the last two bones of each finger (thumb first)."""
    out = np.empty((5,) + tuple(shape), np.float32)
    pts = np.round(kp).astype(np.int32)
    for f in range(5):
        canvas = np.full(shape, 255, np.uint8)
        tip = 4 * f + 4
        for a, b in ((tip - 2, tip - 1), (tip - 1, tip)):
            cv2.line(canvas, tuple(map(int, pts[a])), tuple(map(int, pts[b])), 0, 1)
        out[f] = cv2.distanceTransform(canvas, cv2.DIST_L2, 5)
    return out


def _base_stats(props: Proposals, scene: Scene) -> dict[str, np.ndarray]:
    """Per-base-segment sums (and minima for the finger distances)."""
    lab_ = props.labels
    n = props.n_base
    shape = lab_.shape
    L = scene.palm
    hand_dist = cv2.distanceTransform((~scene.hand).astype(np.uint8), cv2.DIST_L2, 5)
    along = hand_axis(shape, scene.kp)
    ring = np.zeros(shape, bool)
    ring[0, :], ring[-1, :], ring[:, 0], ring[:, -1] = True, True, True, True
    contact = (hand_dist <= CONTACT * L + 1.5) & (along >= 0.5 * L)
    stats = {
        "size": props.sizes,
        "skin": segment_sums(lab_, scene.skin_d2 < SKIN_D2, n),
        "other": segment_sums(lab_, scene.other_hands, n),
        "ring": segment_sums(lab_, ring, n),
        "grasp": segment_sums(lab_, grasp_zone(shape, scene.kp, scene.hand), n),
        "contact": segment_sums(lab_, contact, n),
        "far": segment_sums(lab_, hand_dist > 2.0 * L, n),
    }
    fd = finger_distances(shape, scene.kp)
    mins = np.full((5, n), np.inf)
    if n:
        mins[:] = segment_minima(lab_, fd, n)
    stats["finger_min"] = mins
    return stats


def describe(props: Proposals, scene: Scene) -> np.ndarray:
    """(n_regions, len(CUES)) cues of every hypothesis, ``contrast`` and ``solidity`` left at 0
    (they need the mask drawn)."""
    st = _base_stats(props, scene)
    n = props.n_base
    L = scene.palm
    grasp_total = max(1.0, float(grasp_zone(props.labels.shape, scene.kp, scene.hand).sum()))
    out = np.zeros((len(props.regions), len(CUES)))
    if not props.regions:
        return out
    member = membership(props)
    sums = member @ np.stack(
        [st[k] for k in ("size", "grasp", "contact", "skin", "other", "ring", "far")], 1
    )
    size = np.maximum(1.0, sums[:, 0])
    touch = (member @ (st["finger_min"] <= TOUCH * L).T.astype(np.float64)) > 0
    out[:, 0] = touch.sum(1)
    out[:, 1] = touch[:, 0]
    out[:, 2] = sums[:, 1] / grasp_total
    out[:, 3] = sums[:, 2] / ((CONTACT * L + 1.5) * L)
    out[:, 4] = sums[:, 3] / size
    out[:, 5] = sums[:, 4] / size
    out[:, 6] = sums[:, 5] / L
    out[:, 7] = size / scene.hand_area
    out[:, 8] = sums[:, 6] / size
    table = gc.segment_table(props.labels, scene.hand, scene.kp, n)
    out[:, len(CUES) - len(gc.EXTRA) :] = gc.region_cues(member, table)
    return out


def score(cues: np.ndarray, gated: bool = True) -> np.ndarray:
    """Log-odds style score of (n, len(CUES)) cues; higher is more likely the held object.

    The grasp evidence (fingers, thumb, grasp zone, contact) counts in proportion to how much
    the region looks like an object (``contrast`` and ``solidity``): a thin halo of pixels
    around the hand touches every finger but is no object. ``gated=False`` (the cheap first
    ranking, before those two cues are measured) counts it fully."""
    c = {k: cues[:, j] for j, k in enumerate(CUES)}
    lo, hi = AREA_RANGE
    area = np.maximum(c["area"], 1e-6)
    size_pen = np.abs(np.log(area / np.clip(area, lo, hi)))
    w = WEIGHTS
    grasp = (
        w["fingers"] * np.minimum(c["fingers"], 4.0)
        + w["thumb"] * c["thumb"]
        + w["grasp"] * c["grasp"]
        + w["contact"] * np.minimum(c["contact"], 2.0)
    )
    if gated:
        grasp = grasp * (0.25 + 0.75 * c["contrast"]) * (0.25 + 0.75 * c["solidity"])
    return (
        grasp
        + w["skin"] * c["skin"]
        + w["other_hand"] * c["other_hand"]
        + w["border"] * np.minimum(c["border"], BORDER_CAP)
        + w["size"] * size_pen
        + w["far"] * c["far"]
        + w["contrast"] * c["contrast"]
        + w["solidity"] * c["solidity"]
    )


def colour_codes(lab: np.ndarray) -> np.ndarray:
    """(h, w) int joint Lab colour bin of every pixel (6 lightness x 8 x 8 chroma bins)."""
    li = np.clip(lab[..., 0] / 256.0 * 6, 0, 5).astype(np.int64)
    ai = np.clip((lab[..., 1] - 64.0) / 128.0 * 8, 0, 7).astype(np.int64)
    bi = np.clip((lab[..., 2] - 64.0) / 128.0 * 8, 0, 7).astype(np.int64)
    return (li * 8 + ai) * 8 + bi


def outline_contrast(mask: np.ndarray, exclude: np.ndarray, codes: np.ndarray, width: int) -> float:
    """How different the region is from what surrounds it: 1 - the intersection of the colour
    histograms of the region and of the band ``width`` px wide around it (not on ``exclude``).

    A whole object differs from its surroundings (near 1); a part of an object, or a piece cut
    out of a larger region, is surrounded by more of the same colours (near 0). Histograms, not
    pixel pairs, so a textured object is judged as a whole. 1 when there is no band."""
    if not mask.any():
        return 0.0
    k = 2 * width + 1
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    ring &= ~mask & ~exclude
    if ring.sum() < 4:
        return 1.0
    n = 6 * 8 * 8
    hi = np.bincount(codes[mask], minlength=n) / float(mask.sum())
    ho_ = np.bincount(codes[ring], minlength=n) / float(ring.sum())
    return 1.0 - float(np.minimum(hi, ho_).sum())


def solidity(mask: np.ndarray, hull: tuple[int, np.ndarray | None] | None = None) -> float:
    """Area of ``mask`` / area of its convex hull (1 for a convex region). Held objects are
    mostly compact; a region that wanders around the hand and into the background is not.
    ``hull``: :func:`.grasp_cues.pixel_hull` of ``mask``, when already computed."""
    count, hull = gc.pixel_hull(mask) if hull is None else hull
    if hull is None:
        return 0.0
    return float(
        min(1.0, count / max(1.0, cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True)))
    )


def drawn_cues(props: Proposals, scene: Scene, cues: np.ndarray, order) -> None:
    """Fill in, for the hypotheses ``order``, the cues that need the mask drawn."""
    exclude = cv2.dilate(
        (scene.hand | scene.other_hands).astype(np.uint8), np.ones((5, 5), np.uint8)
    ).astype(bool)
    width = max(3, int(0.2 * scene.palm))
    codes = colour_codes(scene.lab)
    j, k, a = CUES.index("contrast"), CUES.index("solidity"), CUES.index("amodal")
    for i in order:
        m = props.mask(props.regions[i])
        cues[i, j] = outline_contrast(m, exclude, codes, width)
        hull = gc.pixel_hull(m)
        cues[i, k] = solidity(m, hull)
        cues[i, a] = gc.amodal_solidity(m, scene.hand, hull)


def overlap(props: Proposals, a: frozenset, b: frozenset) -> float:
    """IoU of two hypotheses from their base-segment sizes."""
    inter = sum(props.sizes[i] for i in a & b)
    union = sum(props.sizes[i] for i in a | b)
    return float(inter / max(union, 1.0))


def runner_up(hyp: Hypotheses, best: int, max_iou: float = 0.5) -> int | None:
    """Index of the hypothesis with the most held-object evidence (:meth:`Hypotheses.strength`)
    that is a different region from ``best`` (IoU < ``max_iou``) and not smaller than the
    smallest held object (``AREA_RANGE[0]`` hands: a speck or a pocket of background between
    the fingers and the object is no alternative object)."""
    regs = hyp.proposals.regions
    ev = hyp.scores if hyp.evidence is None else hyp.evidence
    small = hyp.cues[:, CUES.index("area")] < AREA_RANGE[0]
    for i in np.argsort(-ev, kind="stable"):
        if i == best or not np.isfinite(ev[i]) or small[i]:
            continue
        if overlap(hyp.proposals, regs[best], regs[i]) < max_iou:
            return int(i)
    return None


def refine(
    img: np.ndarray,
    mask: np.ndarray,
    forbidden: np.ndarray,
    iterations: int,
    seed: int,
    sure: np.ndarray | None = None,
    margin: float = 0.0,
    fallback: bool = True,
) -> np.ndarray:
    """GrabCut seeded by a hypothesis: its eroded core (and ``sure``) sure foreground, the
    hypothesis probable foreground, a margin around it (half its radius, at least ``margin`` px)
    probable background, ``forbidden`` (the hands) and everything farther sure background.
    Returns the components overlapping the core; with ``fallback``, ``mask`` itself when
    GrabCut moved far from it (IoU < 0.5)."""
    if not mask.any():
        return mask
    r = max(2.0, np.sqrt(mask.sum() / np.pi))
    k = int(max(1, 0.25 * r)) * 2 + 1
    core = cv2.erode(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    if sure is not None:
        core |= sure
    dist = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
    init = np.full(mask.shape, cv2.GC_BGD, np.uint8)
    init[dist <= max(3.0, 0.5 * r, margin)] = cv2.GC_PR_BGD
    init[mask] = cv2.GC_PR_FGD
    init[core] = cv2.GC_FGD
    init[forbidden & ~core] = cv2.GC_BGD
    fg = grabcut(img, init, iterations, seed)
    if core.any():
        fg = components_at(fg, core)
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    if not fallback:
        return fg if fg.any() else mask
    inter = float((fg & mask).sum())
    iou = inter / max(1.0, float((fg | mask).sum()))
    return fg if iou >= 0.5 else mask


def mask_cues(mask: np.ndarray, scene: Scene) -> np.ndarray:
    """(len(CUES),) cues of an arbitrary (h, w) bool mask, contrast included."""
    labels = np.where(mask, 0, -1)
    props = Proposals(labels=labels, regions=(frozenset((0,)),), sizes=np.array([mask.sum()]))
    cues = describe(props, scene)[0]
    exclude = cv2.dilate(
        (scene.hand | scene.other_hands).astype(np.uint8), np.ones((5, 5), np.uint8)
    ).astype(bool)
    width = max(3, int(0.2 * scene.palm))
    cues[CUES.index("contrast")] = outline_contrast(mask, exclude, colour_codes(scene.lab), width)
    hull = gc.pixel_hull(mask)
    cues[CUES.index("solidity")] = solidity(mask, hull)
    cues[CUES.index("amodal")] = gc.amodal_solidity(mask, scene.hand, hull)
    return cues


def distinct_best(hyp: Hypotheses, k: int, max_iou: float = 0.6) -> list[int]:
    """Indices of up to ``k`` best-scoring hypotheses, each overlapping the ones before it by
    less than ``max_iou``."""
    regs = hyp.proposals.regions
    out: list[int] = []
    for i in np.argsort(-hyp.scores, kind="stable"):
        if not np.isfinite(hyp.scores[i]):
            break
        if all(overlap(hyp.proposals, regs[i], regs[j]) < max_iou for j in out):
            out.append(int(i))
            if len(out) == k:
                break
    return out
