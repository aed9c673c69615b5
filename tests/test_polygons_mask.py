"""``polygons_mask`` against the one-polygon-at-a-time definition (bit for bit)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from easyhoi.perception.shapes.common import SUPERSAMPLE, polygons_mask, rasterize


def _reference(polys, shape):
    """Each polygon rounded and filled on its own; the mean of each pixel's sub-pixels."""
    k = SUPERSAMPLE
    out = np.zeros((shape[0] * k, shape[1] * k), np.uint8)
    for p in polys:
        q = np.round((np.asarray(p) * k - 0.5) * 16).astype(np.int32)
        cv2.fillConvexPoly(out, q, 1, lineType=cv2.LINE_8, shift=4)
    return out.reshape(shape[0], k, shape[1], k).mean(axis=(1, 3)) >= 0.5


def _sphere(n_lat=14, n_lon=24, centre=(40.0, 33.0), radius=(27.3, 19.6)):
    """A UV sphere's vertices (orthographic u, v) and faces, tilted so edges fall off-grid."""
    th = np.linspace(0, np.pi, n_lat)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    xyz = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    xyz = np.vstack([[0, 0, 1], xyz, [0, 0, -1]])
    a = 0.4
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    xyz = xyz @ rot.T
    uv = xyz[:, :2] * radius + centre
    faces = []
    ring = lambda i, j: 1 + i * n_lon + j % n_lon  # noqa: E731
    for j in range(n_lon):
        faces.append([0, ring(0, j), ring(0, j + 1)])
        faces.append([len(xyz) - 1, ring(len(th) - 1, j + 1), ring(len(th) - 1, j)])
        for i in range(len(th) - 1):
            faces.append([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)])
            faces.append([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)])
    return uv, np.array(faces)


def test_mesh_silhouette_equals_reference():
    uv, faces = _sphere()
    got = rasterize(uv, faces, (70, 81))
    want = _reference([uv[f] for f in faces], (70, 81))
    assert got.dtype == bool and got.shape == (70, 81)
    assert 500 < got.sum() < 70 * 81  # a real silhouette, not empty nor full
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(polygons_mask(uv[faces], (70, 81)), want)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_random_polygons_of_mixed_sizes_equal_reference(dtype):
    rng = np.random.default_rng(3)
    polys = []
    for _ in range(300):
        k = int(rng.choice([3, 3, 4, 6]))
        c = rng.uniform(-5, 70, 2)
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        r = rng.uniform(0.2, 9.0)
        polys.append((c + r * np.stack([np.cos(ang), np.sin(ang)], 1)).astype(dtype))
    polys.append(np.array([[3, 4], [20, 4], [20, 17]]))  # integer corners
    got = polygons_mask(polys, (64, 60))
    np.testing.assert_array_equal(got, _reference(polys, (64, 60)))
    assert got.any() and not got.all()


def test_half_covered_pixel_counts_in():
    # a rectangle covering exactly the left half of pixel column 2 (sub-pixel edges)
    k = SUPERSAMPLE
    x1 = 2 + (k // 2 + 0.5) / k if k % 2 else 2.5
    rect = np.array([[0.0, 0.0], [x1, 0.0], [x1, 4.0], [0.0, 4.0]])
    np.testing.assert_array_equal(polygons_mask([rect], (4, 5)), _reference([rect], (4, 5)))
    assert polygons_mask([], (4, 5)).shape == (4, 5) and not polygons_mask([], (4, 5)).any()
