"""forward_kinematics and skin (hand/lbs.py) against a naive recursive 4x4 reference."""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.geometry.transforms import axis_angle_to_matrix, random_rotations
from easyhoi.hand.lbs import forward_kinematics, skin
from easyhoi.structures import JOINT_PARENTS
from tests.helpers import assert_close


def _naive_global(rotmats, joints, parents):
    """Per batch element: world 4x4 of every joint by explicit recursion over the tree."""
    J = len(parents)

    def world(j):
        local = np.eye(4)
        local[:3, :3] = rotmats[j]
        p = parents[j]
        local[:3, 3] = joints[j] - (joints[p] if p >= 0 else 0.0)
        return local if p < 0 else world(p) @ local

    return [world(j) for j in range(J)]


def _naive_skin(verts, rotmats, joints, weights, parents):
    G = _naive_global(rotmats, joints, parents)
    out = np.zeros_like(verts)
    for v in range(len(verts)):
        acc = np.zeros(3)
        for j in range(len(parents)):
            # move to the joint's rest frame, then apply its world transform
            local = np.r_[verts[v] - joints[j], 1.0]
            acc += weights[v, j] * (G[j] @ local)[:3]
        out[v] = acc
    return out, np.array([g[:3, 3] for g in G])


def _problem(B=2, V=30, seed=0):
    g = torch.Generator().manual_seed(seed)
    rot = random_rotations(B * 16, generator=g).reshape(B, 16, 3, 3)
    joints = 0.05 * torch.randn(B, 16, 3, generator=g, dtype=torch.float64)
    verts = 0.05 * torch.randn(B, V, 3, generator=g, dtype=torch.float64)
    w = torch.rand(V, 16, generator=g, dtype=torch.float64) ** 4
    return rot, joints, verts, w / w.sum(1, keepdim=True)


def test_forward_kinematics_and_skin_match_naive():
    rot, joints, verts, w = _problem()
    posed_j, T = forward_kinematics(rot, joints, JOINT_PARENTS)
    out = skin(verts, T, w)
    assert T.shape == (2, 16, 4, 4) and out.shape == verts.shape
    for b in range(2):
        v_ref, j_ref = _naive_skin(
            verts[b].numpy(), rot[b].numpy(), joints[b].numpy(), w.numpy(), JOINT_PARENTS
        )
        assert_close(out[b], v_ref, atol=1e-12)
        assert_close(posed_j[b], j_ref, atol=1e-12)
        # each skinning transform maps the joint's rest position to its posed position
        homog = torch.cat([joints[b], torch.ones(16, 1, dtype=torch.float64)], 1)
        assert_close((T[b] @ homog[..., None])[:, :3, 0], j_ref, atol=1e-12)


def test_identity_pose_gives_rest_geometry():
    _, joints, verts, w = _problem(seed=1)
    eye = torch.eye(3, dtype=torch.float64).expand(2, 16, 3, 3)
    posed_j, T = forward_kinematics(eye, joints, JOINT_PARENTS)
    assert_close(posed_j, joints, atol=1e-14)
    assert_close(skin(verts, T, w), verts, atol=1e-14)
    assert_close(T, torch.eye(4, dtype=torch.float64).expand_as(T), atol=1e-14)


def test_root_rotation_is_rigid_about_the_root():
    rot, joints, verts, w = _problem(seed=2)
    R0 = rot[:, :1].expand(-1, 16, -1, -1).clone()
    R0[:, 1:] = torch.eye(3, dtype=torch.float64)
    _, T = forward_kinematics(R0, joints, JOINT_PARENTS)
    expected = (verts - joints[:, :1]) @ rot[:, 0].transpose(1, 2) + joints[:, :1]
    assert_close(skin(verts, T, w), expected, atol=1e-12)


def test_gradcheck_lbs():
    g = torch.Generator().manual_seed(3)
    aa = (0.7 * torch.randn(1, 16, 3, generator=g, dtype=torch.float64)).requires_grad_(True)
    joints = (0.05 * torch.randn(1, 16, 3, generator=g, dtype=torch.float64)).requires_grad_(True)
    verts = (0.05 * torch.randn(1, 6, 3, generator=g, dtype=torch.float64)).requires_grad_(True)
    w = torch.rand(6, 16, generator=g, dtype=torch.float64)
    w = (w / w.sum(1, keepdim=True)).requires_grad_(True)

    def f(aa, joints, verts, w):
        pj, T = forward_kinematics(axis_angle_to_matrix(aa), joints, JOINT_PARENTS)
        return skin(verts, T, w), pj

    assert torch.autograd.gradcheck(f, (aa, joints, verts, w), eps=1e-6, atol=1e-7)
