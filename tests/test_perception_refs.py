"""The reference outlines of the perception development set: format, geometry, agreement."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from tests.perception_refs import (
    HandRef,
    ObjectRef,
    PerceptionRef,
    RefFormatError,
    hand_mask,
    held_object_mask,
    load_ref,
    load_refs,
    mask_iou,
    object_masks,
    object_point,
    parse_ref,
    rasterize,
    ref_keys,
)

KEYS = ref_keys()
# The two photos with an object mask made with SAM 2 by the photos' publishers.
SAM_CHECKED = (
    "photos-dev__mccho-boardgame_v_W_qdSiPKSdQ_frame000019",
    "photos-dev__mccho-drink_v_1F96GArORtg_frame000084",
)


def _shoelace(poly) -> float:
    p = np.asarray(poly, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _rect_ref(x0: int, y0: int, x1: int, y1: int) -> PerceptionRef:
    box = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
    finger = ((0, 0), (3, 0), (3, 3), (0, 3))
    return PerceptionRef(
        key="synthetic",
        image="none.png",
        width=64,
        height=48,
        hands=(HandRef("right", (finger,), True),),
        objects=(ObjectRef("box", (box,), (0,), True),),
        note="",
    )


def test_rasterize_rectangle_counts_boundary_pixels():
    # Vertices on pixel centres, boundary included: columns 2..11 and rows 3..7.
    mask = rasterize([[[2, 3], [11, 3], [11, 7], [2, 7]]], 20, 30)
    assert mask.sum() == 10 * 5
    assert mask[3:8, 2:12].all()


def test_rasterize_triangle_counts_lattice_points():
    # Right triangle with legs of 10 px: pixels with x, y >= 0 and x + y <= 10,
    # i.e. 1 + 2 + ... + 11 = 66.
    mask = rasterize([[[0, 0], [10, 0], [0, 10]]], 16, 16)
    assert mask.sum() == 66
    ys, xs = np.nonzero(mask)
    assert (xs + ys <= 10).all()


def test_rasterize_union_of_polygons():
    a = [[0, 0], [4, 0], [4, 4], [0, 4]]
    b = [[2, 2], [6, 2], [6, 6], [2, 6]]
    assert rasterize([a, b], 10, 10).sum() == 25 + 25 - 9


def test_object_point_is_the_centre_of_a_rectangle():
    ref = _rect_ref(10, 20, 30, 30)  # 21 x 11 pixels, centre (20, 25)
    assert object_point(ref) == (20, 25)


def test_object_point_without_held_object_is_none():
    ref = _rect_ref(10, 20, 30, 30)
    free = PerceptionRef(ref.key, ref.image, 64, 48, ref.hands, (), "")
    assert object_point(free) is None


def test_parse_ref_rejects_bad_fields():
    good = {
        "image": "x.png",
        "width": 10,
        "height": 10,
        "hands": [{"side": "left", "holds_object": True, "polygons": [[[0, 0], [5, 0], [0, 5]]]}],
        "objects": [
            {
                "name": "cup",
                "held_by": [0],
                "visibly_held": True,
                "polygons": [[[1, 1], [4, 1], [1, 4]]],
            }
        ],
        "note": "",
    }
    assert parse_ref(good, "ok").hands[0].side == "left"
    for path, value in [
        (("hands", 0, "side"), "both"),
        (("objects", 0, "held_by"), [1]),
        (("objects", 0, "polygons"), [[[0, 0], [1, 1]]]),
        (("hands", 0, "polygons"), [[[0, 0], [1, 1], ["a", 2]]]),
    ]:
        bad = json.loads(json.dumps(good))
        target = bad
        for k in path[:-1]:
            target = target[k]
        target[path[-1]] = value
        with pytest.raises(RefFormatError):
            parse_ref(bad, "bad")


def test_references_exist():
    assert len(KEYS) >= 2
    for key in KEYS:
        folder, _, stem = key.partition("__")
        assert folder in ("photos-dev", "images") and stem


@pytest.mark.parametrize("key", KEYS)
def test_reference_geometry(key):
    ref = load_ref(key)
    folder, _, stem = key.partition("__")
    assert ref.image.startswith(folder + "/") and ref.image.rsplit(".", 1)[0].endswith(stem)
    assert ref.hands, "every development photo shows at least one hand"
    for item in (*ref.hands, *ref.objects):
        for poly in item.polygons:
            p = np.asarray(poly)
            assert (p[:, 0] >= 0).all() and (p[:, 0] <= ref.width - 1).all(), key
            assert (p[:, 1] >= 0).all() and (p[:, 1] <= ref.height - 1).all(), key
            assert _shoelace(poly) >= 4.0, f"{key}: degenerate polygon {poly[:3]}..."
            assert rasterize([poly], ref.height, ref.width).sum() >= 4
    # A hand holds an object exactly when some object names it in held_by.
    holders = {i for o in ref.objects for i in o.held_by}
    assert holders == {i for i, h in enumerate(ref.hands) if h.holds_object}, key
    hands = hand_mask(ref)
    for obj, mask in zip(ref.objects, object_masks(ref), strict=True):
        assert mask.any()
        overlap = np.logical_and(mask, hands).sum() / mask.sum()
        assert overlap < 0.05, f"{key}: {obj.name} overlaps the hands by {overlap:.1%}"
    point = object_point(ref)
    if any(o.held_by for o in ref.objects):
        x, y = point
        assert held_object_mask(ref)[y, x]
    else:
        assert point is None


@pytest.mark.parametrize("key", KEYS)
def test_reference_size_matches_photo(key, shared_data):
    ref = load_ref(key)
    path = ref.image_path(shared_data)
    assert path.is_file(), path
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None, path
    assert image.shape[:2] == (ref.height, ref.width)


@pytest.mark.parametrize("key", SAM_CHECKED)
def test_reference_agrees_with_sam_mask(key, shared_data):
    """The drawn object outline matches the independent SAM 2 object mask.

    SAM 2 object masks take in the fingers lying on the object, which the references cut out,
    so the comparison leaves out the pixels of the reference hands.
    """
    ref = load_ref(key)
    sam_path = shared_data / ref.image.replace(".jpg", "_mask.png")
    sam = cv2.imread(str(sam_path), cv2.IMREAD_GRAYSCALE) > 127
    visible_sam = sam & ~hand_mask(ref)
    assert mask_iou(held_object_mask(ref), visible_sam) >= 0.75


def test_every_development_photo_has_a_reference(shared_data):
    photos = [
        f"{folder}__{p.stem}"
        for folder in ("photos-dev", "images")
        for p in sorted((shared_data / folder).iterdir())
        if p.suffix.lower() in (".jpg", ".png") and not p.stem.endswith("_mask")
    ]
    assert len(photos) == 39
    assert sorted(photos) == KEYS


def test_load_refs_matches_keys():
    refs = load_refs()
    assert [r.key for r in refs] == KEYS
