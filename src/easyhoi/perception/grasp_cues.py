"""Further held-object cues: how a region sits against the hand and the frame.

Each cue is a general property of photos of hands holding things (why each holds is in
``docs/perception.md``). The per-pixel ones are measured per base segment once and summed per
hypothesis (:func:`segment_table`, :func:`region_cues`); ``amodal`` needs the mask drawn
(:func:`amodal_solidity`). Lengths are in palm lengths L.

=================  ========================================================================
cue                measure
=================  ========================================================================
``sides``          number of sides of the working crop (0-4) the region touches
``back``           length of contact with the hand on its wrist end (< 0.5 L along the
                   hand's axis from the wrist), in L
``cross``          share of the sampled finger cross-sections (across each finger's bones)
                   whose two sides both lie in the region
``pinch``          share of the grip lines (thumb tip and thumb IP joint to the index and
                   middle fingertips and the index PIP), outside the hand, the region covers
``wrap``           share of the hand's outline (the band around the hand mask, inside the
                   crop) the region borders
``spread``         share of the ``SECTORS`` angular sectors around the palm centre in which
                   the region borders the hand
``flanks``         share of the sampled cross-sections of the palm (across the wrist to
                   middle-MCP axis) whose two sides both lie in the region
``amodal``         solidity of the region with the hand pixels inside its convex hull counted
                   as the region (what the fingers hide of it)
=================  ========================================================================
"""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.perception.proposals import segment_sums
from easyhoi.perception.skin import hand_axis, palm_length

#: Cue names, in the order :func:`region_cues` returns them (``amodal`` is filled in later).
EXTRA = ("sides", "back", "cross", "pinch", "wrap", "spread", "flanks", "amodal")
#: Angular sectors around the palm centre in which ``spread`` looks for contact.
SECTORS = 12
#: Grip lines (keypoint pairs): the thumb tip and IP joint to the index and middle fingers.
GRIP_LINES = ((4, 8), (4, 12), (4, 6), (3, 8), (3, 7))
#: Bones whose cross-sections are sampled: the three bones of each finger, the thumb's last two.
CROSS_BONES = tuple(
    (a, b) for f in range(5) for a, b in ((4 * f + 1, 4 * f + 2), (4 * f + 2, 4 * f + 3),
                                          (4 * f + 3, 4 * f + 4)) if f > 0 or a >= 2
)  # fmt: skip
#: How far from a bone the sides of its finger are looked for, in L (a finger is ~0.2 L wide,
#: the hand mask may be wider where it takes in shadows).
CROSS_REACH = 0.45


def cross_sections(
    labels: np.ndarray,
    kp: np.ndarray,
    step: float = 2.0,
    bones: tuple[tuple[int, int], ...] = CROSS_BONES,
    reach_l: float = CROSS_REACH,
) -> np.ndarray:
    """(m, 2) base labels on the two sides of each sampled finger cross-section.

    Along every bone of ``bones`` (:data:`CROSS_BONES`), every ``step`` px, a line perpendicular
    to the bone is followed both ways from the bone to the first pixel that is not excluded (not
    a hand); the labels there are the two sides. Sections leaving the crop, or not leaving the
    hand within ``reach_l`` L, are dropped."""
    h, w = labels.shape
    L = palm_length(kp)
    reach = np.arange(1.0, max(2.0, reach_l * L) + 1.0)
    out = []
    for a, b in bones:
        d = kp[b] - kp[a]
        n = float(np.hypot(*d))
        if n < 1.0:
            continue
        t = np.linspace(0.15, 0.85, max(2, int(n / step)))
        pts = kp[a] + t[:, None] * d  # (k, 2)
        normal = np.array([-d[1], d[0]]) / n
        sides = []
        for sgn in (1.0, -1.0):
            q = pts[:, None, :] + sgn * reach[None, :, None] * normal  # (k, r, 2)
            u = np.round(q[..., 0]).astype(int)
            v = np.round(q[..., 1]).astype(int)
            inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            lab = np.full(u.shape, -2, np.int64)
            lab[inside] = labels[v[inside], u[inside]]
            free = lab != -1  # first pixel off the hand (or off the crop: -2)
            first = np.argmax(free, axis=1)
            got = lab[np.arange(len(lab)), first]
            got[~free.any(1)] = -2
            sides.append(got)
        s = np.stack(sides, 1)
        out.append(s[(s >= 0).all(1)])
    return np.concatenate(out) if out else np.zeros((0, 2), np.int64)


