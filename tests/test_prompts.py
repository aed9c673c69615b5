"""Prompts: parsing, validation against the photo, round trip."""

import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.perception.prompts import Prompts, parse_numbers


def test_parse_numbers():
    assert parse_numbers("3, 4.5", 2, "--object-point") == (3.0, 4.5)
    assert parse_numbers("0,1,2,3", 4, "--object-box") == (0.0, 1.0, 2.0, 3.0)
    for bad in ("3", "3,4,5", "a,b", "nan,1", "inf,2"):
        with pytest.raises(InvalidInputError, match="--object-point"):
            parse_numbers(bad, 2, "--object-point")


def test_check_inside_photo():
    ok = Prompts(((0, 0), (9.5, 4)), (1, 1, 20, 20), (5, 4))
    assert ok.check(10, 5) is ok
    with pytest.raises(InvalidInputError, match="outside the 10x5 photo"):
        Prompts(((10, 0),)).check(10, 5)
    with pytest.raises(InvalidInputError, match="--hand-point"):
        Prompts(hand_point=(1, 5)).check(10, 5)
    with pytest.raises(InvalidInputError, match="--background-point -1,2 lies outside"):
        Prompts(background_points=((1, 1), (-1, 2))).check(10, 5)
    with pytest.raises(InvalidInputError, match="x0 < x1"):
        Prompts(object_box=(5, 1, 5, 3)).check(10, 5)
    with pytest.raises(InvalidInputError, match="does not overlap"):
        Prompts(object_box=(11, 1, 15, 3)).check(10, 5)


def test_round_trip_and_flags():
    p = Prompts(((1.0, 2.0),), (0.0, 0.0, 4.0, 4.0), (3.0, 3.0), ((5.0, 1.0),))
    assert Prompts.from_dict(p.to_dict()) == p
    assert not p.empty and p.has_object_prompt
    assert Prompts().empty and not Prompts(hand_point=(1, 1)).has_object_prompt
    # background points alone are a prompt, not an object prompt
    bg = Prompts(background_points=((2.0, 2.0),))
    assert not bg.empty and not bg.has_object_prompt
    with pytest.raises(InvalidInputError, match="background_points must be a list"):
        Prompts.from_dict({"background_points": 3})
    with pytest.raises(InvalidInputError, match="unknown prompt keys"):
        Prompts.from_dict({"object_pts": []})
    with pytest.raises(InvalidInputError, match="object_box"):
        Prompts.from_dict({"object_box": [1, 2, 3]})


def test_mask_confidence_and_report():
    from easyhoi.perception.chain import PerceptionReport
    from easyhoi.perception.confidence import LOW_CONFIDENCE, MaskConfidence

    hi = MaskConfidence(0.9)
    lo = MaskConfidence(LOW_CONFIDENCE - 0.01, ["object runs out of the frame"])
    assert not hi.low and lo.low and MaskConfidence(LOW_CONFIDENCE).low is False
    with pytest.raises(ValueError):
        MaskConfidence(1.5)
    r = PerceptionReport(confidence={"hand": hi, "object": lo})
    assert r.low_confidence == ["object"]
    d = r.to_dict()["confidence"]
    assert d["object"] == {"score": 0.49, "low": True, "reasons": ["object runs out of the frame"]}
