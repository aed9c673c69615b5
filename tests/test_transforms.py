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
