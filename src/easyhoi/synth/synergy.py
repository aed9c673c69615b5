"""Hand-side helpers of grasp synthesis: batched posing and grasp synergies.

A *synergy* is a pair of articulations (open, closed) for one grasp type; closing a grasp moves
each digit's joints along the straight line between the two in axis-angle space
(:func:`easyhoi.synth.grasp.synthesize_grasp` freezes joints segment by segment on contact).
The closed postures are partly fitted once per hand model by gradient descent on the thumb
(its distal pad brought onto a target: the index and middle fingertip pads for a pinch, the
radial side of the index middle phalanx for a key pinch, the index middle phalanx of a fist for
a power wrap), so the same code serves OpenHand and a user's MANO.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle
from easyhoi.hand.base import HandModel
from easyhoi.hand.lbs import forward_kinematics
from easyhoi.hand.regions import DIGIT_JOINTS, flexion_axes
from easyhoi.optim.adam import Adam
from easyhoi.structures import HandParams

#: Grasp types with a synergy.
SYNERGY_TYPES = ("power", "precision", "lateral")


class HandPoser:
    """Poses one shaped right hand for many articulations at once (same maths as
    :meth:`HandModel.forward` without keypoints and mirroring; skinning by one matrix product).

    ``world = R @ v_canonical(theta) + T`` with ``v_canonical`` the hand at zero global
    orientation and zero translation.
    """

    def __init__(self, model: HandModel, betas: torch.Tensor):
        with torch.no_grad():
            v, j = model.shaped(betas.reshape(1, -1).double())
        self.betas = betas.reshape(-1).double()
        self.v_rest, self.j_rest = v, j  # (1, V, 3), (1, 16, 3)
        self.weights = model.skin_weights.double()
        self.parents = model.parents
        self.model = model

    def canonical(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, 45) articulation -> (B, V, 3) canonical vertices."""
        B = pose.shape[0]
        full = torch.cat([torch.zeros(B, 3, dtype=pose.dtype), pose], dim=1).reshape(B, 16, 3)
        rot = axis_angle_to_matrix(full)
        v_rest = self.v_rest.expand(B, -1, -1)
        offsets = self.model.pose_offsets(rot)
        if offsets is not None:
            v_rest = v_rest + offsets
        _, transforms = forward_kinematics(rot, self.j_rest.expand(B, -1, -1), self.parents)
        T = (self.weights @ transforms[:, :, :3, :].reshape(B, 16, 12)).reshape(B, -1, 3, 4)
        return (T[..., :3] @ v_rest[..., None])[..., 0] + T[..., 3]

    def subset(self, ids: np.ndarray):
        """A function (B, 45) -> (B, len(ids), 3) posing only the vertices ``ids``."""
        ids = torch.as_tensor(ids)
        weights, v_rest = self.weights[ids], self.v_rest[:, ids]

        def pose_fn(pose: torch.Tensor) -> torch.Tensor:
            B = pose.shape[0]
            full = torch.cat([torch.zeros(B, 3, dtype=pose.dtype), pose], 1).reshape(B, 16, 3)
            rot = axis_angle_to_matrix(full)
            _, tf = forward_kinematics(rot, self.j_rest.expand(B, -1, -1), self.parents)
            T = (weights @ tf[:, :, :3, :].reshape(B, 16, 12)).reshape(B, -1, 3, 4)
            return (T[..., :3] @ v_rest.expand(B, -1, -1)[..., None])[..., 0] + T[..., 3]

        return pose_fn

    def params(self, pose: torch.Tensor, R: torch.Tensor, T: torch.Tensor) -> HandParams:
        """HandParams whose model output equals ``R @ canonical(pose) + T``."""
        j0 = self.j_rest[0, 0]
        go = matrix_to_axis_angle(R[None])
        transl = T + R @ j0 - j0
        return HandParams(go, transl[None], pose.reshape(1, 45), self.betas[None])


