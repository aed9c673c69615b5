"""The sentences about perception's certainty: weak masks with their fix, the hand used."""

from __future__ import annotations

from easyhoi.errors import ExitCode, LowConfidenceError
from easyhoi.perception.chain import PerceptionReport
from easyhoi.perception.confidence import MaskConfidence
from easyhoi.perception.feedback import (
    advice,
    contact_line,
    hand_choice_note,
    low_confidence_error,
    low_confidence_lines,
)


def report(**conf) -> dict:
    r = PerceptionReport(hands_found=1, side="right", has_object=True)
    r.confidence = {k: MaskConfidence(*v) for k, v in conf.items()}
    return r.to_dict()


def test_only_low_masks_are_named_with_their_weak_cues_and_fix():
    rep = report(hand=(0.8, ()), object=(0.2, ("touches the border", "no contrast")),
                 amodal=(0.49, ()))  # fmt: skip
    lines = low_confidence_lines(rep)
    assert lines == [
        "low confidence in the object mask (score 0.20; weak: touches the border; no contrast): "
        "re-run with --object-point X,Y on the held object (or --object-box X0,Y0,X1,Y1 around "
        "it, or --object-choice K for region K of masks.png)",
        "low confidence in the amodal mask (score 0.49; weak: no cue stood out): re-run with "
        "--object-point X,Y on the held object (or --object-box X0,Y0,X1,Y1 around it, or "
        "--object-choice K for region K of masks.png)",
    ]
    assert low_confidence_lines(report(hand=(0.5, ()), object=(0.99, ()))) == []
    assert low_confidence_lines({}) == []
    assert advice("hand", "demo").startswith("choose 'hand' and click on the hand")
    assert advice("object", "batch", prompted=True).startswith("add object_point rows")
    err = low_confidence_error(rep)
    assert isinstance(err, LowConfidenceError) and err.exit_code == ExitCode.LOW_CONFIDENCE == 9
    assert str(err).endswith("(--strict: no result written)") and "object mask" in str(err)


def test_hand_choice_note():
    base = {"hands_found": 2, "side": "left", "notes": ["hand 0 (right) holds no object"]}
    assert hand_choice_note({**base, "hand_index": 0}) is None
    assert hand_choice_note({**base, "hand_index": None}) is None
    assert hand_choice_note({**base, "hand_index": 1}) == (
        "hand 0 (right) holds no object: the result uses hand 1 (left) of 2 detected (choose "
        "another with --hand-point X,Y)"
    )
    assert hand_choice_note({**base, "hand_index": 1, "hand_choice": "hand point"}) == (
        "using hand 1 (left), the hand nearest the hand point"
    )
    # a report that names the hand used only in its notes
    named = {**base, "notes": base["notes"] + ["using hand 1 (left)"]}
    assert hand_choice_note(named).startswith("hand 0 (right) holds no object: the result uses")


def test_hand_choice_note_of_an_object_prompt():
    perception = {"hands_found": 2, "side": "left", "hand_index": 1,
                  "hand_choice": "object prompt"}  # fmt: skip
    assert hand_choice_note(perception) == (
        "using hand 1 (left), the hand nearest the object prompt"
    )


def test_contact_line_only_for_a_hand_apart_from_its_object():
    apart = {"in_contact": False, "contact_distance_cm": 2.0279, "penetration_depth_cm": 0.0}
    assert contact_line(apart) == (
        "the hand does not touch the object in the result (2.0 cm apart): the object mask or the "
        "hand's keypoints place them apart (see masks.png); re-run with --object-point X,Y on the "
        "held object (or --object-box X0,Y0,X1,Y1 around it, or --object-choice K for region K "
        "of masks.png)"
    )
    assert contact_line(apart, "batch", prompted=True).endswith(
        "add object_point rows on parts of the object the mask misses, background_point rows on "
        "what it takes in beyond the object, or an object_box (or an object_choice K for the "
        "point's region K of masks.png)"
    )
    assert "cm apart" not in contact_line({"in_contact": False})
    assert contact_line({"in_contact": True, "contact_distance_cm": -0.2}) is None
    # a metric that could not be computed (None) is not reported as a gap
    assert contact_line({"in_contact": None}) is None
    assert contact_line({}) is None


