"""``--object-choice K``: the numbered object regions of the automatic path and of an object
point, and picking one.

Drawn scenes with a known answer: a held disk in the grasp and a second disk against the little
finger's side (the automatic path takes the held disk; the other one is among the regions it
offers instead, and picking it gives that disk); and an object with a label of its own colour,
clicked on the label (the point's first region is the label, the whole object is another).
"""

from __future__ import annotations

import numpy as np
import pytest

from easyhoi.batch_prompts import parse_prompts_csv, parse_prompts_json
from easyhoi.cli import main
from easyhoi.errors import InvalidInputError
from easyhoi.perception.chain import _choices_meta, segment_hands
from easyhoi.perception.masks import ClassicalHOISegmenter
from easyhoi.perception.outlines import mask_outlines, outlines_mask
from easyhoi.perception.prompts import N_CHOICES, Prompts
from tests.test_perception_held_object import (
    BLUE,
    RED,
    S,
    canvas,
    det,
    finish,
    grasped_disk,
    scene_of,
)
from tests.test_perception_masks import iou


def two_disks():
    """(photo, the held disk, the other disk), the disks without the hand's pixels."""
    disk = grasped_disk()
    yy, xx = np.mgrid[0:S, 0:S]
    other = (xx - 180) ** 2 + (yy - 150) ** 2 < 20**2
    img, hand = scene_of([(other, RED), (disk, BLUE)])
    return img, disk & ~hand, other & ~hand


def test_prompts_check_the_choice():
    assert Prompts(object_choice=2).object_choice == 2 and not Prompts(object_choice=2).empty
    assert not Prompts(object_choice=2).has_object_prompt
    for bad in (0, -1, True, 2.5, "2"):
        with pytest.raises(InvalidInputError, match="whole number >= 1"):
            Prompts(object_choice=bad)
    assert Prompts(object_points=((1.0, 2.0),), object_choice=2).object_choice == 2
    with pytest.raises(InvalidInputError, match="cannot be combined with --object-box"):
        Prompts(object_box=(0.0, 0.0, 4.0, 4.0), object_choice=1)
    p = Prompts(hand_point=(3.0, 3.0), object_choice=3)
    assert Prompts.from_dict(p.to_dict()) == p


def test_sidecar_files_carry_the_choice():
    assert parse_prompts_json('{"a.jpg": {"object_choice": 2}}')["a.jpg"] == Prompts(
        object_choice=2
    )
    csv = "photo,kind,x,y,x1,y1\na.jpg,object_choice,3,,,\nb.jpg,hand_point,4,5,,\n"
    got = parse_prompts_csv(csv)
    assert got["a.jpg"] == Prompts(object_choice=3)
    assert got["b.jpg"] == Prompts(hand_point=(4.0, 5.0))
    for row, msg in (
        ("a.jpg,object_choice,0,,,", "whole number"),
        ("a.jpg,object_choice,1.5,,,", "whole number"),
        ("a.jpg,object_choice,2,7,,", "has no y"),
        ("a.jpg,object_choice,,,,", "needs numbers x"),
    ):
        with pytest.raises(InvalidInputError, match=msg):
            parse_prompts_csv("photo,kind,x,y,x1,y1\n" + row + "\n")
    got = parse_prompts_csv("photo,kind,x,y\na.jpg,object_choice,2\na.jpg,object_point,4,5\n")
    assert got["a.jpg"] == Prompts(object_points=((4.0, 5.0),), object_choice=2)
    with pytest.raises(InvalidInputError, match="cannot be combined"):
        parse_prompts_csv(
            "photo,kind,x,y,x1,y1\na.jpg,object_choice,2,,,\na.jpg,object_box,1,1,9,9\n"
        )


