"""Occlusion-aware hand/object masks vs a joint rasterization of both meshes."""

from __future__ import annotations

import torch
import trimesh

from easyhoi.render.composite import hoi_masks
from easyhoi.render.raster import rasterize
from easyhoi.render.soft import soft_silhouette
from easyhoi.structures import Camera
from tests.helpers import assert_close

F64 = torch.float64


def _meshes(hand_z: float):
    hand = trimesh.creation.capsule(height=0.6, radius=0.2, count=[12, 12])
    hand.apply_transform(trimesh.transformations.rotation_matrix(1.2, [0, 1, 0]))
    hand.apply_translation((0.35, 0.1, hand_z))
    obj = trimesh.creation.box((0.8, 0.6, 0.6))
    as_t = lambda m: (torch.tensor(m.vertices, dtype=F64), torch.tensor(m.faces))  # noqa: E731
    return as_t(hand), as_t(obj)


def _cam():
    return Camera.look_at((0.0, 0.0, -3.0), (0, 0, 0), focal=60.0, width=48, height=40, dtype=F64)


def _front_mesh(hand, obj, cam):
    """(H, W) long: 0 no hit, 1 hand nearest, 2 object nearest (hard, joint z-buffer)."""
    v = torch.cat([hand[0], obj[0]])
    f = torch.cat([hand[1], obj[1] + hand[0].shape[0]])
    ids = rasterize(v, f, cam).face_ids[..., 0]
    return torch.where(ids < 0, 0, torch.where(ids < hand[1].shape[0], 1, 2))


def test_visible_masks_follow_depth_order():
    cam = _cam()
    for hand_z, hand_in_front in ((-0.5, True), (0.5, False)):
        hand, obj = _meshes(hand_z)
        m = hoi_masks(*hand, *obj, cam, sigma=0.5)
        front = _front_mesh(hand, obj, cam)
        both = torch.isfinite(m.hand_depth) & torch.isfinite(m.object_depth)
        assert int(both.sum()) > 40  # the meshes overlap in the image
        assert_close(m.hand, soft_silhouette(*hand, cam, sigma=0.5), atol=0)
        assert_close(m.object, soft_silhouette(*obj, cam, sigma=0.5), atol=0)
        hand_px, obj_px = front == 1, front == 2
        assert_close(m.hand_visible[hand_px], m.hand[hand_px], atol=0)
        assert_close(m.object_visible[obj_px], m.object[obj_px], atol=0)
        # a mesh hit behind the other is hidden (its soft fringe may spread only when in front)
        hidden_hand = obj_px & torch.isfinite(m.hand_depth)
        hidden_obj = hand_px & torch.isfinite(m.object_depth)
        assert int(hidden_hand.sum() + hidden_obj.sum()) > 40
        assert float(m.hand_visible[hidden_hand].abs().sum()) == 0
        assert float(m.object_visible[hidden_obj].abs().sum()) == 0
        # in the overlap the winner is the nearer mesh
        assert bool((m.hand_visible[both] > 0.5).all()) == hand_in_front
        assert bool((m.object_visible[both] > 0.5).all()) != hand_in_front


def test_front_fringe_over_object_keeps_gradient():
    cam = _cam()
    for hand_z, in_front in ((-0.5, True), (0.5, False)):
        hand, obj = _meshes(hand_z)
        hv = hand[0].clone().requires_grad_(True)
        m = hoi_masks(hv, hand[1], *obj, cam, sigma=2.0)
        fringe = torch.isinf(m.hand_depth) & torch.isfinite(m.object_depth) & (m.hand > 0.05)
        assert int(fringe.sum()) > 5
        assert bool((m.hand_visible[fringe] > 0).all()) == in_front
        (g,) = torch.autograd.grad(m.hand_visible[fringe].sum(), hv)
        assert (float(g.abs().sum()) > 0) == in_front


def test_empty_object_and_detach():
    cam = _cam()
    hand, _ = _meshes(-0.5)
    m = hoi_masks(*hand, torch.zeros(0, 3, dtype=F64), torch.zeros(0, 3, dtype=torch.long), cam)
    assert_close(m.hand_visible, m.hand, atol=0)
    assert float(m.object.abs().max()) == 0 and bool(torch.isinf(m.object_depth).all())
    d = m.detach()
    assert d.hand.shape == (40, 48) and not d.hand.requires_grad


def test_extend_depth_matches_naive_min_filter():
    from easyhoi.render import extend_depth, soft

    g = torch.Generator().manual_seed(3)
    z = torch.rand(13, 17, generator=g, dtype=torch.float64) + 1.0
    z[torch.rand(13, 17, generator=g) < 0.6] = float("inf")
    r = 2
    expected = z.clone()
    for i in range(13):
        for j in range(17):
            if not torch.isfinite(z[i, j]):
                expected[i, j] = z[max(i - r, 0) : i + r + 1, max(j - r, 0) : j + r + 1].min()
    try:
        for name in ("numba", "torch"):
            soft.set_backend(name)
            assert torch.equal(extend_depth(z, r), expected), name
            assert torch.equal(extend_depth(z, 0), z)
    finally:
        soft.set_backend("auto")
