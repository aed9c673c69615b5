"""Click-to-prompt of the web demo without a browser: clicks to photo pixels, drawing, the mask
preview, prompts through the request handler, the perception warnings, the example photos."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from easyhoi import app_prompts as ap
from easyhoi.app_request import handle_request, synthetic_examples
from easyhoi.config import get_preset
from easyhoi.errors import InvalidInputError
from easyhoi.perception.prompts import Prompts
from tests.test_app import Recorder, load_screenshot_script, photo

standin = load_screenshot_script()


def grey(path: Path, size=(1000, 800)) -> Path:
    Image.fromarray(np.full((size[1], size[0], 3), 100, np.uint8)).save(path)
    return path


def test_clicks_on_the_thumbnail_become_photo_pixels(tmp_path):
    rgb, err, state = ap.load_preview(grey(tmp_path / "p.png"), 20)
    assert err == "" and rgb.shape == (410, 512, 3)  # 1000x800 shown at 512 px
    assert state == {
        "object_points": [],
        "hand_point": None,
        "background_points": [],
        "object_box": None,
        "box_corner": None,
        "object_choice": None,
        "photo_size": [1000, 800],
    }
    assert ap.state_prompts(state) is None and "Click on the held object" in ap.prompt_text(state)
    s1 = ap.add_click(state, "object point", (255, 204), (512, 410))
    # pixel centre (255.5, 204.5) of the thumbnail times 1000/512 and 800/410
    assert s1["object_points"] == [[round(255.5 * 1000 / 512, 1), round(204.5 * 800 / 410, 1)]]
    assert state["object_points"] == []  # the old state is not changed
    s2 = ap.add_click(s1, "object point", (511, 409), (512, 410))
    s2 = ap.add_click(s2, "hand point", (10, 20), (512, 410))
    s2 = ap.add_click(s2, "hand point", (12, 30), (512, 410))  # replaces the hand point
    assert s2["object_points"][1] == [round(511.5 * 1000 / 512, 1), round(409.5 * 800 / 410, 1)]
    assert s2["hand_point"] == [round(12.5 * 1000 / 512, 1), round(30.5 * 800 / 410, 1)]
    assert ap.state_prompts(s2) == Prompts(
        tuple(tuple(p) for p in s2["object_points"]), None, tuple(s2["hand_point"])
    )
    assert ap.prompt_text(s2) == "object points: (499, 399), (999, 799); hand point: (24, 60)"
    ap.state_prompts(s2).check(1000, 800)  # every click lands inside the photo
    # outside the image, or before a photo: nothing changes
    assert ap.add_click(s2, "object point", (512, 5), (512, 410)) == s2
    assert ap.add_click(ap.new_state(), "object point", (5, 5), (512, 410)) == ap.new_state()
    with pytest.raises(InvalidInputError, match="unknown click mode"):
        ap.add_click(s2, "box", (5, 5), (512, 410))
    many = state
    for i in range(ap.MAX_OBJECT_POINTS + 3):
        many = ap.add_click(many, "object point", (i, i), (512, 410))
    assert len(many["object_points"]) == ap.MAX_OBJECT_POINTS
    assert many["object_points"][-1][0] == round((ap.MAX_OBJECT_POINTS + 2.5) * 1000 / 512, 1)
    first = many["object_points"][0][0]  # the first point stays: it frames the object
    assert first == round(0.5 * 1000 / 512, 1)
    assert many["object_points"][1][0] == round(4.5 * 1000 / 512, 1)
    # background points: appended, the oldest dropped past the cap
    bg = ap.add_click(s2, "background point", (100, 50), (512, 410))
    bg = ap.add_click(bg, "background point", (101, 51), (512, 410))
    assert bg["background_points"] == [
        [round(100.5 * 1000 / 512, 1), round(50.5 * 800 / 410, 1)],
        [round(101.5 * 1000 / 512, 1), round(51.5 * 800 / 410, 1)],
    ]
    assert ap.state_prompts(bg).background_points == tuple(map(tuple, bg["background_points"]))
    assert ap.prompt_text(bg).endswith("; not the object: (196, 98), (198, 100)")
    for i in range(ap.MAX_OBJECT_POINTS + 3):
        bg = ap.add_click(bg, "background point", (i, i), (512, 410))
    assert len(bg["background_points"]) == ap.MAX_OBJECT_POINTS
    assert bg["background_points"][0][0] == round(3.5 * 1000 / 512, 1)


def test_two_box_corners_make_the_object_box(tmp_path):
    rgb, _, state = ap.load_preview(grey(tmp_path / "p.png"), 20)
    s1 = ap.add_click(state, "object box corner", (300, 200), (512, 410))
    assert s1["box_corner"] == [round(300.5 * 1000 / 512, 1), round(200.5 * 800 / 410, 1)]
    assert s1["object_box"] is None and ap.state_prompts(s1) is None  # one corner: no box yet
    assert ap.prompt_text(s1) == "box corner (587, 391): click the opposite corner"
    s2 = ap.add_click(s1, "object box corner", (100, 50), (512, 410))  # any opposite corner
    x0, y0 = round(100.5 * 1000 / 512, 1), round(50.5 * 800 / 410, 1)
    x1, y1 = s1["box_corner"]
    assert s2["object_box"] == [x0, y0, x1, y1] and s2["box_corner"] is None
    assert ap.state_prompts(s2) == Prompts(object_box=(x0, y0, x1, y1))
    assert ap.prompt_text(s2) == f"object box: ({x0:.0f}, {y0:.0f})-({x1:.0f}, {y1:.0f})"
    # a second corner on the first one's row makes no box; a new pair replaces the box
    s3 = ap.add_click(ap.add_click(s2, "object box corner", (10, 10), (512, 410)),
                      "object box corner", (40, 10), (512, 410))  # fmt: skip
    assert s3["object_box"] == s2["object_box"] and s3["box_corner"] is not None
    s4 = ap.add_click(s3, "object box corner", (40, 40), (512, 410))
    lo = ap.add_click(state, "object box corner", (10, 10), (512, 410))["box_corner"]
    hi = ap.add_click(state, "object box corner", (40, 40), (512, 410))["box_corner"]
    assert s4["object_box"] == lo + hi
    # the box replaces the automatic path: a region chosen from it does not count
    chosen = ap.set_choice(s2, "3")
    assert ap.state_prompts(chosen).object_choice is None
    assert "counts only without a box" in ap.prompt_text(chosen)
    # drawn: a green rectangle on the box's outline, a green square at a pending corner
    drawn = ap.draw_prompts(rgb, s2)
    assert tuple(drawn[50, 200]) == (40, 220, 90) and tuple(drawn[125, 100]) == (40, 220, 90)
    assert tuple(drawn[125, 200]) == (100, 100, 100)  # inside the box: untouched
    pending = ap.draw_prompts(rgb, s1)
    assert tuple(pending[200, 300]) == (40, 220, 90)


def test_points_and_masks_are_drawn_where_they_are(tmp_path):
    rgb, _, state = ap.load_preview(grey(tmp_path / "p.png"), 20)
    state = ap.add_click(state, "object point", (100, 100), (512, 410))
    state = ap.add_click(state, "hand point", (400, 300), (512, 410))
    state = ap.add_click(state, "background point", (300, 50), (512, 410))
    drawn = ap.draw_prompts(rgb, state)
    assert tuple(drawn[50, 300 + 5]) == (230, 40, 60)  # red disc beside the background point
    assert tuple(drawn[50, 300]) == (255, 255, 255)  # with a white cross through it
    assert drawn.shape == rgb.shape and drawn.dtype == np.uint8
    assert tuple(drawn[100, 100]) == (40, 220, 90)  # green disc at the object point
    assert tuple(drawn[300, 400]) == (255, 140, 0)  # orange disc at the hand point
    assert tuple(drawn[200, 250]) == (100, 100, 100)  # elsewhere untouched
    assert (rgb == 100).all()  # the thumbnail itself is not drawn on
    # masks of the working size are resized to the thumbnail and tinted
    obj = np.zeros((800, 1000), bool)
    obj[:400, :500] = True
    tinted = ap.draw_prompts(rgb, ap.new_state(), (None, obj))
    assert (tinted[:200, :250] != 100).any(axis=-1).all() and (tinted[210:, 260:] == 100).all()


def test_mask_preview_segments_the_working_photo_with_scaled_prompts(tmp_path):
    big = grey(tmp_path / "big.png", size=(3200, 2000))  # works at 1600x1000, shown 512x320
    _, _, state = ap.load_preview(big, 20)
    state = ap.add_click(state, "object point", (255, 159), (512, 320))
    calls = []

    def segment(rgb, config, prompts):
        calls.append((rgb.shape, prompts))
        return standin.standin_segment(rgb, config, prompts)

    shown, text = ap.mask_preview(big, state, get_preset("fast"), segment)
    ((shape, prompts),) = calls
    assert shape == (1000, 1600, 3)
    (x, y), (px, py) = prompts.object_points[0], state["object_points"][0]
    assert (x, y) == pytest.approx((px / 2, py / 2))
    # the stand-in's object disc: radius 1000/8 = 125 px at work size = 40 px on the thumbnail
    assert shown.shape == (320, 512, 3)
    assert text.startswith("Object mask: ") and "% of the photo (green)" in text
    share = float(text.split(": ")[1].split("%")[0])
    assert share == pytest.approx(100 * np.pi * 125**2 / (1600 * 1000), abs=0.1)
    assert tuple(shown[159, 255]) == (40, 220, 90)  # the point itself, drawn
    ring = shown[159, 255 + 30]  # inside the disc: tinted green
    assert ring[1] > ring[0] + 40 and ring[1] > ring[2] + 40
    assert (shown[5, 5] == 100).all()  # far away: untouched


def test_mask_preview_states_the_masks_confidence(tmp_path):
    src = grey(tmp_path / "p.png")
    _, _, state = ap.load_preview(src, 20)
    state = ap.add_click(state, "object point", (100, 100), (512, 410))

    def rated(rgb, config, prompts):
        hand, obj, facts = standin.standin_segment(rgb, config, prompts)
        conf = {"hand": {"score": 0.9, "low": False, "reasons": []},
                "object": {"score": 0.35, "low": True, "reasons": ["faint outline"]}}  # fmt: skip
        return hand, obj, {**facts, "confidence": conf}

    _, text = ap.mask_preview(src, state, get_preset("fast"), rated)
    assert "; confidence hand 0.90, object 0.35." in text
    assert text.endswith(
        " Low confidence in the object mask (score 0.35; weak: faint outline): click on the parts "
        "of the object the mask misses (or, as background points, on what it takes in beyond "
        "the object) and run again."
    )  # the object was clicked on already: more clicks


def test_mask_preview_failures_are_sentences(tmp_path):
    src = grey(tmp_path / "p.png")
    cfg = get_preset("fast")
    _, _, state = ap.load_preview(src, 20)
    shown, text = ap.mask_preview(src, state, cfg, standin.standin_segment)
    assert shown is None and text.startswith("No held object was found in the photo: stand-in")
    assert text.endswith("Click on the held object to point at it.")
    far = dict(state, object_points=[[2000.0, 5.0]])
    shown, text = ap.mask_preview(src, far, cfg, standin.standin_segment)
    assert shown is None and "--object-point 2000,5 lies outside the 1000x800 photo" in text
    assert ap.mask_preview(None, state, cfg, standin.standin_segment) == (
        None, "Please upload a photo first.")  # fmt: skip

    def buggy(rgb, config, prompts):
        raise KeyError("oops")

    shown, text = ap.mask_preview(src, state, cfg, buggy)
    assert text.startswith("Internal error (KeyError") and "Traceback" not in text


def test_default_preview_uses_the_chain_backends(tmp_path, monkeypatch):
    from easyhoi.perception import base
    from tests.test_prompt_passthrough import Recording, TwoHands

    class Found(Recording):
        def segment(self, image, hand, prompts=None):
            Recording.calls.append((hand.side, prompts))
            m = np.zeros(image.shape[:2], bool)
            m[:10, :10] = True
            return base.Segmentation(~m, m, hand.side == "right")

    monkeypatch.setitem(base._REGISTRY["hand"], "two-hands", TwoHands)
    monkeypatch.setitem(base._REGISTRY["segmenter"], "found", Found)
    Recording.calls = []
    cfg = get_preset("fast")
    cfg = replace(cfg, perception=replace(cfg.perception, hand="two-hands", segmenter="found"))
    img = np.zeros((100, 200, 3), np.uint8)
    hand, obj, facts = ap.segment_for_preview(img, cfg, None)
    assert obj.sum() == 100
    assert facts == {"hands_found": 2, "hand_index": 1, "side": "right", "confidence": {}}
    assert Recording.calls == [("left", None), ("right", None)]
    Recording.calls = []
    pts = Prompts(object_points=((150.0, 40.0),), hand_point=(170.0, 60.0))
    hand, obj, facts = ap.segment_for_preview(img, cfg, pts)
    assert Recording.calls == [("right", pts)] and facts["hand_index"] == 1
    with pytest.raises(InvalidInputError, match="outside the 200x100 photo"):
        ap.segment_for_preview(img, cfg, Prompts(object_points=((250.0, 40.0),)))


def test_prompts_reach_the_reconstruction_and_the_warnings_the_page(tmp_path):
    src = photo(tmp_path / "p.png")  # 160x120
    fn = Recorder()
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn)
    assert res.ok and "prompts" not in fn.calls[0]
    assert res.warnings == (
        "Low confidence in the object mask (score 0.30; weak: stand-in: nobody pointed at the "
        "object): click on the held object in the photo and run again.",
    )
    pts = Prompts(object_points=((80.0, 60.0),))
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn,
                         prompts=pts)  # fmt: skip
    assert res.ok and fn.calls[1]["prompts"] == pts and res.warnings == ()
    doc = json.loads((res.folder / "result.json").read_text())
    assert doc["meta"]["prompts"]["object_points"] == [[80.0, 60.0]]
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn,
                         prompts=Prompts(hand_point=(300.0, 5.0)))  # fmt: skip
    assert not res.ok and len(fn.calls) == 2
    assert res.error == ("The photo cannot be used: --hand-point 300,5 lies outside the 160x120 "
                         "photo (x in [0, 160), y in [0, 120))")  # fmt: skip


def test_a_result_on_another_hand_says_so_first(tmp_path):
    def other_hand(image_path, out_dir, config, **kw):
        rec = standin.standin_reconstruct(image_path, out_dir, config, **kw)
        path = [f for f in rec.files if f.name == "result.json"][0]
        doc = json.loads(path.read_text())
        doc["meta"]["perception"].update(
            hand_index=1, hands_found=2, side="left", hand_choice="first holding an object",
            notes=["hand 0 (right) holds no object"], confidence={},
        )  # fmt: skip
        path.write_text(json.dumps(doc))
        return rec

    res = handle_request(photo(tmp_path / "p.png"), "fast", 0, work_root=tmp_path / "w",
                         reconstruct_fn=other_hand)  # fmt: skip
    assert res.ok and res.warnings == (
        "Hand 0 (right) holds no object: the result uses hand 1 (left) of 2 detected (choose "
        "another with --hand-point X,Y).",
    )


def test_example_photos_are_the_scenes_photos(tmp_path):
    from easyhoi.synth import make_scene

    (path,) = synthetic_examples(tmp_path, seeds=(1,))
    assert path.name == "synthetic-1.png"
    np.testing.assert_array_equal(np.asarray(Image.open(path)), make_scene(1).image)


@pytest.mark.slow
def test_example_photos_reconstruct_through_the_handler(tmp_path):
    from easyhoi.app_request import EXAMPLE_SEEDS
    from easyhoi.config import with_overrides
    from easyhoi.pipeline import reconstruct_photo

    def short(image_path, out_dir, config, **kw):
        cfg = with_overrides(config, {"optim.camera.max_iters": 6, "optim.contact.max_iters": 6,
                                      "optim.refine.max_iters": 6})  # fmt: skip
        return reconstruct_photo(image_path, out_dir, cfg, **kw)

    for path in synthetic_examples(tmp_path / "ex", EXAMPLE_SEEDS):
        res = handle_request(path, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=short)
        assert res.ok, (path.name, res.error)
        assert res.glb.read_bytes()[:4] == b"glTF"
