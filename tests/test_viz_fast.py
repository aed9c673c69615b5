"""The picture path: compiled z-buffer against the torch rasterizer, sizes, PNG bytes.

Agreement thresholds (stated once, used below): the compiled z-buffer and the torch rasterizer
must pick the same face at >= 99.9 % of the pixels (they differ only where two faces are at the
same depth to the last bits, which the two summation orders may break either way) and give
the same depth to 1e-9 relative where they pick the same face; shaded pictures must be equal
at >= 99.9 % of the pixels and within 2 levels of 255 wherever labels agree.
"""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from easyhoi.render import get_backend, set_backend
from easyhoi.render.raster import depth_map, face_buffer, rasterize
from easyhoi.structures import Camera
from easyhoi.testing.hoi_scene import H, W, hand_model, make_input, make_result
from easyhoi.viz.overlay import render_overlay, result_meshes, shrink_photo
from easyhoi.viz.shade import SceneMesh, render_shaded
from easyhoi.viz.stages import render_stages, stages_png
from easyhoi.viz.views import render_views

AGREE = 0.999

pytestmark = pytest.mark.skipif(get_backend() != "numba", reason="numba kernels unavailable")


@pytest.fixture(scope="module")
def result():
    return make_result()


@pytest.fixture(scope="module")
def inp():
    return make_input()


