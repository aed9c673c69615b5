"""What the user is told about perception's certainty, and which prompt fixes a weak mask.

Perception reports, per mask, a :class:`~easyhoi.perception.confidence.MaskConfidence` (a score
and the weak cues). These functions turn the JSON form of that report
(:meth:`~easyhoi.perception.chain.PerceptionReport.to_dict`) into sentences for the command
line and the web demo, so both say the same thing:

* a low-confidence mask names its weak cues and the one gesture that fixes it: a point on the
  held object for the object masks, a point on the holding hand for the hand mask; uncertain
  hand keypoints say that the pose may be wrong and what can replace them;
* a result that does not use the first detected hand says so, and why;
* a result whose hand does not touch its object says so (:func:`contact_line`): the photo shows
  a held object, so a gap means the masks or the hand's keypoints are off, and the fix is the
  same point on the held object.
"""

from __future__ import annotations

from easyhoi.errors import LowConfidenceError

# The object advice without the region choice: where masks.png numbers no regions to pick from
# (fewer than two), and on the command line with --strict, which writes no masks.png. The
# advice where there are regions names the choice as well.
_NO_REGIONS = {
    "cli": "re-run with --object-point X,Y on the held object (or --object-box X0,Y0,X1,Y1 "
    "around it)",
    "batch": "give the photo an object_point on the held object in the --prompts file",
}
# ... the same once the object was pointed at
_NO_REGIONS_MORE = {
    "cli": "add --object-point X,Y on parts of the object the mask misses, --background-point "
    "X,Y on what it takes in beyond the object, or an --object-box",
    "batch": "add object_point rows on parts of the object the mask misses, background_point "
    "rows on what it takes in beyond the object, or an object_box",
}

#: The fix for a weak mask, per mask name: on the command line and in the web demo.
_ADVICE = {
    "cli": {
        "object": "re-run with --object-point X,Y on the held object "
        "(or --object-box X0,Y0,X1,Y1 around it, or --object-choice K for region K of "
        "masks.png)",
        "hand": "re-run with --hand-point X,Y on the hand that holds the object",
        "keypoints": "the hand's pose may be wrong: give --hand-params from another hand "
        "estimator, or use a photo where the hand is seen more clearly",
    },
    "batch": {
        "object": _NO_REGIONS["batch"] + " (or an object_choice K for region K of masks.png)",
        "hand": "give the photo a hand_point on the hand that holds the object in the --prompts "
        "file",
        "keypoints": "the hand's pose may be wrong: reconstruct the photo alone with "
        "--hand-params from another hand estimator",
    },
    "demo": {
        "object": "click on the held object in the photo and run again",
        "hand": "choose 'hand' and click on the hand that holds the object, then run again",
        "keypoints": "the hand's pose may be wrong: use a photo where the hand is seen more "
        "clearly",
    },
}
# --strict writes nothing, so there is no masks.png to pick a numbered region from
_ADVICE["strict"] = {**_ADVICE["cli"], "object": _NO_REGIONS["cli"]}
_ADVICE_MORE = {
    "cli": _NO_REGIONS_MORE["cli"]
    + " (or take the point's region K of masks.png with --object-choice K)",
    "batch": _NO_REGIONS_MORE["batch"]
    + " (or an object_choice K for the point's region K of masks.png)",
    "demo": "click on the parts of the object the mask misses (or, as background points, on "
    "what it takes in beyond the object) and run again",
    "strict": _NO_REGIONS_MORE["cli"],
}