def grip_lines(shape: tuple[int, int], kp: np.ndarray) -> np.ndarray:
    """(h, w) bool: the grip lines of :data:`GRIP_LINES`, 1 px wide."""
    canvas = np.zeros(shape, np.uint8)
    pts = np.round(kp).astype(np.int32)
    for a, b in GRIP_LINES:
        cv2.line(canvas, tuple(map(int, pts[a])), tuple(map(int, pts[b])), 1, 1, cv2.LINE_8)
    return canvas.astype(bool)


def segment_table(labels: np.ndarray, hand: np.ndarray, kp: np.ndarray, n: int) -> dict:
    """Per-base-segment quantities the cues of :func:`region_cues` sum."""
    h, w = labels.shape
    L = palm_length(kp)
    sides = np.zeros((4, n))
    for k, edge in enumerate((labels[0], labels[-1], labels[:, 0], labels[:, -1])):
        e = edge[edge >= 0]
        sides[k, np.unique(e)] = 1.0
    hand_dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
    back = (hand_dist > 0) & (hand_dist <= 0.12 * L + 1.5) & (hand_axis((h, w), kp) < 0.5 * L)
    lines = grip_lines((h, w), kp) & (labels >= 0)
    band = (hand_dist > 0) & (hand_dist <= 0.12 * L + 1.5) & (labels >= 0)
    centre = kp[[0, 5, 9, 13, 17]].mean(0)
    yy, xx = np.mgrid[0:h, 0:w]
    ang = np.arctan2(yy - centre[1], xx - centre[0])
    sector = np.clip(((ang + np.pi) / (2 * np.pi) * SECTORS).astype(int), 0, SECTORS - 1)
    spread = np.zeros((SECTORS, n))
    for k in range(SECTORS):
        spread[k] = segment_sums(labels, band & (sector == k), n)
    return {
        "sides": sides,
        "back": segment_sums(labels, back, n),
        "pinch": segment_sums(labels, lines, n),
        "pinch_total": float(lines.sum()),
        "cross": cross_sections(labels, kp),
        "flanks": cross_sections(labels, kp, bones=((0, 9),), reach_l=1.0),
        "wrap": segment_sums(labels, band, n),
        "wrap_total": float(max(1, band.sum())),
        "spread": spread,
        "L": L,
    }


def region_cues(member, table: dict) -> np.ndarray:
    """(n_regions, len(EXTRA)) cues of the hypotheses whose (n_regions, n_base) sparse
    membership matrix is ``member``; ``amodal`` left at 0."""
    nr = member.shape[0]
    out = np.zeros((nr, len(EXTRA)))
    if nr == 0:
        return out
    L = table["L"]
    out[:, 0] = ((member @ table["sides"].T) > 0).sum(1)
    out[:, 1] = (member @ table["back"]) / ((0.12 * L + 1.5) * L)
    pairs = table["cross"]
    if len(pairs):
        m = member.tocsc()
        both = m[:, pairs[:, 0]].multiply(m[:, pairs[:, 1]])
        out[:, 2] = np.asarray(both.sum(1)).ravel() / len(pairs)
    if table["pinch_total"] > 0:
        out[:, 3] = (member @ table["pinch"]) / table["pinch_total"]
    pairs = table["flanks"]
    if len(pairs):
        m = member.tocsc()
        both = m[:, pairs[:, 0]].multiply(m[:, pairs[:, 1]])
        out[:, 6] = np.asarray(both.sum(1)).ravel() / len(pairs)
    out[:, 4] = (member @ table["wrap"]) / table["wrap_total"]
    out[:, 5] = ((member @ table["spread"].T) >= 2).sum(1) / SECTORS
    return out


def pixel_hull(mask: np.ndarray) -> tuple[int, np.ndarray | None]:
    """Number of pixels of ``mask`` and the convex hull of their (u, v) indices (None under 3
    pixels): what :func:`amodal_solidity` and :func:`.held_object.solidity` both start from,
    computed once when a caller needs both."""
    vv, uu = np.nonzero(mask)
    if len(vv) < 3:
        return len(vv), None
    return len(vv), cv2.convexHull(np.stack([uu, vv], 1).astype(np.int32))


def amodal_solidity(
    mask: np.ndarray, hand: np.ndarray, hull: tuple[int, np.ndarray | None] | None = None
) -> float:
    """Solidity of ``mask`` with the ``hand`` pixels inside its convex hull added: the fingers
    in front of a held object hide parts of it, and it is compact once they are counted in.
    ``hull``: :func:`pixel_hull` of ``mask``, when already computed."""
    count, hull = pixel_hull(mask) if hull is None else hull
    if hull is None:
        return 0.0
    canvas = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(canvas, hull, 1)
    inside = canvas.astype(bool)
    area = count + float((hand & inside & ~mask).sum())
    # the hull's area as in held_object.solidity, so that without a hand both are equal
    hull_area = cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True)
    return float(min(1.0, area / max(1.0, hull_area)))
