"""benchmarks/bench_real_shapes.py: the drawn outline completed behind the hand, and the summary
of the families found on perception's outlines and on the drawn ones."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.helpers import load_script


def _script():
    return load_script("benchmarks/bench_real_shapes.py")


def test_drawn_outline_is_completed_only_behind_the_hand():
    bs = _script()
    yy, xx = np.mgrid[:80, :80]
    disk = (yy - 40) ** 2 + (xx - 40) ** 2 <= 20**2
    hand = (xx >= 35) & (xx < 45)  # a finger across the disk
    drawn = disk & ~hand  # the reference outlines the visible object only
    out = bs.completed_reference(drawn, hand)
    assert (out & drawn).sum() == drawn.sum()  # it contains the drawn outline
    added = out & ~drawn
    grown = (xx >= 33) & (xx < 47)  # the hand grown by the amodal step's 2 px
    assert added.any() and not (added & ~grown).any()  # only behind the (grown) hand
    # the band of the disk the finger hides comes back (the hull of the two halves spans it)
    assert (out & disk & hand).sum() >= 0.9 * (disk & hand).sum()
    # a concave outline (an L) keeps its corner open: the hull is used only behind the hand
    ell = ((xx >= 10) & (xx < 20) & (yy >= 10) & (yy < 70)) | ((yy >= 60) & (yy < 70) & (xx < 70))
    finger = (yy >= 30) & (yy < 36)
    out = bs.completed_reference(ell & ~finger, finger)
    corner = (xx >= 30) & (xx < 50) & (yy >= 40) & (yy < 55)  # inside the L's hull, not the L
    assert not (out & corner).any()
    assert (out & ell & finger).sum() == (ell & finger).sum()


def test_summary_counts_families_inflations_and_differences():
    bs = _script()
    rows = [
        {"photo": "a", "mask_iou": 0.9, "perception": "inflation", "drawn": "revolution",
         "same": True},
        {"photo": "b", "mask_iou": 0.4, "perception": "inflation", "drawn": "inflation",
         "same": True},
        {"photo": "c", "mask_iou": 0.7, "perception": "cuboid", "drawn": "cuboid", "same": False},
        {"photo": "d", "error": "NoHandError: no hand"},
    ]  # fmt: skip
    s = bs.summary(rows)
    assert s["photos"] == 4 and s["reconstructed"] == 3
    assert s["perception_families"] == {"cuboid": 1, "inflation": 2}
    assert s["drawn_families"] == {"cuboid": 1, "inflation": 1, "revolution": 1}
    assert s["perception_inflation"] == 2 and s["drawn_inflation"] == 1
    assert s["differ"] == 1 and s["chain_family_reproduced"] == 2
    assert s["mask_iou_ge_0.5"] == pytest.approx(2 / 3)


def test_shape_family_reads_the_reconstructors_record():
    bs = _script()
    mesh = trimesh.creation.box()
    mesh.metadata["easyhoi"] = {"method": "cuboid", "shape": {"shape": "cuboid"}}
    assert bs.shape_family(mesh) == "cuboid"
