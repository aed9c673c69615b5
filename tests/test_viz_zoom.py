"""The figures' window around the hand and the object (viz.zoom) and Camera.cropped."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.render import get_backend
from easyhoi.structures import Camera
from easyhoi.testing.hoi_scene import H, W, hand_model, make_input, make_result
from easyhoi.viz.masks import mask_ious
from easyhoi.viz.overlay import render_overlay, shrink_photo
from easyhoi.viz.report import render_pictures
from easyhoi.viz.stages import render_stages
from easyhoi.viz.zoom import ZOOM_MIN_SIDE, interaction_box, mapped, outlined, zoomed

#: The test scene padded into a photo this many times its size, placed off centre: the hand
#: and the object then fill a small part of the frame, as in most photos.
PAD = 4
OFFSET = (37, 211)  # where the scene's top-left pixel lands in the padded photo (x, y)


@pytest.fixture(scope="module")
def padded():
    """The test scene's result and input inside a larger photo (grey around it)."""
    result, inp = make_result(), make_input()
    ox, oy = OFFSET
    big_w, big_h = PAD * W, PAD * H

    def image(a):
        out = np.full((big_h, big_w, 3), 128, np.uint8)
        out[oy : oy + H, ox : ox + W] = a
        return out

    def mask(m):
        out = np.zeros((big_h, big_w), bool)
        out[oy : oy + H, ox : ox + W] = m
        return out

    return mapped(result, inp, image, mask, lambda c: c.cropped(-ox, -oy, big_w, big_h))


def test_camera_cropped_shifts_the_projection():
    cam = Camera.look_at((0.3, -0.2, 2.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), focal=90.0,
                         width=160, height=120, dtype=torch.float64)  # fmt: skip
    pts = torch.as_tensor(np.random.default_rng(0).uniform(-0.3, 0.3, (50, 3)))
    uv, z = cam.project(pts)
    crop = cam.cropped(21, 13, 70, 50)
    uv_c, z_c = crop.project(pts)
    assert (crop.width, crop.height) == (70, 50)
    np.testing.assert_allclose(uv_c.numpy(), uv.numpy() - [21.0, 13.0], atol=1e-12)
    np.testing.assert_allclose(z_c.numpy(), z.numpy(), atol=0)
    # a negative offset pads; cropping it back is the original camera
    back = cam.cropped(-10, -5, 200, 150).cropped(10, 5, 160, 120)
    np.testing.assert_allclose(back.K.numpy(), cam.K.numpy(), atol=1e-12)
    for bad in ((0, 0, 0, 10), (0, 0, 10, -1), (0.5, 0, 10, 10)):
        with pytest.raises(InvalidInputError):
            cam.cropped(*bad)


def test_interaction_box_frames_masks_and_meshes(padded):
    result, inp = padded
    big_h, big_w = inp.image.shape[:2]
    x0, y0, x1, y1 = interaction_box(result, inp)
    assert 0 <= x0 < x1 <= big_w and 0 <= y0 < y1 <= big_h
    union = inp.hand_mask | inp.object_mask | inp.amodal_mask
    ys, xs = np.nonzero(union)
    assert x0 <= xs.min() and xs.max() < x1 and y0 <= ys.min() and ys.max() < y1
    # every projected vertex of the reconstruction is inside too
    cam = result.camera.to(dtype=torch.float64)
    pts = np.concatenate([result.hand_vertices, result.object_mesh.vertices])
    uv, _ = cam.project(torch.as_tensor(pts, dtype=torch.float64))
    uv = uv.numpy()
    assert (uv[:, 0] >= x0).all() and (uv[:, 0] <= x1).all()
    assert (uv[:, 1] >= y0).all() and (uv[:, 1] <= y1).all()
    # at least the minimum side, and far less than the photo
    assert max(x1 - x0, y1 - y0) >= ZOOM_MIN_SIDE * max(big_w, big_h) - 1
    assert (x1 - x0) * (y1 - y0) < 0.25 * big_w * big_h
    # the window stays inside the photo when the scene lies at its corner
    small_result, small_inp = make_result(), make_input()
    bx = interaction_box(small_result, small_inp, margin=2.0)
    assert bx == (0, 0, W, H)


def test_zoomed_pictures_are_the_crop_of_the_full_ones(padded):
    result, inp = padded
    box = interaction_box(result, inp)
    x0, y0, x1, y1 = box
    z_result, z_inp = zoomed(result, inp, box, min_width=1)  # cut, not enlarged
    assert z_inp.image.shape[:2] == (y1 - y0, x1 - x0)
    np.testing.assert_array_equal(z_inp.hand_mask, inp.hand_mask[y0:y1, x0:x1])
    full = render_overlay(result, inp.image).image[y0:y1, x0:x1].astype(int)
    crop = render_overlay(z_result, z_inp.image).image.astype(int)
    same = np.all(np.abs(full - crop) <= 2, axis=-1)
    assert same.mean() >= 0.999
    # the masks' agreement is the same on the window as on the photo
    a, b = mask_ious(result, inp), mask_ious(z_result, z_inp)
    for k in a:
        assert b[k] == pytest.approx(a[k], abs=2e-3)


@pytest.mark.skipif(get_backend() != "numba", reason="numba kernels unavailable")
def test_zoomed_stage_panels_show_the_meshes_larger(padded):
    result, inp = padded
    wide = 360
    box = interaction_box(result, inp)
    z_result, z_inp = zoomed(result, inp, box, min_width=wide)
    assert z_inp.image.shape[1] >= wide

    # the share of each panel the meshes cover: the drawn pixels differ from the photo's
    def share(res, image):
        drawn = render_stages(res, image, hand_model(), width=wide)[-1][1]
        photo = shrink_photo(image, wide)
        return float(np.mean(np.any(drawn != photo, axis=-1)))

    assert share(z_result, z_inp.image) > 4 * share(result, inp.image)


def test_render_pictures_outlines_the_window(padded):
    result, inp = padded
    pics = render_pictures(result, inp, hand_model())
    assert set(pics) == {"overlay.png", "views.png", "stages.png", "masks.png", "losses.png"}
    assert all(v.startswith(b"\x89PNG") for v in pics.values())
    # same input, same bytes
    assert render_pictures(result, inp, hand_model()) == pics
    img = np.zeros((40, 60, 3), np.uint8)
    out = outlined(img, (10, 5, 30, 25), color=(255, 0, 0))
    assert out[5, 10:30, 0].all() and out[24, 10:30, 0].all()
    assert not out[15, 15].any() and not img.any()