def test_the_choices_are_distinct_regions_the_automatic_one_first():
    img, disk, other = two_disks()
    seg = ClassicalHOISegmenter(seed=0).segment(img, det())
    assert seg.has_object and iou(seg.object_mask, disk) > 0.7
    ch = seg.candidates
    assert 2 <= len(ch) <= N_CHOICES
    assert np.array_equal(ch[0], seg.object_mask)  # region 1 is what the automatic path used
    for a in range(len(ch)):
        for b in range(a + 1, len(ch)):
            assert iou(ch[a], ch[b]) < 0.6
    assert max(iou(m, other) for m in ch[1:]) > 0.9  # the other disk is offered


def test_picking_a_region_gives_it_and_region_1_is_the_automatic_result():
    img, disk, other = two_disks()
    seg = ClassicalHOISegmenter(seed=0)
    auto = seg.segment(img, det())
    one = seg.segment(img, det(), prompts=Prompts(object_choice=1))
    assert np.array_equal(one.object_mask, auto.object_mask)
    k = 1 + int(np.argmax([iou(m, other) for m in auto.candidates]))
    assert k > 1
    got = seg.segment(img, det(), prompts=Prompts(object_choice=k))
    assert got.has_object and got.meta["prompted"] and got.meta["object_choice"] == k
    assert iou(got.object_mask, other) > 0.7 and iou(got.object_mask, disk) < 0.1
    # the same regions are offered whichever is picked, and the same pick gives the same mask
    assert all(np.array_equal(a, b) for a, b in zip(got.candidates, auto.candidates, strict=True))
    again = seg.segment(img, det(), prompts=Prompts(object_choice=k))
    assert np.array_equal(again.object_mask, got.object_mask)
    with pytest.raises(InvalidInputError, match=f"found {len(auto.candidates)} object region"):
        seg.segment(img, det(), prompts=Prompts(object_choice=len(auto.candidates) + 1))


def test_segment_hands_picks_in_the_automatically_chosen_hand():
    img, disk, other = two_disks()
    seg = ClassicalHOISegmenter(seed=0)
    i, auto, _, _ = segment_hands(img, [det()], seg)
    k = 1 + int(np.argmax([iou(m, other) for m in auto.candidates]))
    j, got, _, _ = segment_hands(img, [det()], seg, prompts=Prompts(object_choice=k))
    assert i == j == 0 and iou(got.object_mask, other) > 0.7
    meta = _choices_meta(got)
    assert meta["object_choice"] == k and len(meta["object_choices"]) == len(auto.candidates)

    class NoChoices:
        def segment(self, image, hand, prompts=None):
            return auto

    with pytest.raises(InvalidInputError, match="offers no numbered object regions"):
        segment_hands(img, [det()], NoChoices(), prompts=Prompts(object_choice=2))


def test_outlines_round_trip():
    yy, xx = np.mgrid[0:120, 0:160]
    m = ((xx - 50) ** 2 + (yy - 60) ** 2 < 30**2) | ((np.abs(xx - 130) < 15) & (yy > 20))
    outlines = mask_outlines(m)
    assert len(outlines) == 2 and all(isinstance(v, int) for p in outlines for q in p for v in q)
    assert iou(outlines_mask(outlines, m.shape), m) > 0.97
    half = outlines_mask(mask_outlines(m, 0.5), (60, 80))
    assert abs(half.sum() - m.sum() / 4) < 0.05 * m.sum() / 4
    assert mask_outlines(np.zeros((5, 5), bool)) == []


def test_cli_refuses_a_bad_choice_before_any_work(tmp_path, capsys):
    img, _, _ = two_disks()
    photo = tmp_path / "p.png"
    import cv2

    cv2.imwrite(str(photo), img[:, :, ::-1])
    out = tmp_path / "out"
    rc = main(["reconstruct", str(photo), "--out", str(out), "--object-choice", "0"])
    assert rc == 2 and "whole number >= 1" in capsys.readouterr().err
    rc = main(["reconstruct", str(photo), "--out", str(out), "--object-choice", "2",
               "--object-box", "10,10,60,60"])  # fmt: skip
    assert rc == 2 and "cannot be combined with --object-box" in capsys.readouterr().err
    assert not out.exists()


