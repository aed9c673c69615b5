"""Confidence of the hand and held-object masks, from the cues that chose them.

The score is a logistic function of the evidence; the reasons name every weak cue in words, so
a user learns what was doubtful and that an object point (``--object-point X,Y``) fixes it.

Object (automatic): the held-object evidence of the chosen hypothesis (the hand-set score of
:func:`easyhoi.perception.held_object.score`, not the ranking's score) and its margin over the
*different* hypothesis (IoU < 0.5) with the most evidence. A high score means the region is where
a grasped object lies (pressed by several fingers and the thumb, filling the grasp, not skin, not
background running out of the picture, with a closed outline); a small margin means another
region is almost as good a held object, and the choice between them is a guess. Prompted: the
user said where the object is, so only a region that grew far beyond the prompt (larger than
held objects are, or running out of the frame around the points on all four sides), much smaller
than the hand (with object points: a part of the object, a label or a cap, is what a point's
outline often stops at) or has more of the hand's skin colour than what the points are on (a mask
grown into the hand's rim, the arm or a face; a point on a beige cup says that colour is the
object's) lowers the score, and, for a single object point, another outline around the point that
scores almost as high (the click's choice between them is then a guess, which a second point
on what the mask misses, or a background point on what it takes in, settles). An object box
says how large the object is, so there size does not count; what does is whether the box's
other candidates (GrabCut started from other regions) reach the same outline: one that stands
alone is a guess.

Hand: the detector's score, and how much of the skeleton's core the hand mask covers (a mask
that misses the fingers the detector placed means the hand colour model failed).
"""

from __future__ import annotations

import numpy as np

from easyhoi.perception.confidence import MaskConfidence
from easyhoi.perception.held_object import AREA_RANGE, CUES, Hypotheses
from easyhoi.perception.skin import draw_skeleton, palm_length

#: Logistic calibration of the automatic object score: sigmoid(A * (score - S0) + B * (margin -
#: M0)), the margin capped at 3. Set on the tuning half of the development photos so that the
#: wrong choices there score low: a choice is trusted only when the region has most of the
#: held-object cues (score >= S0) and clearly beats every different region (margin >= M0).
CALIBRATION = {"A": 1.0, "S0": 5.0, "B": 1.5, "M0": 2.5}

#: A single click's choice is unsure when another region scores within this of it (scores of
#: about 6; the same photo saved again as JPEG reorders candidates within about half a point).
CLICK_MARGIN = 0.5
#: Taken off the prompted logit then: a clean click mask (logit 2.5) falls to low (below 0.5).
CLICK_MARGIN_PENALTY = 3.0
#: A box's outline is trusted when at least this many of its other candidates (GrabCut started
#: from other regions, and the box's own GrabCut) reach it (IoU >= 0.5); below, the same
#: penalty as an unsure click. On the development photos with a box round the held object
#: (reference box + 5 %) the rule flags 10 of the 13 masks with IoU < 0.5 and 9 of the 25 with
#: IoU >= 0.5 (11 with the skin cue).
BOX_AGREEMENT = 2
#: A mask with more than this share of the hand's skin colour is named as doubtful (in a prompted
#: mask: more than the share around the object points).
SKIN_REASON = 0.3
#: An object point's mask smaller than this share of the hand's area is unsure (the same
#: penalty as an unsure click): the outline grown from a point stops at the strongest edge
#: around it, which inside an object is often a part's (a label, a cap, a pen's tip, a
#: microphone's head), and held objects are mostly about as large as the hand or larger; a
#: small whole object (a pen) is a thin outline that a pixel or two moves.
SMALL_POINT_MASK = 0.25


def _sigmoid(z: float) -> float:
    return float(1.0 / (1.0 + np.exp(-z)))


def weak_cues(cues: dict) -> list[str]:
    """Words for every weak cue of a hypothesis (``cues``: name -> value, see held_object)."""
    out = []
    if cues["fingers"] < 2:
        out.append(f"touches {int(cues['fingers'])} fingertip(s)")
    if not cues["thumb"]:
        out.append("the thumb does not touch it")
    if cues["skin"] > SKIN_REASON:
        out.append(f"{cues['skin']:.0%} of it has the hand's skin colour")
    if cues["other_hand"] > 0.1:
        out.append("it overlaps another hand")
    if cues["border"] > 0.5:
        out.append("it runs out of the picture around the hand, as background does")
    lo, hi = AREA_RANGE
    if not lo <= cues["area"] <= hi:
        out.append(f"its size ({cues['area']:.2f} x the hand) is unusual for a held object")
    if cues["contrast"] < 0.5:
        out.append("its outline has little contrast with its surroundings")
    return out


