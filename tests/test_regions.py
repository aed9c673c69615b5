"""Hand regions: palmar faces, contact zones, fingertips, frame independence, plotting."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from easyhoi.geometry.transforms import random_rotations
from easyhoi.hand.base import HandModel
from easyhoi.hand.openhand import OpenHand
from easyhoi.hand.regions import (
    DIGIT_JOINTS,
    compute_regions,
    flexion_axes,
    palm_frame,
    plot_regions,
    rest_geometry,
    vertex_normals,
)
from easyhoi.structures import HandParams


@pytest.fixture(scope="module")
def model() -> OpenHand:
    return OpenHand(dtype=torch.float64)


@pytest.fixture(scope="module")
def regions(model):
    return compute_regions(model)


class _Rotated(HandModel):
    """A MANO-layout model given only by its rest mesh, in another (rotated, shifted) frame."""

    name = "rotated"

    def __init__(self, base: OpenHand, R: torch.Tensor, t: torch.Tensor):
        super().__init__()
        v, j = base.shaped(torch.zeros(1, 10, dtype=torch.float64))
        self.register_buffer("v", v[0] @ R.T + t)
        self.register_buffer("j", j[0] @ R.T + t)
        self.register_buffer("faces", base.faces.clone())
        self.register_buffer("skin_weights", base.skin_weights.clone())
        self.register_buffer("tip_vertex_ids", base.tip_vertex_ids.clone())

    def shaped(self, betas):
        B = betas.shape[0]
        return self.v.expand(B, -1, -1).to(betas.dtype), self.j.expand(B, -1, -1).to(betas.dtype)


def test_palmar_faces_fraction_and_side(model, regions):
    palmar = regions.palmar_faces.numpy()
    assert palmar.shape == (len(model.faces),) and palmar.dtype == bool
    assert 0.4 <= palmar.mean() <= 0.6
    # Naive reference on the palm: OpenHand's palm faces -y, so there palmar <=> normal_y < 0.
    v, f, w, _ = rest_geometry(model)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    on_palm = (w[f].sum(1).argmax(1) == 0) & (np.abs(n[:, 1]) > 0.5)
    assert on_palm.sum() > 200
    np.testing.assert_array_equal(palmar[on_palm], n[on_palm, 1] < 0)


def test_contact_vertices(model, regions):
    c = regions.contact_vertices.numpy()
    V = model.num_vertices
    assert len(np.unique(c)) == len(c)
    assert 0.13 <= len(c) / V <= 0.17
    # All on the palmar side: each touches a palmar face, and its normal points to the palm.
    faces = model.faces.numpy()
    touches = np.zeros(V, dtype=bool)
    touches[faces[regions.palmar_faces.numpy()].ravel()] = True
    assert touches[c].all()
    v, f, _, _ = rest_geometry(model)
    assert (vertex_normals(v, f)[c, 1] < 0).mean() > 0.95
    # Pads on all five digits and a palm-centre patch.
    parts = regions.vertex_part.numpy()[c]
    for js in DIGIT_JOINTS.values():
        assert np.isin(parts, js[1:]).sum() >= 10
    assert (parts == 0).sum() >= 0.25 * len(c)
    assert not np.isin(parts, [1, 4, 7, 10, 13]).any()  # no proximal phalanges


def test_tips_are_extreme_along_each_finger(model, regions):
    v, _, _, j = rest_geometry(model)
    part = regions.vertex_part.numpy()
    tips = regions.tip_vertices.numpy()
    np.testing.assert_array_equal(tips, model.tip_vertex_ids.numpy())
    for tip, js in zip(tips, DIGIT_JOINTS.values(), strict=True):
        axis = v[tip] - j[js[2]]
        axis /= np.linalg.norm(axis)
        digit = np.nonzero(np.isin(part, js))[0]
        proj = (v[digit] - j[js[2]]) @ axis
        assert proj.max() == pytest.approx((v[tip] - j[js[2]]) @ axis)
        assert np.linalg.norm(v[tip] - j[js[2]]) > 0.015


def test_vertex_part_is_argmax(model, regions):
    np.testing.assert_array_equal(regions.vertex_part.numpy(), model.skin_weights.argmax(1).numpy())


def test_frame_and_flexion_axes(model):
    _, _, _, j = rest_geometry(model)
    f, lat, n = palm_frame(j)
    assert f @ np.array([-1.0, 0, 0]) > 0.99
    assert lat @ np.array([0, 0, 1.0]) > 0.99
    assert n @ np.array([0, -1.0, 0]) > 0.99
    axes = flexion_axes(model)
    assert (axes[:12, 2] > 0.95).all()  # fingers flex about ~ +z
    # Flexing every joint about its axis brings every tip closer to the palm centre.
    pose = torch.from_numpy(axes * 0.8).reshape(1, 45)
    z = torch.zeros(1, 3, dtype=torch.float64)
    rest = model(HandParams(z, z, torch.zeros_like(pose)))
    bent = model(HandParams(z, z, pose))
    centre = rest.joints[0, [0, 1, 4, 7, 10]].mean(0)
    d0 = (rest.vertices[0, model.tip_vertex_ids] - centre).norm(dim=1)
    d1 = (bent.vertices[0, model.tip_vertex_ids] - centre).norm(dim=1)
    assert (d1 < d0 - 0.005).all()


def test_regions_do_not_depend_on_the_frame(model, regions):
    R = random_rotations(1, torch.Generator().manual_seed(5))[0]
    other = compute_regions(_Rotated(model, R, torch.tensor([0.3, -0.2, 1.0], dtype=R.dtype)))
    agree = (other.palmar_faces == regions.palmar_faces).double().mean().item()
    assert agree > 0.999
    common = np.intersect1d(other.contact_vertices.numpy(), regions.contact_vertices.numpy())
    assert len(common) >= 0.98 * len(regions.contact_vertices)


def test_plot_regions_writes_png(model, tmp_path):
    path = plot_regions(model, tmp_path / "sub" / "regions.png")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
