"""Pure linear-blend-skinning functions shared by every MANO-layout hand model."""

from __future__ import annotations

from collections.abc import Sequence

import torch


def forward_kinematics(
    rotmats: torch.Tensor, joints: torch.Tensor, parents: Sequence[int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Compose local joint rotations along the kinematic tree.

    Each joint rotates about its own rest position; the root rotates about the root joint.

    Args:
        rotmats: (B, J, 3, 3) local rotation of every joint (root first).
        joints: (B, J, 3) rest-pose joint positions.
        parents: length-J parent indices, ``parents[0] == -1``, parents before children.
    Returns:
        posed_joints: (B, J, 3) joint positions after posing.
        transforms: (B, J, 4, 4) skinning transforms mapping rest-pose points to posed points
            (``G_j @ [I | -J_j]``), ready for :func:`skin`.
    """
    B, J = joints.shape[:2]
    rel = torch.cat([joints[:, :1], joints[:, 1:] - joints[:, list(parents[1:])]], dim=1)
    chain_R = [rotmats[:, 0]]
    chain_t = [rel[:, 0]]
    for j in range(1, J):
        p = parents[j]
        chain_R.append(chain_R[p] @ rotmats[:, j])
        chain_t.append(chain_t[p] + (chain_R[p] @ rel[:, j, :, None])[..., 0])
    Rg = torch.stack(chain_R, dim=1)  # (B, J, 3, 3)
    tg = torch.stack(chain_t, dim=1)  # (B, J, 3) = posed joint positions
    t_skin = tg - (Rg @ joints[..., None])[..., 0]
    top = torch.cat([Rg, t_skin[..., None]], dim=-1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=joints.dtype, device=joints.device)
    bottom = bottom.expand(B, J, 1, 4)
    return tg, torch.cat([top, bottom], dim=-2)


def skin(vertices: torch.Tensor, transforms: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning.

    Args:
        vertices: (B, V, 3) rest-pose vertices (shape and pose-corrective offsets applied).
        transforms: (B, J, 4, 4) per-joint skinning transforms from :func:`forward_kinematics`.
        weights: (V, J) skinning weights, rows summing to 1.
    Returns:
        (B, V, 3) posed vertices.
    """
    T = torch.einsum("vj,bjrc->bvrc", weights, transforms[:, :, :3, :])  # (B, V, 3, 4)
    return (T[..., :3] @ vertices[..., None])[..., 0] + T[..., 3]
