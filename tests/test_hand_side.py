"""Left hands by mirroring (hand/base.py), keypoint order, on a synthetic MANO model."""

from __future__ import annotations

import pytest
import torch
import trimesh

from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand.base import mirror_params, mirror_points
from easyhoi.hand.mano import MANOHand
from easyhoi.structures import HandParams
from easyhoi.testing.mano_synth import write_synthetic_mano
from tests.helpers import assert_close


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("mano_side")
    return MANOHand(write_synthetic_mano(d, seed=2))


def _params(side="right", seed=0, B=2):
    g = torch.Generator().manual_seed(seed)
    r = lambda n, s: s * torch.randn(B, n, generator=g, dtype=torch.float64)  # noqa: E731
    return HandParams(r(3, 1.0), r(3, 0.1), r(45, 0.5), r(10, 1.0), side=side)


def test_mirror_params_twice_is_identity():
    p = _params("left")
    q = mirror_params(p)
    assert q.side == "right"
    back = mirror_params(q)
    assert back.side == "left"
    for k, v in p.tensors().items():
        assert_close(getattr(back, k), v, atol=0.0, msg=k)
    assert_close(q.transl[:, 0], -p.transl[:, 0], atol=0.0)


def test_mirrored_rotation_is_conjugation_by_reflection():
    p = _params()
    M = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
    R = axis_angle_to_matrix(p.full_pose)
    Rm = axis_angle_to_matrix(mirror_params(p).full_pose)
    assert_close(Rm, M @ R @ M, atol=1e-12)


@pytest.mark.parametrize("flat", [True, False])
def test_left_is_mirror_of_right(model, flat):
    model.flat_hand_mean = flat
    try:
        left = _params("left", seed=1)
        out_l = model(left)
        out_r = model(mirror_params(left))
    finally:
        model.flat_hand_mean = True
    for name in ("vertices", "joints", "keypoints"):
        assert_close(getattr(out_l, name), mirror_points(getattr(out_r, name)), 1e-12, msg=name)
    # and the other way round: a right hand equals the mirror of the mirrored left hand
    right = _params("right", seed=4)
    assert_close(model(right).vertices, mirror_points(model(mirror_params(right)).vertices), 1e-12)


def test_left_faces_reversed_and_volume_positive(model):
    out_l = model(_params("left", seed=3))
    out_r = model(_params("right", seed=3))
    assert torch.equal(out_l.faces, model.faces[:, [0, 2, 1]])
    assert torch.equal(out_r.faces, model.faces)
    for out in (out_l, out_r):
        mesh = out.to_trimesh(1)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0
    # the left mesh with the right (unreversed) faces would be inside out
    inside_out = trimesh.Trimesh(out_l.vertices[0].numpy(), model.faces.numpy(), process=False)
    assert inside_out.volume < 0


@pytest.mark.parametrize("side", ["right", "left"])
def test_keypoints_in_openpose_order(model, side):
    out = model(_params(side, seed=5))
    tips = model.tip_vertex_ids  # thumb, index, middle, ring, pinky
    for kp, tip in zip((4, 8, 12, 16, 20), tips.tolist(), strict=True):
        assert_close(out.keypoints[:, kp], out.vertices[:, tip], atol=0.0)
    # wrist, then thumb (13-15), index (1-3), middle (4-6), ring (10-12), pinky (7-9)
    chains = {0: 0, 1: 13, 2: 14, 3: 15, 5: 1, 6: 2, 7: 3, 9: 4, 10: 5, 11: 6}
    chains.update({13: 10, 14: 11, 15: 12, 17: 7, 18: 8, 19: 9})
    for kp, joint in chains.items():
        assert_close(out.keypoints[:, kp], out.joints[:, joint], atol=0.0)
