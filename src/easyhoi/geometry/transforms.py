"""Rotation conversions (batched, differentiable, stable at zero angle)."""

from __future__ import annotations

import torch

from easyhoi.checks import check_last_dim

_SMALL = 1e-4


def skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices ``[v]_x``."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula.

    Args:
        aa: (..., 3) axis-angle vectors (axis * angle in radians).
    Returns:
        (..., 3, 3) rotation matrices. Gradients are finite at zero angle (Taylor branch).
    """
    check_last_dim(aa, 3, "axis-angle")
    theta2 = (aa * aa).sum(-1)
    small = theta2 < _SMALL**2
    if aa.device.type != "cpu" or bool(small.any()):  # (off the CPU, asking would wait)
        safe2 = torch.where(small, torch.ones_like(theta2), theta2)
        theta = safe2.sqrt()
        a = torch.where(small, 1 - theta2 / 6 + theta2**2 / 120, torch.sin(theta) / theta)
        b = torch.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - torch.cos(theta)) / safe2)
    else:
        # No angle near zero (on the CPU): the closed form alone. The same values, and the same
        # gradients: through the branches above the Taylor terms' share of every gradient is
        # exactly zero. Without the selections the hand fit's batched Jacobian, which runs
        # ``where``'s backward once per residual row, costs about a fifth less.
        theta = theta2.sqrt()
        a = torch.sin(theta) / theta
        b = (1 - torch.cos(theta)) / theta2
    K = skew(aa)
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand(K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def matrix_to_axis_angle(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle, angle in [0, pi].

    Goes through unit quaternions, which is accurate near 0 and near pi.
    """
    return quaternion_to_axis_angle(matrix_to_quaternion(R))


def matrix_to_quaternion(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 4) unit quaternions (w, x, y, z) with w >= 0."""
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = torch.stack(
        [
            1 + tr,
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ],
        dim=-1,
    )
    best = cands.argmax(dim=-1, keepdim=True)
    # four candidate (unnormalised) quaternions, pick the best-conditioned one
    q0 = torch.stack(
        [cands[..., 0], m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
         m[..., 1, 0] - m[..., 0, 1]], -1)  # fmt: skip
    q1 = torch.stack(
        [m[..., 2, 1] - m[..., 1, 2], cands[..., 1], m[..., 0, 1] + m[..., 1, 0],
         m[..., 0, 2] + m[..., 2, 0]], -1)  # fmt: skip
    q2 = torch.stack(
        [m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0], cands[..., 2],
         m[..., 1, 2] + m[..., 2, 1]], -1)  # fmt: skip
    q3 = torch.stack(
        [m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
         cands[..., 3]], -1)  # fmt: skip
    allq = torch.stack([q0, q1, q2, q3], dim=-2)
    q = torch.gather(allq, -2, best[..., None].expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quaternion_to_axis_angle(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3) axis-angle."""
    q = torch.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = v.norm(dim=-1)
    angle = 2 * torch.atan2(s, q[..., 0])
    small = s < 1e-8
    scale = torch.where(small, 2 / q[..., 0].clamp_min(1e-12), angle / s.clamp_min(1e-12))
    return v * scale[..., None]


def rotation_6d_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """(..., 6) continuous 6D rotation (Zhou et al. 2019) -> (..., 3, 3) by Gram-Schmidt."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / a1.norm(dim=-1, keepdim=True)
    b2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = b2 / b2.norm(dim=-1, keepdim=True)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-2)


def matrix_to_rotation_6d(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two rows."""
    return R[..., :2, :].reshape(*R.shape[:-2], 6)


def random_rotations(n: int, generator: torch.Generator | None = None, dtype=torch.float64):
    """(n, 3, 3) uniformly random rotations (from normalised Gaussian quaternions)."""
    q = torch.randn(n, 4, generator=generator, dtype=dtype)
    q = q / q.norm(dim=-1, keepdim=True)
    return quaternion_to_matrix(q)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)  # fmt: skip
