"""The prompts marked on pictures of the photo (viz.marks): where, in which colour, and on the
first panel of ``masks.png``."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from easyhoi.testing.hoi_scene import H, W, hand_model, make_input, make_result
from easyhoi.viz.marks import BACKGROUND_COLOUR, HAND_COLOUR, OBJECT_COLOUR, draw_marks
from easyhoi.viz.masks import PANEL_WIDTH
from easyhoi.viz.report import render_pictures


def test_marks_land_at_the_scaled_photo_pixels():
    img = np.full((600, 900, 3), 100, np.uint8)  # marks of radius 10
    prompts = {
        "object_points": [[100.0, 80.0]],
        "hand_point": [400.0, 300.0],
        "background_points": [[500.0, 40.0]],
        "object_box": [40.0, 60.0, 240.0, 200.0],
        "object_choice": None,
    }
    out = draw_marks(img, prompts, 0.5, 0.5)  # a picture at half the photo's size
    assert out.shape == img.shape and out.dtype == np.uint8 and (img == 100).all()
    assert tuple(out[40, 50]) == OBJECT_COLOUR
    assert tuple(out[150, 200]) == HAND_COLOUR
    assert tuple(out[20, 250 + 5]) == BACKGROUND_COLOUR  # beside the white cross
    assert tuple(out[20, 250]) == (255, 255, 255)
    assert tuple(out[30, 70]) == OBJECT_COLOUR  # the box's top edge (y 60 / 2)
    assert tuple(out[65, 70]) == (100, 100, 100)  # inside the box: untouched
    # a box's pending first corner: a filled square
    corner = draw_marks(img, {"box_corner": [200.0, 200.0]}, 0.5, 0.5)
    assert tuple(corner[100, 100]) == OBJECT_COLOUR
    assert (draw_marks(img, {}, 1.0, 1.0) == img).all()  # nothing given: nothing drawn


def _first_panel(png: bytes) -> np.ndarray:
    fig = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    return fig[:, :PANEL_WIDTH]


def test_masks_png_marks_the_prompts_on_the_whole_photo():
    result, inp = make_result(), make_input()
    plain = render_pictures(result, inp, hand_model())["masks.png"]
    # the photo was twice this size when the user pointed at it
    inp.meta["prompts"] = {"object_points": [[W * 1.0, H * 1.0]], "object_box": None,
                           "hand_point": None, "background_points": []}  # fmt: skip
    inp.meta["prompts_photo_size"] = [2 * W, 2 * H]
    marked = render_pictures(result, inp, hand_model())["masks.png"]
    a, b = _first_panel(plain), _first_panel(marked)
    green = np.all(b == OBJECT_COLOUR, axis=-1)
    assert green.any() and not np.all(a == OBJECT_COLOUR, axis=-1).any()
    # the disc sits at the middle of the photo's picture in the panel
    ys, xs = np.nonzero(green)
    changed = np.nonzero(np.any(a != b, axis=-1))
    assert abs(xs.mean() - changed[1].mean()) < 1.5 and abs(ys.mean() - changed[0].mean()) < 1.5
    photo_rows = np.nonzero(np.any(a != 255, axis=(1, 2)))[0]
    assert photo_rows.min() < ys.mean() < photo_rows.max()
