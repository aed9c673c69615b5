"""optim.window: the optimizer works on the part of the photo around the hand and the object.

A synthetic scene is pasted into a larger photo (its camera's principal point moved, as a crop
moves it the other way); the window must hold every mask pixel and keypoint with a margin, the
cropped input must project as the photo does shifted by the window's offset, and the result's
cameras must come back to the photo. The reason for the window is tested too: in a photo where
the hand and object are small, the object the optimizer places re-projects onto its mask at
the photo's resolution, which a fit over the whole photo at the render size does not.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.geometry.masks import mask_iou
from easyhoi.optim import window as win_mod
from easyhoi.optim.window import MARGIN, crop_input, interest_window, to_photo


def _paste(inp, left: int, top: int, width: int, height: int):
    """``inp`` as the (left, top) window of a larger ``width`` x ``height`` photo."""
    H, W = inp.size

    def grow(a, fill=0):
        if a is None:
            return None
        out = np.full((height, width, *a.shape[2:]), fill, dtype=a.dtype)
        out[top : top + H, left : left + W] = a
        return out

    meta = dict(inp.meta)
    if meta.get("keypoints2d") is not None:
        meta["keypoints2d"] = (np.asarray(meta["keypoints2d"]) + [left, top]).tolist()
    return replace(
        inp,
        image=grow(inp.image, 128),
        hand_mask=grow(inp.hand_mask),
        object_mask=grow(inp.object_mask),
        amodal_mask=grow(inp.amodal_mask),
        inpainted_image=grow(inp.inpainted_image, 128),
        complete_hand_mask=grow(inp.complete_hand_mask),
        hand_camera=inp.hand_camera.cropped(-left, -top, width, height),
        meta=meta,
    )


@pytest.fixture(scope="module")
def small_in_large():
    from easyhoi.synth.benchmark import BenchmarkSettings
    from easyhoi.synth.perturb import get_perturbation
    from easyhoi.synth.scene import make_scene

    st = BenchmarkSettings()
    s = make_scene(3, "box", "power", image_size=st.image_size, hold=True)
    inp = s.to_hoi_input(get_perturbation(st.perturbation), seed=0)
    return inp, _paste(inp, 1200, 500, 1920, 1080)  # a full-HD video frame


def _box(mask):
    rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    return cols[0], rows[0], cols[-1] + 1, rows[-1] + 1


def test_window_holds_the_masks_and_keypoints_with_a_margin(small_in_large):
    small, big = small_in_large
    x0, y0, x1, y1 = interest_window(big, render_size=128)
    H, W = big.size
    assert 0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H
    union = big.hand_mask | big.object_mask | big.amodal_mask
    bx0, by0, bx1, by1 = _box(union)
    kp = np.asarray(big.meta["keypoints2d"])
    bx0, by0 = min(bx0, kp[:, 0].min()), min(by0, kp[:, 1].min())
    bx1, by1 = max(bx1, kp[:, 0].max() + 1), max(by1, kp[:, 1].max() + 1)
    grow = MARGIN * max(bx1 - bx0, by1 - by0)
    # grown on every side (the box lies well inside the photo), and the longer side >= 128
    assert x0 <= bx0 - grow + 1 and y0 <= by0 - grow + 1
    assert x1 >= bx1 + grow - 1 and y1 >= by1 + grow - 1
    assert max(x1 - x0, y1 - y0) >= 128
    # the pasted scene fills most of its 128 px: the window is much smaller than the photo
    assert (x1 - x0) * (y1 - y0) < 0.2 * H * W


def test_a_photo_no_larger_than_the_render_is_used_whole(small_in_large):
    small, _ = small_in_large
    H, W = small.size
    assert interest_window(small, render_size=max(H, W)) == (0, 0, W, H)
    assert crop_input(small, (0, 0, W, H)) is small


def test_a_window_at_the_photo_edge_keeps_its_size_inwards():
    assert win_mod._span(-30.0, 50.0, 0, 200) == (0, 80)
    assert win_mod._span(150.0, 230.0, 0, 200) == (120, 200)
    assert win_mod._span(90.0, 110.0, 128, 200) == (36, 164)
    assert win_mod._span(10.0, 30.0, 128, 100) == (0, 100)  # never wider than the photo


def test_cropped_input_projects_as_the_photo_shifted(small_in_large):
    _, big = small_in_large
    win = interest_window(big, render_size=128)
    x0, y0, x1, y1 = win
    crop = crop_input(big, win)
    assert crop.size == (y1 - y0, x1 - x0)
    np.testing.assert_array_equal(crop.amodal_mask, big.amodal_mask[y0:y1, x0:x1])
    np.testing.assert_array_equal(crop.image, big.image[y0:y1, x0:x1])
    assert crop.amodal_mask.sum() == big.amodal_mask.sum()  # nothing of it cut off
    pts = torch.tensor([[0.01, -0.02, 0.5], [0.03, 0.01, 0.45]], dtype=big.hand_camera.K.dtype)
    uv_big, _ = big.hand_camera.project(pts)
    uv_crop, _ = crop.hand_camera.project(pts)
    torch.testing.assert_close(uv_crop + torch.tensor([x0, y0], dtype=uv_crop.dtype), uv_big)
    np.testing.assert_allclose(
        np.asarray(crop.meta["keypoints2d"]) + [x0, y0], np.asarray(big.meta["keypoints2d"])
    )
    assert big.meta["keypoints2d"] is not crop.meta["keypoints2d"]  # the photo's meta untouched


@pytest.mark.slow
def test_a_small_scene_in_a_large_photo_reprojects_onto_its_masks(small_in_large, monkeypatch):
    from easyhoi.config import get_preset
    from easyhoi.optim.run import optimize
    from easyhoi.viz.masks import rendered_masks

    small, big = small_in_large
    cfg = get_preset("fast").optim
    res = optimize(big, cfg)
    H, W = big.size
    assert (res.camera.width, res.camera.height) == (W, H)
    assert all(s.camera is None or (s.camera.width, s.camera.height) == (W, H)
               for s in res.stages)  # fmt: skip
    assert res.meta["keypoints2d"] == big.meta["keypoints2d"]
    iou_big = mask_iou(rendered_masks(res, H, W)["object_amodal"], big.amodal_mask)
    # the same scene at its own size, where the window is the whole photo
    res_small = optimize(small, cfg)
    h, w = small.size
    iou_small = mask_iou(rendered_masks(res_small, h, w)["object_amodal"], small.amodal_mask)
    assert iou_big >= iou_small - 0.05, (iou_big, iou_small)
    # over the whole photo at the render size the object is a few pixels and misses its mask
    monkeypatch.setattr(
        "easyhoi.optim.run.interest_window", lambda inp, size: (0, 0, inp.size[1], inp.size[0])
    )
    res_whole = optimize(big, cfg)
    iou_whole = mask_iou(rendered_masks(res_whole, H, W)["object_amodal"], big.amodal_mask)
    assert iou_big > iou_whole + 0.2, (iou_big, iou_whole)
    assert to_photo(res, (0, 0, W, H), (H, W)) is res  # a whole-photo window changes nothing