def test_the_web_page_state_carries_the_choice():
    from easyhoi import app_prompts as ap

    labels = ap.choice_labels()
    assert labels[0] == "1 (automatic)" and len(labels) == N_CHOICES
    s = ap.new_state((100, 80))
    assert ap.state_prompts(s) is None
    s2 = ap.set_choice(s, "3")
    assert ap.state_prompts(s2) == Prompts(object_choice=3)
    assert "object region 3" in ap.prompt_text(s2)
    assert ap.state_prompts(ap.set_choice(s2, labels[0])) is None
    # the first object point replaces the automatic regions by its own: the menu goes back to
    # 1, and a region picked then is one of the point's, kept by further points
    s3 = ap.add_click(s2, "object point", (10, 10), (100, 80))
    assert ap.state_prompts(s3) == Prompts(object_points=((10.5, 10.5),))
    assert ap.choice_label(s3) == labels[0] and ap.choice_label(s2) == "3"
    s3 = ap.add_click(ap.set_choice(s3, "2"), "object point", (20, 20), (100, 80))
    assert ap.state_prompts(s3) == Prompts(
        object_points=((10.5, 10.5), (20.5, 20.5)), object_choice=2
    )
    # a box has no regions, and the page says so
    s4 = ap.add_click(ap.add_click(s2, "object box corner", (10, 10), (100, 80)),
                      "object box corner", (50, 40), (100, 80))  # fmt: skip
    boxed = ap.state_prompts(s4)
    assert boxed.object_box is not None and boxed.object_choice is None
    assert "counts only without a box" in ap.prompt_text(s4)


def test_the_mask_preview_shows_the_chosen_region(monkeypatch):
    from dataclasses import replace

    from easyhoi import app_prompts as ap
    from easyhoi.config import get_preset
    from easyhoi.perception import base

    class OneHand:
        def detect(self, image):
            return [det()]

    monkeypatch.setitem(base._REGISTRY["hand"], "one-drawn-hand", OneHand)
    cfg = get_preset("fast")
    cfg = replace(cfg, perception=replace(cfg.perception, hand="one-drawn-hand"))
    img, disk, other = two_disks()
    _, obj, facts = ap.segment_for_preview(img, cfg, None)
    assert iou(obj, disk) > 0.7 and len(facts["regions"]) >= 2
    auto = ClassicalHOISegmenter(seed=0).segment(img, det())
    k = 1 + int(np.argmax([iou(m, other) for m in auto.candidates]))
    _, obj, facts = ap.segment_for_preview(img, cfg, Prompts(object_choice=k))
    assert iou(obj, other) > 0.7
    # the chain's report counts the regions offered (the warnings name the choice only then)
    from easyhoi.perception.chain import perceive
    from easyhoi.settings import resolve_run

    inp, rep = perceive(img, resolve_run(cfg))
    assert rep.regions == len(auto.candidates) >= 2
    assert inp.meta["perception"]["regions"] == len(inp.meta["object_choices"]) == rep.regions


def _regions(shape, *boxes, used=1):
    """(masks, result meta) of rectangular regions ``(y0, y1, x0, x1)`` on a ``shape`` photo."""
    masks = []
    for y0, y1, x0, x1 in boxes:
        m = np.zeros(shape, bool)
        m[y0:y1, x0:x1] = True
        masks.append(m)
    return masks, {"object_choices": [mask_outlines(m) for m in masks], "object_choice": used}


def test_masks_png_numbers_the_offered_regions():
    from easyhoi.viz.masks import choice_panels

    photo = np.full((60, 80, 3), 100, np.uint8)
    (a, b), meta = _regions((120, 160), (20, 60, 20, 60), (70, 110, 100, 150), used=2)
    panels = choice_panels(photo, meta, 0.5)  # the photo shown at half its size
    assert [p.title for p in panels] == ["--object-choice 1", "--object-choice 2 (used)"]
    for panel, m in zip(panels, (a, b), strict=True):
        small = m[::2, ::2]
        tinted = np.any(panel.image != 100, axis=-1)
        assert iou(tinted, small) > 0.9
    assert choice_panels(photo, {}, 0.5) == []
    # regions a small part of the photo: every panel shows the same window round them
    big = np.full((400, 600, 3), 100, np.uint8)
    (c, d), meta = _regions((400, 600), (100, 140, 200, 220), (150, 160, 230, 260))
    panels = choice_panels(big, meta, 1.0)
    # the box round both (y 100-160, x 200-260) grown by a quarter of 60 on every side
    assert all(p.image.shape[:2] == (90, 90) for p in panels)
    for panel, m in zip(panels, (c, d), strict=True):
        tinted = np.any(panel.image != 100, axis=-1)
        assert iou(tinted, m[85:175, 185:275]) > 0.9