def advice(
    mask: str, where: str = "cli", prompted: bool = False, regions: int | None = None
) -> str:
    """What to do about a weak ``mask`` ("hand", "object", "amodal", or the hand's
    "keypoints"), for ``where``: "cli", "strict" (the command line when nothing is written,
    so no picture to pick a region from), "batch" or "demo".

    ``prompted``: the object was already pointed at (then: more object or background points,
    or a box). ``regions``: how many object regions the result offers for ``--object-choice``
    (fewer than two: the choice is not named; None: not known, named).
    """
    kind = mask if mask in ("hand", "keypoints") else "object"
    if kind == "object" and regions is not None and regions < 2 and where in _NO_REGIONS:
        return (_NO_REGIONS_MORE if prompted else _NO_REGIONS)[where]
    if kind == "object" and prompted:
        return _ADVICE_MORE[where]
    return _ADVICE[where][kind]


def low_confidence_lines(perception: dict, where: str = "cli", prompted: bool = False) -> list:
    """One sentence per low-confidence mask of a perception report (JSON form); [] if none."""
    lines = []
    for name, conf in (perception.get("confidence") or {}).items():
        if not conf.get("low"):
            continue
        reasons = "; ".join(conf.get("reasons") or ()) or "no cue stood out"
        what = "the hand's keypoints" if name == "keypoints" else f"the {name} mask"
        lines.append(
            f"low confidence in {what} (score {float(conf['score']):.2f}; weak: "
            f"{reasons}): {advice(name, where, prompted, perception.get('regions'))}"
        )
    return lines


def low_confidence_error(perception: dict, prompted: bool = False) -> LowConfidenceError:
    """The :class:`LowConfidenceError` of ``--strict`` for a report with low-confidence masks."""
    lines = low_confidence_lines(perception, "strict", prompted)
    return LowConfidenceError("; ".join(lines) + " (--strict: no result written)")


def hand_choice_note(perception: dict) -> str | None:
    """A sentence when the result uses another hand than the first detected one, else None."""
    index = perception.get("hand_index")
    if index is None:  # a report that names the hand used only in its notes
        used = [n for n in perception.get("notes") or () if n.startswith("using hand ")]
        index = int(used[-1].split()[2]) if used else None
    if not index:
        return None
    side = perception.get("side") or "?"
    if perception.get("hand_choice") in ("hand point", "object prompt"):
        return f"using hand {index} ({side}), the hand nearest the {perception['hand_choice']}"
    skipped = [n for n in perception.get("notes") or () if n.endswith("holds no object")]
    why = "; ".join(skipped) or "the hands before it hold no object"
    return (
        f"{why}: the result uses hand {index} ({side}) of {perception.get('hands_found')} "
        f"detected (choose another with --hand-point X,Y)"
    )


#: A move of the object onto the hand (cm) from which :func:`contact_line` says so: the contact
#: tolerance of ``in_contact``, below which a hand counts as touching anyway.
MOVED_ONTO_HAND_CM = 0.5


def contact_line(plausibility: dict, where: str = "cli", prompted: bool = False) -> str | None:
    """A sentence when the result's hand does not touch its object, else None.

    ``plausibility``: the result's report (``HOIResult.plausibility``, ``result.json``), whose
    ``in_contact`` says whether a hand vertex is inside the object or within 5 mm of it. A
    contact the optimizer made by moving the object onto the hand by more than those 5 mm
    (``object_moved_to_hand_cm``) is said as well: the masks placed them apart.
    """
    moved = plausibility.get("object_moved_to_hand_cm")
    if isinstance(moved, int | float) and moved >= MOVED_ONTO_HAND_CM:
        return (
            f"the object was moved {float(moved):.1f} cm onto the hand, which the photo's masks "
            f"place beside it: the object mask or the hand's keypoints may be wrong (see "
            f"masks.png); {advice('object', where, prompted)}"
        )
    if plausibility.get("in_contact") is not False:
        return None
    gap = plausibility.get("contact_distance_cm")
    apart = f" ({float(gap):.1f} cm apart)" if isinstance(gap, int | float) else ""
    return (
        f"the hand does not touch the object in the result{apart}: the object mask or the "
        f"hand's keypoints place them apart (see masks.png); {advice('object', where, prompted)}"
    )
