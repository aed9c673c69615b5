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
         "same": True, "cue_perception": None, "cue_drawn": "gap"},
        {"photo": "b", "mask_iou": 0.4, "perception": "inflation", "drawn": "inflation",
         "same": True, "cue_perception": "pinch", "cue_drawn": "gap"},
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
    # the thickness cue counted by source, rows without one (or older rows) left out
    assert s["perception_thickness_cue"] == {"pinch": 1}
    assert s["drawn_thickness_cue"] == {"gap": 2}


def test_thickness_cue_reads_the_source_recorded_on_the_mesh():
    bs = _script()
    mesh = trimesh.creation.box()
    mesh.metadata["easyhoi"] = {"method": "slab", "shape": {"depth_cue_from": "pinch"}}
    assert bs.thickness_cue(mesh) == "pinch"
    mesh.metadata["easyhoi"] = {"method": "inflation", "shape": {"depth_cue_from": None}}
    assert bs.thickness_cue(mesh) is None
    assert bs.thickness_cue(trimesh.creation.box()) is None  # a mesh of another backend


def test_mesh_views_show_a_flat_box_wide_from_the_front_and_thin_from_the_right():
    bs = _script()
    slab = trimesh.creation.box(extents=(1.0, 0.6, 0.1))  # u right, v down, z along the view
    pic = bs.mesh_views(slab, size=96)
    assert pic.shape == (96, 192, 3) and pic.dtype == np.uint8
    covered = np.abs(pic.astype(int) - 250).sum(-1) > 30
    front, right = covered[:, :96], covered[:, 96:]
    # from the camera the slab is 1.0 wide; from the right only its 0.1 depth shows
    assert np.ptp(np.nonzero(front.any(0))[0]) > 4 * np.ptp(np.nonzero(right.any(0))[0])
    # both show its 0.6 height (the right view nearer to the slab's near edge: larger)
    assert 0.6 < front.any(1).sum() / right.any(1).sum() <= 1.0


def test_outlined_crop_frames_both_outlines_and_draws_them():
    bs = _script()
    rgb = np.full((200, 300, 3), 128, np.uint8)
    perceived = np.zeros((200, 300), bool)
    perceived[80:120, 100:140] = True
    drawn = np.zeros((200, 300), bool)
    drawn[70:130, 100:180] = True
    out = bs.outlined_crop(rgb, perceived, drawn)
    assert out.shape[0] == bs.VIEW_PX
    # the crop holds both outlines with a margin: 80 x 60 px grown by a sixth each side
    assert out.shape[1] / out.shape[0] == pytest.approx((80 + 2 * 15) / (60 + 2 * 15), abs=0.05)
    for colour in (bs.PERCEPTION_RGB, bs.DRAWN_RGB):
        assert (out == np.array(colour, np.uint8)).all(-1).any()


def test_shape_family_reads_the_reconstructors_record():
    bs = _script()
    mesh = trimesh.creation.box()
    mesh.metadata["easyhoi"] = {"method": "cuboid", "shape": {"shape": "cuboid"}}
    assert bs.shape_family(mesh) == "cuboid"


def test_summary_scores_the_family_against_the_objects_kind():
    bs = _script()
    rows = [
        {"photo": "cup", "kind": "reusable cup", "perception": "inflation", "drawn": "revolution"},
        {"photo": "phone", "kind": "phone", "perception": "cuboid", "drawn": "revolution"},
        {"photo": "pen", "kind": "pen", "perception": "tube", "drawn": "tube"},
        {"photo": "horn", "kind": "trumpet", "perception": "cuboid", "drawn": "inflation"},
        {"photo": "old", "perception": "slab", "drawn": "slab"},  # a row without a kind
    ]
    for r in rows:
        r.update(mask_iou=0.9, same=True)
    s = bs.summary(rows)
    # a trumpet suits no one family and a row without a kind is not scored
    assert s["kind_scored"] == 3
    assert s["perception_kind_right"] == 2  # the phone's cuboid and the pen's tube
    assert s["drawn_kind_right"] == 2  # the cup's and the pen's round families
    # every reference object's name that is scored names a known family
    from easyhoi.perception.shapes import FAMILIES

    assert all(set(v) <= set(FAMILIES) and "inflation" not in v for v in bs.KIND_FAMILIES.values())


def test_reference_kind_is_the_name_of_the_first_held_object(tmp_path):
    import json

    bp = load_script("benchmarks/bench_perception.py")
    hand = {"side": "right", "holds_object": True, "polygons": [[[0, 0], [5, 0], [5, 5]]]}
    ref = {"image": "x.png", "width": 10, "height": 10, "note": "", "hands": [hand],
           "objects": [{"name": "poster", "held_by": [], "visibly_held": False,
                        "polygons": [[[6, 6], [9, 6], [9, 9]]]},
                       {"name": "mug", "held_by": [0], "visibly_held": True,
                        "polygons": [[[1, 1], [4, 1], [4, 4]]]}]}  # fmt: skip
    path = tmp_path / "x__y.json"
    path.write_text(json.dumps(ref))
    assert bp.reference(path)["kind"] == "mug"