def test_masks_png_rings_a_small_region_and_keeps_a_thin_one_visible():
    """A region a few photo pixels wide (a pen) in a window that a large region sets: it is
    outlined in the region colour and ringed, so it still shows once the panel is shrunk to
    PANEL_WIDTH; the large region is outlined and not ringed."""
    import cv2

    from easyhoi.viz.marks import REGION_COLOUR
    from easyhoi.viz.masks import PANEL_WIDTH, SMALL_REGION, choice_panels

    photo = np.full((800, 1000, 3), 100, np.uint8)
    (pen, table), meta = _regions((800, 1000), (400, 403, 480, 540), (100, 700, 100, 900))
    panels = choice_panels(photo, meta, 1.0)
    win = panels[0].image.shape[:2]
    assert 60 < SMALL_REGION * max(win)  # the pen is small in the window, the table is not

    def region_coloured(img):
        return np.all(img == np.array(REGION_COLOUR, np.uint8), axis=-1)

    y0, x0 = 0, 0  # the window starts at the photo's corner: the table's margin reaches it
    for panel, m, ringed in zip(panels, (pen, table), (True, False), strict=True):
        img = panel.image
        grown = cv2.dilate(m.astype(np.uint8), np.ones((61, 61), np.uint8)).astype(bool)
        far = ~grown[y0 : y0 + img.shape[0], x0 : x0 + img.shape[1]]
        assert region_coloured(img).any()
        assert bool(region_coloured(img)[far].any()) is ringed
    # shrunk as masks.png shrinks it, the pen's panel still shows the region colour near it
    img = panels[0].image
    small = cv2.resize(img, (PANEL_WIDTH, round(PANEL_WIDTH * img.shape[0] / img.shape[1])),
                       interpolation=cv2.INTER_AREA)  # fmt: skip
    dist = np.abs(small.astype(int) - np.array(REGION_COLOUR)).sum(-1)
    assert dist.min() < 60


def test_the_mask_preview_outlines_the_regions_numbered(tmp_path):
    from PIL import Image

    from easyhoi import app_prompts as ap
    from easyhoi.config import get_preset

    src = tmp_path / "p.png"
    Image.fromarray(np.full((200, 300, 3), 100, np.uint8)).save(src)
    _, _, state = ap.load_preview(src, 20)
    a = np.zeros((200, 300), bool)
    a[40:100, 40:120] = True
    b = np.zeros((200, 300), bool)
    b[120:180, 180:280] = True

    def segment(rgb, config, prompts):
        facts = {"hands_found": 1, "hand_index": 0, "side": "right", "confidence": {},
                 "regions": [a, b]}  # fmt: skip
        return np.zeros_like(a), a, facts

    shown, text = ap.mask_preview(src, state, get_preset("fast"), segment)
    assert "2 object regions to choose from, numbered in yellow" in text
    yellow = np.all(shown == (255, 200, 0), axis=-1)
    assert yellow[40:100, 38:42].any() and yellow[118:122, 180:280].any()  # the outlines
    assert not yellow[5:30, 5:30].any() and not yellow[125:140, 190:210].any()  # inside: untouched
    # a numbered disc at each region's middle (the digit drawn in black on it)
    assert yellow[65:75, 75:85].any() and (shown[60:80, 70:90] == 0).all(-1).any()
    assert yellow[145:155, 225:235].any()


