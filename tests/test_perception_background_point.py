"""Background points (``--background-point``): what the user marks as not the object stays out,
on drawn scenes with a known answer, and the region test against a per-mask reference."""

from __future__ import annotations

import numpy as np

from easyhoi.perception import not_object
from easyhoi.perception.masks import ClassicalHOISegmenter
from easyhoi.perception.prompts import Prompts
from easyhoi.perception.proposals import propose
from tests.test_perception_click import XX, YY, click
from tests.test_perception_held_object import S, canvas, det, finish, grasped_disk, scene_of
from tests.test_perception_masks import BLUE, RED, iou


def leaky_scene():
    """A red object with a patch of a slightly different red below it (a weak edge between
    them, as between an object and a background of its colour): one click takes both."""
    obj = (np.abs(XX - 195) < 26) & (np.abs(YY - 60) < 32)
    leak = (np.abs(XX - 195) < 26) & (YY >= 92) & (YY < 130)
    img = canvas()
    img[obj] = (200, 40, 40)
    img[leak] = (190, 50, 45)
    img, hand = finish(img)
    assert not ((obj | leak) & hand).any()
    return img, obj, leak


def segment(img, **prompts):
    seg = ClassicalHOISegmenter(seed=0).segment(img, det(), prompts=Prompts(**prompts))
    return seg


def test_a_background_point_takes_the_leak_away():
    img, obj, leak = leaky_scene()
    one = click(img, 195.0, 60.0)
    assert iou(one, obj | leak) > 0.9  # the leak: one click takes the patch too
    seg = segment(img, object_points=((195.0, 60.0),), background_points=((195.0, 112.0),))
    assert seg.has_object
    assert iou(seg.object_mask, obj) > 0.9
    assert (seg.object_mask & leak).sum() < 0.05 * leak.sum()
    # the same again (deterministic)
    again = segment(img, object_points=((195.0, 60.0),), background_points=((195.0, 112.0),))
    assert np.array_equal(seg.object_mask, again.object_mask)


def test_a_background_point_takes_the_leak_out_of_a_box():
    img, obj, leak = leaky_scene()
    box = (165.0, 25.0, 225.0, 133.0)  # around the object and the patch below it
    boxed = segment(img, object_box=box)
    assert iou(boxed.object_mask, obj | leak) > 0.9
    seg = segment(img, object_box=box, background_points=((195.0, 112.0),))
    assert iou(seg.object_mask, obj) > 0.9
    assert (seg.object_mask & leak).sum() < 0.05 * leak.sum()


def test_a_background_point_away_from_the_object_changes_nothing():
    img, obj, leak = leaky_scene()
    one = click(img, 195.0, 60.0)
    far = segment(img, object_points=((195.0, 60.0),), background_points=((20.0, 225.0),))
    assert iou(far.object_mask, one) > 0.98


def test_a_background_point_on_the_automatic_choice_removes_it():
    disk = grasped_disk()
    wall = np.zeros((S, S), bool)
    wall[:, 170:] = True
    img, hand = scene_of([(wall, RED), (disk, BLUE)])
    auto = ClassicalHOISegmenter(seed=0).segment(img, det())
    assert auto.has_object and iou(auto.object_mask, disk & ~hand) > 0.7
    seg = segment(img, background_points=((88.0, 128.0),))  # on the grasped disk
    assert not seg.meta["prompted"]  # background points alone keep the automatic path
    assert not seg.has_object or iou(seg.object_mask, disk & ~hand) < 0.2
    assert not (seg.object_mask & disk).any() or not seg.object_mask[128, 88]


def test_enclosing_regions_match_the_per_mask_test():
    # a ring-shaped region around a point, a region beside it and the hierarchy over them
    img = canvas()
    r2 = (XX - 120) ** 2 + (YY - 120) ** 2
    ring = (r2 < 40**2) & (r2 > 3**2)  # a hole smaller than the point's disk
    img[ring] = (40, 160, 60)
    img[(np.abs(XX - 200) < 20) & (np.abs(YY - 40) < 20)] = (40, 40, 200)
    img = np.clip(img, 0, 255).astype(np.uint8)
    import cv2

    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    props = propose(img, lab, np.zeros((S, S), bool), 100.0, 20)
    disks = not_object.disks((S, S), np.array([[120.0, 120.0], [10.0, 230.0]]), 40.0)
    assert len(disks) == 2 and all(d.sum() > 40 for d in disks)
    rings = not_object.rings(disks, np.zeros((S, S), bool))
    fast = not_object.enclosing_regions(props, rings)
    slow = np.array([not_object.encloses(props.mask(r), rings) for r in props.regions])
    assert fast.shape == (len(props.regions),)
    np.testing.assert_array_equal(fast, slow)
    assert fast.any() and not fast.all()
    # the green ring encloses the first point (its hole is the disk), the blue square nothing
    assert not_object.encloses(ring, rings)
    blue = (np.abs(XX - 200) < 20) & (np.abs(YY - 40) < 20)
    assert not not_object.encloses(blue, rings)


def test_points_outside_the_crop_make_no_disk():
    assert not_object.disks((10, 20), np.array([[25.0, 5.0], [5.0, -1.0]]), 10.0) == []
    (d,) = not_object.disks((10, 20), np.array([[5.0, 5.0]]), 10.0)
    assert d[5, 5] and d.sum() == 13  # radius 2 px at least


def test_a_background_points_patch_is_its_colour_within_half_a_palm():
    import cv2

    img = np.full((S, S, 3), 200, np.uint8)
    img[:, 130:] = (40, 40, 200)  # an edge at x = 130
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
    (d,) = not_object.disks((S, S), np.array([[110.0, 120.0]]), 40.0)
    p = not_object.patch(lab, d, 40.0)
    assert p[d].all()  # the disk itself
    reach = 0.5 * 40.0
    assert p[120, 110 - int(reach) + 1] and not p[120, 110 - int(reach) - 2]  # up to 0.5 L
    assert p[120, 129] and not p[120, 130:].any()  # not across the colour edge
    assert p.sum() < np.pi * reach**2 + 10
