"""``bench_perception.py``'s photo transforms (``--resample``, ``--jpeg``, ``--mirror``,
``--rotate``, ``--crop``) and drawn clicks: the photo changed as the loader or a dataset would
change it, with the reference (masks and object point) following it."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import load_script


def test_resample_scales_the_photo_and_keeps_the_loader_cap():
    bench = load_script("benchmarks/bench_perception.py")
    rgb = np.zeros((300, 500, 3), np.uint8)
    rgb[100:200, 200:300] = 255  # a white square
    assert bench.resample(rgb, 1.0) is rgb
    half = bench.resample(rgb, 0.5)
    assert half.shape == (150, 250, 3)
    # area averaging keeps the square's mean brightness
    assert abs(half.mean() - rgb.mean()) < 0.5
    assert bench.resample(rgb, 1.5).shape == (450, 750, 3)
    # never beyond the loader's longer side of 1600 px
    assert bench.resample(rgb, 10.0).shape == (960, 1600, 3)


def test_reference_follows_the_resampled_photo():
    bench = load_script("benchmarks/bench_perception.py")
    obj = np.zeros((300, 500), bool)
    obj[100:200, 200:300] = True
    ref = {"hand": [obj.copy()], "object": obj, "point": (250.0, 150.0)}
    small = bench.fit_to(ref, bench.resample(np.zeros((300, 500, 3), np.uint8), 0.5).shape[:2])
    assert small["object"].shape == (150, 250)
    assert small["point"] == (125.0, 75.0)
    assert small["object"][75, 125] and small["object"].sum() == 50 * 50


def test_jpeg_reencoding_keeps_the_scene_and_changes_the_pixels():
    bench = load_script("benchmarks/bench_perception.py")
    rng = np.random.default_rng(3)
    rgb = np.zeros((120, 160, 3), np.uint8)
    rgb[:, :80] = (200, 40, 30)  # a red half and a blue half, with a little noise
    rgb[:, 80:] = (20, 60, 210)
    rgb = np.clip(rgb + rng.normal(0, 4, rgb.shape), 0, 255).astype(np.uint8)
    out = bench.reencode(rgb, 90)
    assert out.shape == rgb.shape and out.dtype == np.uint8
    # the channel order is kept (red stays red), the colours stay within a few levels...
    assert out[60, 20, 0] > 150 and out[60, 20, 2] < 80 and out[60, 140, 2] > 150
    diff = np.abs(out.astype(int) - rgb.astype(int))
    assert diff.mean() < 4.0
    # ...but the pixels differ, more at a lower quality
    assert (diff > 0).mean() > 0.3
    assert np.abs(bench.reencode(rgb, 30).astype(int) - rgb.astype(int)).mean() > diff.mean()


def test_mirror_flips_the_photo_and_its_reference_together():
    bench = load_script("benchmarks/bench_perception.py")
    rgb = np.zeros((300, 500, 3), np.uint8)
    rgb[100:200, 20:60] = (255, 0, 0)
    obj = np.zeros((300, 500), bool)
    obj[100:200, 20:60] = True
    ref = {"hand": [obj.copy()], "object": obj, "point": (39.0, 150.0)}
    m_rgb, m_ref = bench.mirror(rgb, ref)
    # the red bar now lies at columns 440-479, as do the masks, and the point with them
    assert m_rgb[150, 459, 0] == 255 and m_rgb[150, 39, 0] == 0
    assert m_ref["object"][100:200, 440:480].all() and m_ref["object"].sum() == obj.sum()
    assert m_ref["hand"][0][150, 460] and not m_ref["hand"][0][150, 40]
    assert m_ref["point"] == (460.0, 150.0)
    assert m_rgb[int(m_ref["point"][1]), int(m_ref["point"][0]), 0] == 255
    # mirroring twice gives the original back; the input is left as it was
    back_rgb, back_ref = bench.mirror(m_rgb, m_ref)
    assert np.array_equal(back_rgb, rgb) and np.array_equal(back_ref["object"], obj)
    assert back_ref["point"] == ref["point"] and ref["object"][150, 40]
    assert bench.mirror(rgb, {**ref, "object": None, "point": None})[1]["object"] is None


def test_rotate_turns_the_photo_and_its_reference_together():
    bench = load_script("benchmarks/bench_perception.py")
    rgb = np.zeros((300, 500, 3), np.uint8)
    rgb[100:120, 20:60] = (255, 0, 0)  # a red bar near the left edge
    obj = rgb[..., 0] > 0
    ref = {"hand": [obj.copy()], "object": obj, "point": (39.0, 110.0)}
    one, one_ref = bench.rotate(rgb, ref, 1)
    # a quarter turn counter-clockwise: the left edge becomes the bottom edge
    assert one.shape == (500, 300, 3)
    assert one[500 - 1 - 39, 110, 0] == 255 and one_ref["point"] == (110.0, 460.0)
    for k in range(4):
        t_rgb, t_ref = bench.rotate(rgb, ref, k)
        x, y = (int(v) for v in t_ref["point"])
        # the point stays on the bar, the masks turn with the photo
        assert t_rgb[y, x, 0] == 255 and t_ref["object"][y, x] and t_ref["hand"][0][y, x]
        assert np.array_equal(t_ref["object"], t_rgb[..., 0] > 0)
    # four quarter turns give the original back; the input is left as it was
    back_rgb, back_ref = rgb, ref
    for _ in range(4):
        back_rgb, back_ref = bench.rotate(back_rgb, back_ref, 1)
    assert np.array_equal(back_rgb, rgb) and back_ref["point"] == ref["point"]
    assert bench.rotate(rgb, {**ref, "object": None, "point": None}, 2)[1]["object"] is None


def test_crop_cuts_around_the_holding_hand_and_the_object():
    bench = load_script("benchmarks/bench_perception.py")
    rgb = np.zeros((300, 500, 3), np.uint8)
    hand, other, obj = (np.zeros((300, 500), bool) for _ in range(3))
    hand[100:150, 100:150] = True
    other[0:20, 0:20] = True  # a hand that holds nothing: left out of the box
    obj[140:160, 150:250] = True
    rgb[obj] = 255
    ref = {"hand": [hand, other], "holds": [True, False], "object": obj, "point": (200.0, 150.0)}
    cut, cut_ref = bench.crop_around(rgb, ref, 1.0)
    # the box of the hand and the object: rows 100-159, columns 100-249
    assert cut.shape == (60, 150, 3) and cut_ref["point"] == (100.0, 50.0)
    assert cut_ref["object"].sum() == obj.sum() and cut_ref["hand"][0].sum() == hand.sum()
    assert cut[50, 100, 0] == 255 and cut_ref["object"][50, 100]
    # grown 2x about its centre (rows 70-189, columns 25-324), within the photo
    grown, grown_ref = bench.crop_around(rgb, ref, 2.0)
    assert grown.shape == (120, 300, 3) and grown_ref["point"] == (175.0, 80.0)
    assert bench.crop_around(rgb, ref, 100.0)[0].shape == rgb.shape
    with pytest.raises(SystemExit):
        bench.main(["--crop", "0.5"])


def test_a_drawn_click_lies_inside_the_object_deep_enough_and_is_seeded():
    from scipy import ndimage

    from tests.perception_refs import drawn_point

    obj = np.zeros((120, 200), bool)
    obj[20:100, 30:170] = True  # a 80 x 140 bar: deepest pixels 40 px from the outline
    depth = ndimage.distance_transform_edt(np.pad(obj, 1))[1:-1, 1:-1]
    pts = {drawn_point(obj, 0.5, f"photo{i}.jpg") for i in range(30)}
    assert len(pts) > 10  # the photos' names draw different clicks
    for x, y in pts:
        assert obj[int(y), int(x)]
        assert depth[int(y), int(x)] >= 0.5 * depth.max() - 1.0  # the 5x5 mask's distances
    # the same name draws the same click; share 1 leaves the deepest ridge only
    assert drawn_point(obj, 0.5, "a.jpg") == drawn_point(obj, 0.5, "a.jpg")
    x, y = drawn_point(obj, 1.0, "a.jpg")
    assert depth[int(y), int(x)] >= depth.max() - 1.0


def test_click_draw_needs_click_depth_and_a_count():
    bench = load_script("benchmarks/bench_perception.py")
    for argv in (["--click-draw", "2"], ["--click-depth", "0.5", "--click-draw", "-1"],
                 ["--click-depth", "1.5"]):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            bench.main(argv)
        assert exc.value.code == 2


def test_each_held_object_follows_the_photo_and_a_click_is_scored_on_its_own_object():
    bench = load_script("benchmarks/bench_perception.py")
    rgb = np.zeros((300, 500, 3), np.uint8)
    knife, slice_ = np.zeros((300, 500), bool), np.zeros((300, 500), bool)
    knife[100:110, 20:200] = True  # one object in each hand
    slice_[200:260, 300:360] = True
    both = knife | slice_
    hand = np.zeros((300, 500), bool)
    hand[90:150, 150:320] = True
    ref = {"hand": [hand], "holds": [True], "object": both, "objects": [knife, slice_],
           "point": (330.0, 230.0)}  # fmt: skip
    # the point lies on the slice: a mask of the slice alone is the clicked object, exactly
    assert bench.clicked_object(ref) is slice_
    assert bench.iou(slice_, bench.clicked_object(ref)) == 1.0
    assert bench.iou(slice_, both) == slice_.sum() / both.sum()  # what the union scores
    # every transform carries the objects with the point
    for t_ref in (bench.mirror(rgb, ref)[1], bench.rotate(rgb, ref, 1)[1],
                  bench.fit_to(ref, (150, 250)), bench.crop_around(rgb, ref, 1.2)[1]):  # fmt: skip
        on = bench.clicked_object(t_ref)
        x, y = (int(round(v)) for v in t_ref["point"])
        assert on[y, x] and on.sum() < t_ref["object"].sum()
        assert np.array_equal(on | t_ref["objects"][0], t_ref["object"])
    # one held object, or a point on neither: the whole held-object mask
    assert bench.clicked_object({**ref, "objects": [both]}) is both
    assert bench.clicked_object({**ref, "point": (5.0, 5.0)}) is both
