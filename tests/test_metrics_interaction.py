"""Intersection volume, penetration depth and contact on shapes with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.metrics.interaction import (
    contact_ratio,
    in_contact,
    intersection_volume,
    penetration_depth,
)


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(
        extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2)
    )


def test_overlapping_boxes_solid_volume_is_exact_on_aligned_grid():
    hand = _box([0, 0, 0], [0.04, 0.04, 0.04])
    obj = _box([0.02, 0.01, 0.0], [0.06, 0.05, 0.04])
    # overlap 2 x 3 x 4 cm
    assert intersection_volume(hand, obj, method="solid") == pytest.approx(24.0, abs=1e-9)
    # a finer grid converges to the same value
    assert intersection_volume(hand, obj, pitch=0.0025, method="solid") == pytest.approx(24.0)


def test_solid_volume_of_a_sphere_overlap_within_grid_tolerance():
    hand = _box([-0.05, -0.05, -0.05], [0.05, 0.05, 0.05])
    obj = trimesh.creation.icosphere(4, radius=0.03)
    exact = obj.volume * 1e6  # cm^3 of the polyhedron (~ 4/3 pi 3^3 = 113.1)
    assert intersection_volume(hand, obj, method="solid") == pytest.approx(exact, rel=0.03)
    assert intersection_volume(hand, obj, pitch=0.002, method="solid") == pytest.approx(
        exact, rel=0.01
    )


def test_obman_variant_counts_surface_voxels_only():
    # Object cube of side a (cm) nested in a large hand box: trimesh's surface voxelization with
    # pitch 0.5 cm puts a voxel centre at every grid point on the cube's surface,
    # (2a + 1)^3 - (2a - 1)^3 of them; each counts 0.125 cm^3.
    hand = _box([-0.05, -0.05, -0.05], [0.05, 0.05, 0.05])
    for side_cm, n_vox in ((2.0, 5**3 - 3**3), (5.0, 11**3 - 9**3)):
        obj = trimesh.creation.box((side_cm / 100,) * 3)
        iv = intersection_volume(hand, obj, method="obman")
        assert iv == pytest.approx(n_vox * 0.125, abs=1e-9)
        solid = intersection_volume(hand, obj, method="solid")
        assert solid == pytest.approx(side_cm**3, abs=1e-9)
    # 5 cm cube: ObMan reports 75.25 cm^3 for a true overlap of 125 cm^3 (under-counts)
    assert 602 * 0.125 == 75.25


def test_disjoint_meshes_give_zero():
    hand = _box([0, 0, 0], [0.03, 0.03, 0.03])
    obj = _box([0.05, 0, 0], [0.08, 0.03, 0.03])
    for method in ("obman", "solid"):
        assert intersection_volume(hand, obj, method=method) == 0.0
    assert penetration_depth(hand, obj) == 0.0


def test_nested_hand_inside_object():
    obj = _box([-0.05, -0.05, -0.05], [0.05, 0.05, 0.05])
    hand = trimesh.creation.icosphere(4, radius=0.02)
    assert intersection_volume(hand, obj, method="solid") == pytest.approx(
        hand.volume * 1e6, rel=0.05
    )
    # depth of a vertex in the centred 10 cm cube: 5 cm - its largest |coordinate| (naive
    # reference); the deepest is the vertex nearest a diagonal, below 5 - 2 / sqrt(3) cm
    expected = (0.05 - np.abs(hand.vertices).max(axis=1)).max() * 100
    assert penetration_depth(hand, obj) == pytest.approx(expected, abs=1e-9)
    assert 3.0 < expected < 5 - 2 / math.sqrt(3)


@pytest.mark.parametrize("d_cm", [0.2, 0.5, 0.8])
def test_penetration_depth_of_a_pushed_box(d_cm):
    d = d_cm / 100
    obj = _box([0, -0.02, -0.02], [0.04, 0.02, 0.02])
    hand = _box([-0.04 + d, -0.01, -0.01], [d, 0.01, 0.01])
    assert penetration_depth(hand, obj) == pytest.approx(d_cm, abs=1e-9)
    assert in_contact(hand, obj)


def test_contact_threshold_and_ratio():
    obj = _box([0, -0.02, -0.02], [0.04, 0.02, 0.02])
    near = _box([-0.043, -0.01, -0.01], [-0.003, 0.01, 0.01])  # 3 mm gap
    far = _box([-0.048, -0.01, -0.01], [-0.008, 0.01, 0.01])  # 8 mm gap
    assert in_contact(near, obj) and not in_contact(far, obj)
    assert in_contact(far, obj, threshold=0.01)
    assert contact_ratio([(near, obj), (far, obj), (near, obj), (far, obj)]) == 0.5
    with pytest.raises(InvalidInputError, match="at least one"):
        contact_ratio([])


def test_requires_watertight_and_valid_inputs():
    box = _box([0, 0, 0], [0.03, 0.03, 0.03])
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    with pytest.raises(InvalidInputError, match="watertight"):
        intersection_volume(open_box, box)
    with pytest.raises(InvalidInputError, match="watertight"):
        intersection_volume(box, open_box, method="solid")
    intersection_volume(box, open_box, method="obman")  # the object may be open under ObMan
    with pytest.raises(InvalidInputError, match="watertight"):
        penetration_depth(box, open_box)
    with pytest.raises(InvalidInputError, match="pitch"):
        intersection_volume(box, box, pitch=0.0)
    with pytest.raises(InvalidInputError, match="method"):
        intersection_volume(box, box, method="voxel")
    with pytest.raises(InvalidInputError, match="NaN"):
        penetration_depth((np.full((3, 3), math.nan), [[0, 1, 2]]), box)


def test_inward_oriented_hand_is_handled():
    hand = _box([0, 0, 0], [0.04, 0.04, 0.04])
    flipped = trimesh.Trimesh(hand.vertices, hand.faces[:, ::-1], process=False)
    obj = _box([0.02, 0.01, 0.0], [0.06, 0.05, 0.04])
    assert intersection_volume(flipped, obj, method="solid") == pytest.approx(24.0)