def test_object_prompts_next_to_an_object_mask_are_refused(tmp_path, capsys):
    import cv2

    img, disk, _ = two_disks()
    photo, mask = tmp_path / "p.png", tmp_path / "m.png"
    cv2.imwrite(str(photo), img[:, :, ::-1])
    cv2.imwrite(str(mask), disk.astype(np.uint8) * 255)
    out = tmp_path / "out"
    for extra in (["--object-choice", "2"], ["--object-point", "88,128"],
                  ["--background-point", "5,5"]):  # fmt: skip
        rc = main(["reconstruct", str(photo), "--out", str(out), "--object-mask", str(mask),
                   *extra])  # fmt: skip
        assert rc == 2 and "would steer nothing" in capsys.readouterr().err
    assert not out.exists()


def labelled_object():
    """(photo, the object, its label): a yellow bar right of the hand with a dark red label
    across its middle, which GrabCut grown from a click on the label stops at."""
    yy, xx = np.mgrid[0:S, 0:S]
    obj = (np.abs(xx - 195) < 26) & (np.abs(yy - 62) < 48)
    label = obj & (np.abs(yy - 62) < 16) & (np.abs(xx - 195) < 20)
    img = canvas()
    img[obj] = (230, 200, 60)
    img[label] = (150, 20, 30)
    img, hand = finish(img)
    assert not (obj & hand).any()
    return img, obj, label


def test_a_points_regions_offer_the_whole_object_when_the_click_takes_a_part():
    img, obj, label = labelled_object()
    seg = ClassicalHOISegmenter(seed=0)
    point = ((195.0, 62.0),)
    first = seg.segment(img, det(), prompts=Prompts(object_points=point))
    # the label scores highest, the whole object almost as high: offered, and said so
    assert iou(first.object_mask, label) > 0.9
    conf = first.confidence["object"]
    assert conf.low and any("region 2" in r for r in conf.reasons)
    ch = first.candidates
    assert 2 <= len(ch) <= N_CHOICES and np.array_equal(ch[0], first.object_mask)
    assert all(iou(ch[a], ch[b]) < 0.5 for a in range(len(ch)) for b in range(a + 1, len(ch)))
    k = 1 + int(np.argmax([iou(m, obj) for m in ch]))
    assert k == 2 and iou(ch[k - 1], obj) > 0.9
    got = seg.segment(img, det(), prompts=Prompts(object_points=point, object_choice=k))
    assert got.meta["object_choice"] == k and iou(got.object_mask, obj) > 0.95
    assert not got.confidence["object"].low  # picked by the user: no margin warning
    # the numbering stays: the same regions, the picked one as the object mask
    assert np.array_equal(got.candidates[k - 1], got.object_mask)
    assert len(got.candidates) == len(ch) and iou(got.candidates[0], label) > 0.8
    assert np.array_equal(
        seg.segment(img, det(), prompts=Prompts(object_points=point, object_choice=1)).object_mask,
        first.object_mask,
    )
    # a further point grows the picked region: one inside it adds nothing
    two = Prompts(object_points=(*point, (195.0, 30.0)), object_choice=k)
    assert np.array_equal(seg.segment(img, det(), prompts=two).object_mask, got.object_mask)
    with pytest.raises(InvalidInputError, match=f"has {len(ch)} distinct object region"):
        seg.segment(img, det(), prompts=Prompts(object_points=point, object_choice=len(ch) + 1))
    # through the chain: the point picks the hand, and region K is taken in one pass
    calls = []

    class Counting(ClassicalHOISegmenter):
        def segment(self, image, hand, prompts=None, others=()):
            calls.append(prompts)
            return super().segment(image, hand, prompts=prompts, others=others)

    prompts = Prompts(object_points=point, object_choice=k)
    j, s, _, _ = segment_hands(img, [det()], Counting(seed=0), prompts=prompts)
    assert j == 0 and iou(s.object_mask, obj) > 0.95 and calls == [prompts]
    assert _choices_meta(s)["object_choice"] == k