def object_confidence(
    hyp: Hypotheses | None,
    best: int | None,
    runner: int | None,
    has_object: bool,
    prompted: bool,
    min_score: float,
    click_margin: float | None = None,
    box_agreement: int | None = None,
    point_skin: float | None = None,
) -> MaskConfidence:
    """Confidence of the held-object mask (see the module docstring). ``click_margin``: the
    score margin of a single click's chosen candidate over another region
    (:func:`easyhoi.perception.click.click_margin`), or None; ``box_agreement``: how many of
    an object box's other candidates reach the chosen outline
    (:func:`easyhoi.perception.prompted.prompted_object`), or None; ``point_skin``: the
    largest share of skin-coloured pixels around an object point
    (:func:`easyhoi.perception.click.point_skin`), or None without object points."""
    if hyp is None or best is None or not has_object:
        return MaskConfidence(0.0, ("no region scored as a held object; point at it",))
    cues = dict(zip(CUES, hyp.cues[best], strict=True))
    reasons = weak_cues(cues)
    s = hyp.strength(best)
    if prompted:
        # skin colour beyond what the user pointed at: a point on a skin-coloured object (a beige
        # cup, cardboard) says that colour is the object's, so only the excess is doubtful
        at = 0.0 if point_skin is None else float(point_skin)
        skin = max(0.0, cues["skin"] - at)
        z = 2.5 - 3.0 * skin
        if box_agreement is None:  # a box says how large the object is; points do not
            z -= 2.0 * max(0.0, np.log(max(cues["area"], 1e-6) / 6.0))
        reasons = [r for r in reasons if "size" in r and box_agreement is None]
        if skin > SKIN_REASON:
            where = f", where the point has {at:.0%}" if point_skin is not None else ""
            reasons.insert(0, f"{cues['skin']:.0%} of it has the hand's skin colour{where}")
        if point_skin is not None and box_agreement is None and cues["area"] < SMALL_POINT_MASK:
            z -= CLICK_MARGIN_PENALTY
            reasons = [r for r in reasons if "size" not in r]
            reasons.append(
                f"it is small next to the hand ({cues['area']:.2f} x the hand's area), as a "
                "part of an object often is: check masks.png"
            )
        if box_agreement is None and cues["sides"] >= 4:
            # the frame reaches at least 3 palm lengths beyond the points: a region that runs
            # out of it on every side has no outline in it, as a surface behind the hand
            z -= CLICK_MARGIN_PENALTY
            reasons.append(
                "it reaches every side of the frame around the point, as a background does: "
                "check masks.png"
            )
        if click_margin is not None and click_margin < CLICK_MARGIN:
            z -= CLICK_MARGIN_PENALTY
            reasons.append(
                f"another outline around the point scores almost as high (margin "
                f"{click_margin:.2f}): check masks.png, where it is region 2"
            )
        if box_agreement is not None and box_agreement < BOX_AGREEMENT:
            z -= CLICK_MARGIN_PENALTY
            reasons.append(
                f"few of the box's other candidate outlines agree with it ({box_agreement} with "
                "IoU >= 0.5): check masks.png"
            )
        return MaskConfidence(_sigmoid(z), tuple(reasons))
    margin = s - hyp.strength(runner) if runner is not None else 3.0
    c = CALIBRATION
    z = c["A"] * (s - c["S0"]) + c["B"] * (min(margin, 3.0) - c["M0"])
    if margin < 0:
        # the ranking chose this region, but another one has more held-object evidence
        reasons.append(f"another region looks more like a held object (score margin {margin:.2f})")
    elif margin < c["M0"]:
        reasons.append(f"another region is almost as likely (score margin {margin:.2f})")
    if s < c["S0"]:
        reasons.append(f"weak held-object evidence (score {s:.2f})")
    return MaskConfidence(_sigmoid(z), tuple(reasons))


def hand_confidence(hand, mask: np.ndarray, kp: np.ndarray, skin_d2: np.ndarray) -> MaskConfidence:
    """Confidence of the hand mask: detector score x share of the skeleton core covered."""
    core = draw_skeleton(mask.shape, kp, 0.08 * palm_length(kp), palm=False)
    cover = float((core & mask).sum()) / max(1.0, float(core.sum()))
    det = float(np.clip(hand.score, 0.0, 1.0))
    reasons = []
    if det < 0.7:
        reasons.append(f"the hand detector is unsure ({det:.2f})")
    if cover < 0.7:
        reasons.append(f"the hand mask covers {cover:.0%} of the detected fingers")
    return MaskConfidence(det * min(1.0, cover / 0.7), tuple(reasons))
