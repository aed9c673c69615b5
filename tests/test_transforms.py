import torch

from easyhoi.geometry.transforms import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    matrix_to_rotation_6d,
    random_rotations,
    rotation_6d_to_matrix,
)
from tests.helpers import assert_close


def _naive_rodrigues(aa):
    out = []
    for v in aa:
        th = v.norm()
        if th < 1e-12:
            out.append(torch.eye(3, dtype=aa.dtype))
            continue
        k = v / th
        K = torch.tensor([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], dtype=aa.dtype)
        out.append(torch.eye(3, dtype=aa.dtype) + torch.sin(th) * K + (1 - torch.cos(th)) * K @ K)
    return torch.stack(out)


def test_rodrigues_matches_naive_and_is_orthonormal():
    aa = torch.randn(64, 3, dtype=torch.float64) * 1.5
    aa[0] = 0
    aa[1] = 1e-6
    R = axis_angle_to_matrix(aa)
    assert_close(R, _naive_rodrigues(aa), atol=1e-10)
    assert_close(R @ R.transpose(-1, -2), torch.eye(3).expand(64, 3, 3), atol=1e-10)
    assert_close(torch.linalg.det(R), torch.ones(64), atol=1e-10)


def test_axis_angle_round_trip_including_near_pi():
    aa = torch.randn(200, 3, dtype=torch.float64)
    aa = aa / aa.norm(dim=-1, keepdim=True) * torch.rand(200, 1, dtype=torch.float64) * 3.1
    aa[0] = torch.tensor([3.14159, 0, 0], dtype=torch.float64)
    back = matrix_to_axis_angle(axis_angle_to_matrix(aa))
    assert_close(axis_angle_to_matrix(back), axis_angle_to_matrix(aa), atol=1e-9)
    assert_close(back[1:], aa[1:], atol=1e-7)


def test_rodrigues_gradcheck_including_zero():
    for v in (torch.zeros(1, 3), torch.full((1, 3), 1e-5), torch.tensor([[0.3, -1.2, 0.7]])):
        x = v.double().requires_grad_(True)
        assert torch.autograd.gradcheck(axis_angle_to_matrix, (x,))


def test_6d_round_trip():
    R = random_rotations(50, torch.Generator().manual_seed(1))
    assert_close(rotation_6d_to_matrix(matrix_to_rotation_6d(R)), R, atol=1e-12)


def _rodrigues_with_branches(aa):
    """The formula with both branches selected per angle (what runs when an angle is small)."""
    theta2 = (aa * aa).sum(-1)
    small = theta2 < 1e-4**2
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = safe2.sqrt()
    a = torch.where(small, 1 - theta2 / 6 + theta2**2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - torch.cos(theta)) / safe2)
    x, y, z = aa.unbind(-1)
    o = torch.zeros_like(x)
    K = torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*aa.shape[:-1], 3, 3)
    return (
        torch.eye(3, dtype=aa.dtype).expand(K.shape)
        + a[..., None, None] * K
        + (b[..., None, None] * (K @ K))
    )


def test_rodrigues_without_small_angles_has_the_branches_values_and_gradients_to_the_bit():
    torch.manual_seed(3)
    for dtype in (torch.float32, torch.float64):
        aa = (torch.randn(5, 16, 3, dtype=dtype) * 0.7).requires_grad_(True)
        assert bool(((aa * aa).sum(-1) >= 1e-8).all())
        w = torch.randn(5, 16, 3, 3, dtype=dtype)
        got = axis_angle_to_matrix(aa)
        ref = _rodrigues_with_branches(aa)
        assert torch.equal(got, ref)
        (g_got,) = torch.autograd.grad((got * w).sum(), aa)
        (g_ref,) = torch.autograd.grad((ref * w).sum(), aa)
        assert torch.equal(g_got, g_ref)
        # with one angle small the branches run, as in the reference
        aa2 = aa.detach().clone()
        aa2[0, 0] = 1e-6
        aa2.requires_grad_(True)
        got, ref = axis_angle_to_matrix(aa2), _rodrigues_with_branches(aa2)
        assert torch.equal(got, ref)
        g_got = torch.autograd.grad((got * w).sum(), aa2)[0]
        assert torch.equal(g_got, torch.autograd.grad((ref * w).sum(), aa2)[0])
