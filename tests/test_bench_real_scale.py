"""benchmarks/bench_real_scale.py: the size error against a kind's range, the box sides of a
metric mesh, and its photo list (every entry has a reference and a kind with a size)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from tests.helpers import ROOT, load_script


def _script():
    return load_script("benchmarks/bench_real_scale.py")


def test_range_error_is_zero_inside_and_relative_to_the_nearer_end():
    bs = _script()
    assert bs.range_error(118.0, 115.0, 122.0) == 0.0
    assert bs.range_error(115.0, 115.0, 122.0) == 0.0
    assert bs.range_error(57.0, 66.0, 66.0) == pytest.approx(9 / 66)
    assert bs.range_error(178.4, 115.0, 122.0) == pytest.approx(56.4 / 122)


def test_box_sides_of_a_rotated_metric_box_in_millimetres():
    bs = _script()
    box = trimesh.creation.box(extents=(0.02, 0.1, 0.05))
    R = trimesh.transformations.rotation_matrix(0.7, [1.0, 2.0, 0.5])
    box.apply_transform(R)
    np.testing.assert_allclose(bs.obb_sides_mm(box), [100.0, 50.0, 20.0], atol=0.5)


def test_every_photo_has_a_reference_labelled_as_its_kind():
    bs = _script()
    refs = ROOT / "tests" / "data" / "perception_refs"
    for stem, kind in bs.PHOTOS.items():
        (l_lo, l_hi), (s_lo, s_hi) = bs.KINDS[kind]
        assert 0 < s_lo <= s_hi <= l_lo <= l_hi
        labels = [o["name"] for o in json.loads((refs / f"{stem}.json").read_text())["objects"]]
        # the reference names the held object; the kind is that label or the object it is
        assert any(kind.split()[-1] in lab or lab in kind for lab in labels), (stem, labels)


def test_summary_medians_and_means_over_the_reconstructed_photos():
    bs = _script()
    rows = [
        {"longest_err": 0.0, "second_err": 0.1, "longest_ratio": 1.0},
        {"longest_err": 0.2, "second_err": 0.0, "longest_ratio": 0.5},
        {"longest_err": 0.4, "second_err": 0.3, "longest_ratio": 2.0},
        {"error": "NoHandError: no hand"},
    ]
    s = bs.summary(rows)
    assert s["photos"] == 4 and s["reconstructed"] == 3 and s["longest_in_range"] == 1
    assert s["longest_err_median"] == pytest.approx(0.2)
    assert s["longest_err_mean"] == pytest.approx(0.2)
    assert s["second_err_median"] == pytest.approx(0.1)
    assert s["log_ratio_mean"] == pytest.approx(0.0, abs=1e-12)  # log 0.5 + log 2 = 0
    assert s["longest_ratio_median"] == pytest.approx(1.0)