def frame_rotation(a1_hand, a2_hand, a1_world, a2_world) -> np.ndarray:
    """(3, 3) rotation mapping hand axis ``a1`` exactly onto world ``a1`` and ``a2`` as closely
    as possible onto world ``a2`` (both made orthogonal to ``a1``)."""

    def frame(a, b):
        a = np.asarray(a, float) / np.linalg.norm(a)
        b = np.asarray(b, float) - (np.dot(b, a)) * a
        nb = np.linalg.norm(b)
        if nb < 1e-9:
            raise InvalidInputError("frame_rotation: the two axes are parallel")
        b = b / nb
        return np.stack([a, b, np.cross(a, b)], axis=1)

    return frame(a1_world, a2_world) @ frame(a1_hand, a2_hand).T


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis``."""
    aa = torch.as_tensor(np.asarray(axis, float) * angle / np.linalg.norm(axis))
    return axis_angle_to_matrix(aa).numpy()


_CURLED = (0.9, 1.2, 0.7)


def _digit_pose(axes: np.ndarray, values: dict) -> np.ndarray:
    """(15, 3) articulation with each listed digit flexed by its (base, middle, distal) angles."""
    p = np.zeros((15, 3))
    for d, v in values.items():
        for j, a in zip(DIGIT_JOINTS[d], v, strict=True):
            p[j - 1] = axes[j - 1] * a
    return p


def pad_ids(model: HandModel, joint: int) -> np.ndarray:
    """Contact-zone vertices dominated by ``joint`` (a finger segment's pad, or the palm: 0)."""
    reg = model.regions
    cv, part = reg.contact_vertices.numpy(), reg.vertex_part.numpy()
    return cv[part[cv] == joint]


def _fit_thumb(poser, base: np.ndarray, target_ids, free: tuple[str, ...], iters: int = 150):
    """Thumb articulation (and a common flexion scale of the ``free`` digits) bringing the thumb's
    distal pad onto the centroid of ``target_ids`` (gradient descent on 9 + 1 parameters)."""
    pad = pad_ids(poser.model, 15)
    ids = np.concatenate([pad, target_ids])
    sub = poser.subset(ids)
    n_pad = len(pad)
    base_t = torch.as_tensor(base)
    free_rows = [j - 1 for d in free for j in DIGIT_JOINTS[d]]
    scale_mask = torch.zeros(15, 1, dtype=torch.float64)
    scale_mask[free_rows] = 1.0
    th = torch.zeros(9, dtype=torch.float64, requires_grad=True)
    log_s = torch.zeros(1, dtype=torch.float64, requires_grad=bool(free))
    opt = Adam([th, log_s], lr=0.05)
    for _ in range(iters):
        opt.zero_grad()
        p = base_t * (1 + scale_mask * (torch.exp(log_s) - 1))
        p = torch.cat([p[:12], th.reshape(3, 3)])
        v = sub(p.reshape(1, 45))[0]
        gap = v[:n_pad].mean(0) - v[n_pad:].mean(0)
        loss = 1e4 * gap.pow(2).sum() + 2e-3 * th.pow(2).sum()
        loss.backward()
        opt.step()
    with torch.no_grad():
        p = base_t * (1 + scale_mask * (torch.exp(log_s) - 1))
        p[12:] = th.reshape(3, 3)
    return p.numpy()


_SYNERGIES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def synergy(model: HandModel, grasp_type: str) -> tuple[np.ndarray, np.ndarray]:
    """Open and closed (15, 3) articulations of a grasp type (cached per model).

    * power: flat hand -> fingers flexed (1.6, 1.76, 1.28) rad, thumb wrapped onto the index
      finger's middle phalanx of a fist (fitted).
    * precision: index and middle nearly straight, ring and pinky curled -> thumb pad meeting
      the index and middle fingertip pads (thumb and finger flexion fitted).
    * lateral: fingers curled, thumb extended -> thumb pad on the radial side of the index
      finger's middle phalanx (fitted).
    """
    cache = _SYNERGIES.setdefault(model, {})
    if grasp_type in cache:
        return cache[grasp_type]
    axes = flexion_axes(model)
    poser = HandPoser(model, torch.zeros(10, dtype=torch.float64))
    part = model.regions.vertex_part.numpy()
    fingers = ("index", "middle", "ring", "pinky")
    if grasp_type == "power":
        opened = np.zeros((15, 3))
        closed = _digit_pose(axes, {d: (1.6, 1.76, 1.28) for d in fingers})
        fist = _digit_pose(axes, {d: (1.0, 1.2, 0.8) for d in fingers})
        thumb = _fit_thumb(poser, fist, np.nonzero(part == 2)[0], ())
        closed[12:] = thumb[12:]
    elif grasp_type == "precision":
        curled = {"ring": _CURLED, "pinky": _CURLED}
        opened = _digit_pose(axes, {"index": (0.2, 0.25, 0.1), "middle": (0.2, 0.25, 0.1),
                                    **curled})  # fmt: skip
        base = _digit_pose(axes, {"index": (0.5, 0.6, 0.3), "middle": (0.5, 0.6, 0.3), **curled})
        target = np.concatenate([pad_ids(model, 3), pad_ids(model, 6)])
        closed = _fit_thumb(poser, base, target, ("index", "middle"))
    elif grasp_type == "lateral":
        opened = _digit_pose(axes, {d: _CURLED for d in fingers})
        with torch.no_grad():
            v = poser.canonical(torch.as_tensor(opened.reshape(1, 45)))[0].numpy()
        idx = np.nonzero(part == 2)[0]
        radial = idx[np.argsort(-v[idx, 2])[:8]]
        closed = _fit_thumb(poser, opened, radial, ())
    else:
        raise InvalidInputError(f"grasp_type must be one of {SYNERGY_TYPES}, got {grasp_type!r}")
    cache[grasp_type] = (opened, closed)
    return opened, closed


__all__ = ["SYNERGY_TYPES", "HandPoser", "axis_rotation", "frame_rotation", "pad_ids", "synergy"]