def _scene(seed: int):
    """Two overlapping random blobs (a sphere and a box) seen by a camera at a random angle."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(3, radius=1.0)
    sphere.vertices += rng.normal(scale=0.04, size=sphere.vertices.shape)
    box = trimesh.creation.box(extents=(1.5, 0.6, 0.9))
    box.apply_translation(rng.uniform(-0.6, 0.6, 3))
    eye = rng.normal(size=3)
    eye = 5.0 * eye / np.linalg.norm(eye)
    cam = Camera.look_at(eye, np.zeros(3), up=(0.0, 1.0, 0.0), focal=150.0, width=173,
                         height=131, dtype=torch.float64)  # fmt: skip
    meshes = [SceneMesh(sphere.vertices, sphere.faces, (200, 120, 90), "sphere"),
              SceneMesh(box.vertices, box.faces, (60, 110, 220), "box")]  # fmt: skip
    return meshes, cam


def _as_one(meshes):
    verts = np.concatenate([m.vertices for m in meshes])
    off = np.cumsum([0] + [len(m.vertices) for m in meshes])[:-1]
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, off, strict=True)])
    return torch.from_numpy(verts), torch.from_numpy(faces)


@pytest.mark.parametrize("seed", range(4))
def test_face_buffer_matches_the_torch_rasterizer(seed):
    meshes, cam = _scene(seed)
    v, f = _as_one(meshes)
    ids, depth = face_buffer(v, f, cam)
    frag = rasterize(v, f, cam)
    ref_ids, ref_depth = frag.face_ids[..., 0], frag.depth[..., 0]
    same = ids == ref_ids
    assert same.float().mean() >= AGREE
    assert (ids >= 0).sum() > 2000  # the meshes cover a good part of the picture
    hit = same & (ids >= 0)
    torch.testing.assert_close(depth[hit], ref_depth[hit], rtol=1e-9, atol=0)
    assert torch.isinf(depth[ids < 0]).all()
    # the depth-only kernel gives the same z-buffer
    torch.testing.assert_close(depth_map(v, f, cam), depth, rtol=0, atol=0)


def test_face_buffer_keeps_the_first_of_coincident_faces():
    # the same triangle twice: every pixel it covers belongs to face 0, as in rasterize
    tri = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    v = torch.from_numpy(np.concatenate([tri, tri]))
    f = torch.tensor([[0, 1, 2], [3, 4, 5]])
    cam = Camera.look_at((0, 0, 4.0), (0, 0, 0), up=(0, 1, 0), focal=40.0, width=48, height=40,
                         dtype=torch.float64)  # fmt: skip
    ids, _ = face_buffer(v, f, cam)
    ref = rasterize(v, f, cam).face_ids[..., 0]
    assert (ids >= 0).sum() > 100
    assert set(ids[ids >= 0].tolist()) == {0}
    torch.testing.assert_close(ids, ref)


def _shaded_pair(meshes, cam, background=None):
    fast = render_shaded(meshes, cam, background=background, alpha=0.7)
    before = get_backend()
    set_backend("torch")
    try:
        ref = render_shaded(meshes, cam, background=background, alpha=0.7)
    finally:
        set_backend(before)
    return fast, ref


def _check_pictures_agree(fast, ref):
    same_label = fast.labels == ref.labels
    assert same_label.mean() >= AGREE
    equal = (fast.image == ref.image).all(axis=2)
    assert equal.mean() >= AGREE
    diff = np.abs(fast.image.astype(int) - ref.image.astype(int)).max(axis=2)
    assert diff[same_label].max() <= 2


@pytest.mark.parametrize("seed", range(3))
def test_shaded_pictures_match_the_torch_path(seed):
    meshes, cam = _scene(seed)
    rng = np.random.default_rng(seed)
    bg = rng.integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8)
    fast, ref = _shaded_pair(meshes, cam, bg)
    assert (fast.labels >= 0).sum() > 2000
    _check_pictures_agree(fast, ref)
    # uncovered pixels keep the background exactly
    np.testing.assert_array_equal(fast.image[fast.labels < 0], bg[fast.labels < 0])


def test_hand_overlay_and_views_match_the_torch_path(result, inp):
    meshes = result_meshes(result)
    fast, ref = _shaded_pair(meshes, result.camera, inp.image)
    assert (fast.labels == 0).sum() > 200 and (fast.labels == 1).sum() > 200
    _check_pictures_agree(fast, ref)
    fast_views = render_views(result, size=96)
    set_backend("torch")
    try:
        ref_views = render_views(result, size=96)
    finally:
        set_backend("auto")
    for name, img in fast_views.items():
        assert (img == ref_views[name]).all(axis=2).mean() >= AGREE, name


def test_stage_panels_are_drawn_at_the_panel_width(result, inp):
    panels = render_stages(result, inp.image, hand_model(), width=W // 2)
    assert all(p[1].shape == (H // 2, W // 2, 3) for p in panels)
    # the last panel is the final overlay drawn over the downscaled photo
    small = shrink_photo(inp.image, W // 2)
    np.testing.assert_array_equal(panels[-1][1], render_overlay(result, small).image)
    # a width at or above the photo's keeps the photo's size
    assert render_stages(result, inp.image, width=W)[0][1].shape == (H, W, 3)


def test_full_size_figures_hold_more_pixels():
    # a photo wider than a panel (360 px): the default draws the panels at the panel's size
    result, inp = make_result(240, 480), make_input(height=240, width=480)
    small = stages_png(result, inp.image, hand_model())
    full = stages_png(result, inp.image, hand_model(), full_size=True)
    a, b = Image.open(io.BytesIO(small)), Image.open(io.BytesIO(full))
    assert a.size == b.size  # the same figure...
    assert small != full  # ...whose panels were drawn from different pixels


_PICTURE_BYTES = """
import hashlib, json
from easyhoi.testing.hoi_scene import hand_model, make_input, make_result
from easyhoi.viz.report import render_pictures
pics = render_pictures(make_result(), make_input(), hand_model())
print(json.dumps({k: hashlib.sha256(v).hexdigest() for k, v in sorted(pics.items())}))
"""


@pytest.mark.slow
def test_pictures_are_the_same_bytes_in_two_processes():
    runs = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _PICTURE_BYTES], capture_output=True,
                             text=True, timeout=300)  # fmt: skip
        assert out.returncode == 0, out.stderr
        runs.append(out.stdout.strip().splitlines()[-1])
    assert runs[0] == runs[1]


def test_full_size_pictures_flag_reaches_the_config(tmp_path):
    from easyhoi.cli import _config_from_args, build_parser

    parser = build_parser()
    for command in (["reconstruct", "a.jpg"], ["batch", str(tmp_path)]):
        base = [*command, "--out", str(tmp_path / "o")]
        assert not _config_from_args(parser.parse_args(base)).full_size_pictures
        args = parser.parse_args([*base, "--full-size-pictures"])
        assert _config_from_args(args).full_size_pictures