def test_uncertain_keypoints_are_named_as_keypoints_with_their_own_fix():
    import numpy as np
    import pytest

    from easyhoi.perception.confidence import keypoints_confidence

    conf = np.r_[np.full(12, 0.2), np.full(9, 0.9)]
    kc = keypoints_confidence(conf)
    assert kc.score == pytest.approx(0.2) and kc.low
    assert kc.reasons == ("12 of 21 keypoints move when the detector's crop moves",)
    sure = keypoints_confidence(np.linspace(0.05, 1.0, 21))
    assert sure.score == pytest.approx(np.median(np.linspace(0.05, 1.0, 21))) and not sure.low
    assert sure.reasons == ("10 of 21 keypoints move when the detector's crop moves",)
    assert keypoints_confidence(np.ones(21)).reasons == ()
    lost = keypoints_confidence(None)  # the detector could not measure them
    assert lost.score == 0.0 and lost.low
    assert lost.reasons == ("the detector does not find the hand again around them",)
    with pytest.raises(ValueError):
        keypoints_confidence([np.nan] * 21)

    rep = report(hand=(0.9, ()), keypoints=(kc.score, kc.reasons))
    (line,) = low_confidence_lines(rep)
    assert line == (
        "low confidence in the hand's keypoints (score 0.20; weak: 12 of 21 keypoints move "
        "when the detector's crop moves): the hand's pose may be wrong: give --hand-params "
        "from another hand estimator, or use a photo where the hand is seen more clearly"
    )
    assert "--hand-params" in low_confidence_lines(rep, "batch")[0]
    assert low_confidence_lines(rep, "demo")[0].endswith("where the hand is seen more clearly")
    assert "hand's keypoints" in str(low_confidence_error(rep))


def test_contact_line_says_when_the_object_was_moved_onto_the_hand():
    met = {"in_contact": True, "contact_distance_cm": -0.01, "object_moved_to_hand_cm": 1.6575}
    assert contact_line(met) == (
        "the object was moved 1.7 cm onto the hand, which the photo's masks place beside it: the "
        "object mask or the hand's keypoints may be wrong (see masks.png); re-run with "
        "--object-point X,Y on the held object (or --object-box X0,Y0,X1,Y1 around it, or "
        "--object-choice K for region K of masks.png)"
    )
    # a move within the contact tolerance is a touching hand anyway
    assert contact_line({**met, "object_moved_to_hand_cm": 0.3}) is None
    assert contact_line({**met, "object_moved_to_hand_cm": None}) is None


def test_strict_names_no_numbered_region_as_it_writes_no_masks_png():
    from easyhoi.perception.feedback import low_confidence_error

    rep = report(object=(0.2, ("touches the border",)))
    (line,) = low_confidence_lines(rep)
    assert "--object-choice K for region K of masks.png" in line
    err = str(low_confidence_error(rep))
    assert "--object-point X,Y on the held object" in err and "masks.png" not in err
    assert err.endswith("(--strict: no result written)")


def test_no_region_is_named_where_masks_png_numbers_none():
    rep = report(object=(0.2, ("no contrast",)))
    named = "--object-choice K"
    assert named in low_confidence_lines(rep)[0]  # regions not known: named
    for regions, shown in ((0, False), (1, False), (2, True), (4, True)):
        rep["regions"] = regions
        for prompted in (False, True):
            cli = low_confidence_lines(rep, "cli", prompted)[0]
            batch = low_confidence_lines(rep, "batch", prompted)[0]
            assert (named in cli) is shown and ("object_choice" in batch) is shown
    rep["regions"] = 1
    assert low_confidence_lines(rep, "cli")[0].endswith(
        "re-run with --object-point X,Y on the held object (or --object-box X0,Y0,X1,Y1 around it)"
    )
    assert low_confidence_lines(rep, "batch", prompted=True)[0].endswith(
        "background_point rows on what it takes in beyond the object, or an object_box"
    )
    # the demo names no command-line option either way
    assert "choice" not in low_confidence_lines(rep, "demo")[0]
