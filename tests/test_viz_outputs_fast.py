"""The cheaper formulations of the result pictures equal the plain ones they replace."""

from __future__ import annotations

import io
import math

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image

from easyhoi import aot, compiled
from easyhoi.errors import InvalidInputError
from easyhoi.viz import masks, shade
from easyhoi.viz.chart import _densify
from easyhoi.viz.compose import fit_width
from easyhoi.viz.plots import png_bytes
from easyhoi.viz.shade import _blend


def test_blend_on_covered_pixels_equals_the_whole_picture_formula():
    rng = np.random.default_rng(0)
    bg = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    hit = rng.random((37, 53)) < 0.4
    shade = rng.uniform(-20.0, 280.0, (int(hit.sum()), 3))  # out of range on purpose: clipped
    for alpha in (0.0, 0.3, 0.65, 1.0):
        out = bg.astype(np.float64)  # the whole picture in float64, then the uncovered restored
        out[hit] = (1.0 - alpha) * out[hit] + alpha * shade
        ref = np.clip(np.rint(out), 0, 255).astype(np.uint8)
        ref[~hit] = bg[~hit]
        got = bg.copy()
        _blend(got.reshape(-1, 3), np.flatnonzero(hit), shade, alpha)
        np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("shape", [(1, 1), (7, 5), (7, 5, 2), (40, 31, 3), (9, 13, 4), (3, 4, 1)])
def test_png_decodes_to_the_same_pixels(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.integers(0, 256, shape, dtype=np.uint8)
    a[:, : shape[1] // 2] = 7  # flat and noisy parts
    data = png_bytes(a)
    im = Image.open(io.BytesIO(data))
    im.load()
    np.testing.assert_array_equal(np.asarray(im), a[..., 0] if shape[2:] == (1,) else a)
    assert png_bytes(a) == data
    assert png_bytes(np.asfortranarray(a)) == data  # memory layout does not matter


@pytest.mark.parametrize("bad", [np.zeros((0, 4, 3), np.uint8), np.zeros((4, 4, 5), np.uint8),
                                 np.zeros((4, 4), np.float32), np.zeros(4, np.uint8)])  # fmt: skip
def test_png_refuses_what_it_cannot_encode(bad):
    with pytest.raises(InvalidInputError):
        png_bytes(bad)


def _densify_loop(x, y, step=8.0):
    """The segment-by-segment formulation :func:`easyhoi.viz.chart._densify` replaces."""
    pts = [np.stack([x[:1], y[:1]], axis=1)]
    for a, b, c, d in zip(x[:-1], y[:-1], x[1:], y[1:], strict=True):
        n = max(1, int(math.hypot(c - a, d - b) / step))
        t = np.arange(1, n + 1) / n
        pts.append(np.stack([a + t * (c - a), b + t * (d - b)], axis=1))
    return np.concatenate(pts)


@pytest.mark.parametrize("n", [0, 1, 2, 3, 50, 400])
def test_densify_equals_the_segment_loop(n):
    rng = np.random.default_rng(n)
    x = np.sort(rng.uniform(100, 900, n))
    y = rng.uniform(30, 600, n)
    if n > 3:
        x[2], y[2] = x[1], y[1]  # a zero-length segment
        x[3] = x[2] + 8.0  # exactly one step long
        y[3] = y[2]
    np.testing.assert_array_equal(_densify(x, y, 8.0), _densify_loop(x, y, 8.0))


@pytest.mark.parametrize("size", [(974, 650, 320), (350, 350, 320), (451, 601, 360), (20, 30, 30)])
def test_fit_width_of_a_mask_equals_scaling_its_three_channels(size):
    h, w, width = size
    rng = np.random.default_rng(h)
    mask = rng.random((h, w)) < 0.3
    mask[h // 4 : h // 2, w // 3 : w // 2] = True
    rgb = np.repeat((mask.astype(np.uint8) * 255)[..., None], 3, axis=2)  # the old order
    if w > width:
        rgb = cv2.resize(rgb, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(fit_width(mask, width), rgb)


def test_mask_comparison_colours_equal_the_masked_assignments():
    rng = np.random.default_rng(3)
    a, b = rng.random((2, 41, 29)) < 0.5
    ref = np.empty(a.shape + (3,), np.uint8)
    ref[:] = masks._NONE
    ref[a & b] = masks._BOTH
    ref[a & ~b] = masks._INPUT_ONLY
    ref[~a & b] = masks._RENDER_ONLY
    np.testing.assert_array_equal(masks._compare(a, b), ref)


def _meshes():
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    sphere = trimesh.creation.icosphere(3)
    rng = np.random.default_rng(5)
    v = rng.normal(size=(60, 3))
    f = rng.integers(0, 60, (150, 3))
    f[:5, 1] = f[:5, 0]  # repeated corners: degenerate faces
    v[f[5, 1]] = v[f[5, 0]]  # a zero-area face
    return [(box.vertices, box.faces), (sphere.vertices, sphere.faces), (v, f)]


@pytest.mark.parametrize("k", range(3))
def test_compiled_corner_sums_equal_the_numpy_pairs(k):
    pytest.importorskip("numba")
    from easyhoi.viz._normals_kernel import corner_sums

    v, f = (np.asarray(a) for a in _meshes()[k])
    f = f.astype(np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    unit = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30)
    for crease in (0.0, 40.0, 89.0):
        c = float(np.cos(np.radians(crease)))
        ref = shade._pair_sums(f, len(v), cross, unit, c)
        np.testing.assert_array_equal(corner_sums(f, len(v), cross, unit, c), ref)


def test_a_failing_corner_sums_kernel_warns_once_and_is_not_retried(monkeypatch):
    pytest.importorskip("numba")
    from numba.core.errors import NumbaError

    import easyhoi.viz._normals_kernel as kernel
    from easyhoi.render import get_backend

    if get_backend() != "numba":
        pytest.skip("the compiled kernels are not in use")
    calls = []

    def failing(*args):
        calls.append(1)
        raise NumbaError("no LLVM here")

    monkeypatch.setattr(kernel, "corner_sums", failing)
    monkeypatch.setattr(compiled, "_FAILED", set())  # this test's failure stays in it
    monkeypatch.setitem(aot._STATE, "mod", None)  # the numba function, not the built export
    v, f = (np.asarray(a) for a in _meshes()[0])
    f = f.astype(np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    unit = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30)
    with pytest.warns(RuntimeWarning, match="corner_sums failed"):
        assert shade._compiled_sums(f, len(v), cross, unit, 0.5) is None
    assert shade._compiled_sums(f, len(v), cross, unit, 0.5) is None
    assert len(calls) == 1  # not compiled again at the next picture
    # the pictures' normals still come out, from the NumPy path: unit vectors per corner
    normals = shade.corner_normals(v, f)
    assert normals.shape == (len(f), 3, 3) and len(calls) == 1
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-9)
