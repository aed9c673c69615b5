"""Shaded rendering, overlays, views, stage / mask / loss figures."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

import easyhoi.viz.views as views_mod
from easyhoi.errors import InvalidInputError
from easyhoi.structures import Camera
from easyhoi.testing.hoi_scene import H, W, hand_model, make_input, make_result
from easyhoi.viz import (
    mask_iou,
    mask_ious,
    masks_png,
    render_overlay,
    render_shaded,
    render_stages,
    render_views,
    stages_png,
    views_png,
)
from easyhoi.viz.plots import losses_png, stage_loss_series
from easyhoi.viz.shade import SceneMesh, corner_normals


@pytest.fixture(scope="module")
def result():
    return make_result()


@pytest.fixture(scope="module")
def inp():
    return make_input()


def _png(data: bytes) -> Image.Image:
    im = Image.open(io.BytesIO(data))
    im.load()
    return im


def test_corner_normals_box_flat_sphere_smooth():
    box = trimesh.creation.box()
    n = corner_normals(box.vertices, box.faces)
    np.testing.assert_allclose(n, np.repeat(box.face_normals[:, None], 3, 1), atol=1e-12)
    s = trimesh.creation.icosphere(3)
    n = corner_normals(s.vertices, s.faces)
    radial = s.vertices[s.faces] / np.linalg.norm(s.vertices[s.faces], axis=-1, keepdims=True)
    assert np.min((n * radial).sum(-1)) > 0.995


def test_render_shaded_labels_depth_and_occlusion():
    cam = Camera.look_at([0, 0, -5.0], [0, 0, 0], focal=100.0, width=64, height=48)
    front = trimesh.creation.box(extents=(1, 1, 1))
    back = trimesh.creation.box(extents=(3, 3, 1))
    back.apply_translation((0, 0, 2))
    meshes = [SceneMesh(front.vertices, front.faces, (255, 0, 0), "front"),
              SceneMesh(back.vertices, back.faces, (0, 0, 255), "back")]  # fmt: skip
    r = render_shaded(meshes, cam, background=np.array([0, 255, 0], np.uint8), outline=False)
    assert r.labels[24, 32] == 0  # the small box occludes the big one at the centre
    assert r.depth[24, 32] == pytest.approx(4.5)
    assert r.labels[24, 12] == 1 and r.depth[24, 12] == pytest.approx(6.5)
    assert r.labels[0, 0] == -1 and np.isinf(r.depth[0, 0])
    assert tuple(r.image[0, 0]) == (0, 255, 0)
    red = r.image[24, 32]
    assert red[0] > 150 and red[1] == 0 and red[2] == 0  # facing the camera: bright, pure red
    # the front box's footprint: 1 unit at distance 4.5 with f = 100 -> 22.2 px wide
    cols = np.flatnonzero(r.labels[24] == 0)
    assert 21 <= cols.size <= 23


def test_overlay_changes_exactly_the_mesh_pixels(result):
    photo = np.zeros((H, W, 3), np.uint8)
    photo[:] = (30, 160, 60)
    r = render_overlay(result, photo)
    assert r.image.shape == photo.shape
    # rendered coverage = where the projected hand or object is (depth maps agree)
    from easyhoi.render.raster import depth_map

    cam = result.camera.to(dtype=torch.float64)
    hv = torch.tensor(result.hand_vertices)
    zh = depth_map(hv, torch.tensor(result.hand_faces), cam).numpy()
    ov = torch.tensor(np.asarray(result.object_mesh.vertices))
    zo = depth_map(ov, torch.tensor(np.asarray(result.object_mesh.faces)), cam).numpy()
    covered = np.isfinite(zh) | np.isfinite(zo)
    assert 0.05 < covered.mean() < 0.6
    np.testing.assert_array_equal(r.labels >= 0, covered)
    changed = np.any(r.image != photo, axis=-1)
    np.testing.assert_array_equal(changed, covered)
    # hand pixels are warm (red > blue), object pixels cool (blue > red)
    hand_px = r.image[r.labels == 0].astype(int)
    obj_px = r.image[r.labels == 1].astype(int)
    assert np.mean(hand_px[:, 0] > hand_px[:, 2]) > 0.95
    assert np.mean(obj_px[:, 2] > obj_px[:, 0]) > 0.95
    # the projected hand centroid lies on hand pixels
    uv, _ = result.camera.project(torch.tensor(result.hand_vertices[result.hand_faces[50]]))
    u, v = uv.mean(0).numpy().astype(int)
    assert r.labels[v, u] in (0, 1)


def test_overlay_rejects_bad_photo(result):
    with pytest.raises(InvalidInputError):
        render_overlay(result, np.zeros((H, W), np.uint8))


def test_views_front_matches_photo_direction(result, monkeypatch):
    views = render_views(result, size=64)
    assert list(views) == ["front", "side", "top", "back"]
    for img in views.values():
        assert img.shape == (64, 64, 3)
        covered = np.any(img != 250, axis=-1)
        assert 0.05 < covered.mean() < 0.8  # framed: something drawn, not filling everything
        assert not covered[0].any() and not covered[-1].any()  # nothing cut at the borders
    # front and back are mirror views: silhouettes mirror left-right
    f = np.any(views["front"] != 250, -1)
    b = np.any(views["back"] != 250, -1)
    assert (f & b[:, ::-1]).sum() / (f | b[:, ::-1]).sum() > 0.8
    monkeypatch.setattr(views_mod, "VIEW_SIZE", 48)
    im = _png(views_png(result))
    assert im.size[0] == 4 * 48 + 5 * 10  # four panels of VIEW_SIZE, 10 px margins and gaps
    assert im.size[1] > 48


def test_stage_overlays_differ_and_figure(result, inp):
    panels = render_stages(result, inp.image, hand_model())
    assert [p[0] for p in panels] == ["initial", "camera", "contact", "refine"]
    assert all(p[1].shape == (H, W, 3) for p in panels)
    assert all(p[2] == "" for p in panels)
    # the hand moves between snapshots, so the pictures differ
    assert np.any(panels[0][1] != panels[3][1])
    assert np.any(panels[2][1] != panels[3][1])
    # the final stage equals the final overlay
    np.testing.assert_array_equal(panels[3][1], render_overlay(result, inp.image).image)
    im = _png(stages_png(result, inp.image, hand_model()))
    assert im.size[0] > im.size[1] > 100
    # without the run's hand model the earlier snapshots show the object and say why
    bare = render_stages(result, inp.image)
    assert [p[2] for p in bare] == ["hand model unavailable"] * 3 + [""]
    np.testing.assert_array_equal(bare[3][1], panels[3][1])


def test_mask_iou_and_figure(result, inp):
    a = np.zeros((4, 4), bool)
    a[:2] = True
    b = np.zeros((4, 4), bool)
    b[1:3] = True
    assert mask_iou(a, b) == pytest.approx(4 / 12)
    assert np.isnan(mask_iou(np.zeros((2, 2)), np.zeros((2, 2))))
    with pytest.raises(InvalidInputError):
        mask_iou(a, np.zeros((3, 3), bool))
    ious = mask_ious(result, inp)
    # the object did not move: its amodal mask is reproduced exactly; the hand is shifted
    assert ious["object_amodal"] == pytest.approx(1.0)
    assert 0.5 < ious["hand_visible"] < 0.99
    assert _png(masks_png(result, inp)).size[0] > 500


def test_loss_series_and_plot(result):
    x, s = stage_loss_series([{"iter": 0, "a": 1.0, "note": "x"}, {"iter": 5, "b": 2.0}])
    np.testing.assert_array_equal(x, [0, 5])
    assert set(s) == {"a", "b"}
    np.testing.assert_array_equal(s["a"], [1.0, np.nan])
    im = _png(losses_png(result))
    assert im.size[0] == 3 * 420 + 4 * 10  # three stages with history, one row of panels
    assert 320 < im.size[1] < 420


def test_scene_mesh_normals_shared_by_content():
    s = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    a = SceneMesh(v.copy(), f.copy(), (1, 2, 3), "a").corner_normals
    b = SceneMesh(v.copy(), f.copy(), (9, 9, 9), "b").corner_normals
    np.testing.assert_array_equal(a, corner_normals(v, f))
    assert b is a and not a.flags.writeable  # one computation, shared read-only
    v2 = v.copy()
    v2[0] *= 1.5  # other content: its own normals
    c = SceneMesh(v2, f, (1, 2, 3), "c").corner_normals
    np.testing.assert_array_equal(c, corner_normals(v2, f))
    assert not np.array_equal(c, a)
