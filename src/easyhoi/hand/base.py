"""The hand-model interface shared by the built-in open hand and user-supplied MANO.

A :class:`HandModel` is a stateless layer: it holds the model's fixed data as buffers and takes
every parameter as an argument (:class:`~easyhoi.structures.HandParams`). All models share the
MANO layout: 16 joints with the MANO kinematic tree, 45 articulation parameters (15 joints x
axis-angle, relative to the flat rest pose), 10 shape coefficients, and 21 keypoints (16 joints
+ 5 fingertip vertices) in OpenPose order.

Models are right hands. A left hand (``params.side == "left"``) is the mirror image (x negated)
of the right hand posed with mirrored parameters (axis-angle y and z negated, translation x
negated); faces of a left hand have reversed winding so normals still point outwards.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import fields

import torch
from torch import nn

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand.lbs import forward_kinematics, skin
from easyhoi.hand.regions import HandRegions, compute_regions
from easyhoi.structures import (
    JOINT_PARENTS,
    OPENPOSE_ORDER,
    HandOutput,
    HandParams,
)

#: Fingertip order used by ``tip_vertex_ids``.
TIP_ORDER = ("thumb", "index", "middle", "ring", "pinky")


def mirror_params(params: HandParams) -> HandParams:
    """The mirror image (x -> -x) of a hand's parameters; flips ``side``.

    Rotations conjugated by the reflection diag(-1, 1, 1) keep their x component and negate y
    and z; the translation's x is negated. Applying it twice is the identity.
    """
    flip = torch.tensor([1.0, -1.0, -1.0], dtype=params.pose.dtype, device=params.pose.device)
    return HandParams(
        global_orient=params.global_orient * flip,
        transl=params.transl * -flip,
        pose=(params.pose.reshape(-1, 15, 3) * flip).reshape(-1, 45),
        betas=params.betas,
        side="left" if params.side == "right" else "right",
    )


def mirror_points(x: torch.Tensor) -> torch.Tensor:
    """Negate the x coordinate of (..., 3) points."""
    return x * torch.tensor([-1.0, 1.0, 1.0], dtype=x.dtype, device=x.device)


class HandModel(nn.Module, ABC):
    """Base class of MANO-layout hand models (right hands; left hands by mirroring).

    Subclasses register these buffers in ``__init__``:
        faces: (F, 3) long, closed watertight mesh, outward (counter-clockwise) winding.
        skin_weights: (V, 16) float, rows summing to 1.
        tip_vertex_ids: (5,) long, fingertip vertices in ``TIP_ORDER``.
    and implement :meth:`shaped`. Pose-corrective offsets are optional (:meth:`pose_offsets`).
    """

    name: str = "hand"
    parents: tuple[int, ...] = JOINT_PARENTS

    faces: torch.Tensor
    skin_weights: torch.Tensor
    tip_vertex_ids: torch.Tensor

    @abstractmethod
    def shaped(self, betas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest-pose geometry for shape coefficients.

        Args:
            betas: (B, 10).
        Returns:
            vertices (B, V, 3) and joints (B, 16, 3) of the flat rest pose.
        """

    def shaped_subset(
        self, betas: torch.Tensor, vertex_ids: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest-pose vertices ``vertex_ids`` (B, K, 3) and all joints (B, 16, 3).

        Models with a linear shape space (buffers ``v_template`` (V, 3), ``shapedirs``
        (V, 3, 10) and a dense ``J_regressor`` (16, V), as MANO and the open hand) get a fast
        path that never forms all V vertices: the joints' own blend shapes are precomputed.
        Other models fall back to :meth:`shaped`.
        """
        names = ("v_template", "shapedirs", "J_regressor")
        if not all(isinstance(getattr(self, n, None), torch.Tensor) for n in names):
            v, j = self.shaped(betas)
            return v[:, vertex_ids], j
        dt = betas.dtype
        key = (dt, self.shapedirs.data_ptr())
        cache = getattr(self, "_joint_blend", None)
        if cache is None or cache[0] != key:
            Jr = self.J_regressor.to(dt)
            cache = (key, Jr @ self.v_template.to(dt),
                     torch.einsum("jv,vck->jck", Jr, self.shapedirs.to(dt)))  # fmt: skip
            object.__setattr__(self, "_joint_blend", cache)
        _, j_tpl, j_dirs = cache
        joints = j_tpl + torch.einsum("jck,bk->bjc", j_dirs, betas)
        v = self.v_template[vertex_ids].to(dt) + torch.einsum(
            "vck,bk->bvc", self.shapedirs[vertex_ids].to(dt), betas
        )
        return v, joints

    def pose_offsets(self, rotmats: torch.Tensor) -> torch.Tensor | None:
        """Optional pose-corrective vertex offsets (B, V, 3) from (B, 16, 3, 3) rotations."""
        return None

    @property
    def num_vertices(self) -> int:
        return int(self.skin_weights.shape[0])

    @property
    def regions(self) -> HandRegions:
        """Palmar faces, contact zones and fingertips (see :mod:`easyhoi.hand.regions`)."""
        cached = getattr(self, "_regions", None)
        if cached is None:
            cached = compute_regions(self)
            object.__setattr__(self, "_regions", cached)
        return cached

    def on_device(self, device) -> HandModel:
        """This model when its buffers are already on ``device``, else a copy moved there.

        A copy, not ``.to()`` in place: the CPU instance is shared (perception fits the hand
        on the CPU, built-in models are cached). The copy's regions are moved with it.
        """
        device = torch.device(device)
        if self.faces.device == device:
            return self
        import copy

        regions = self.regions
        moved = copy.deepcopy(self).to(device)
        object.__setattr__(moved, "_joint_blend", None)
        object.__setattr__(moved, "_regions", HandRegions(
            *(getattr(regions, f.name).to(device) for f in fields(HandRegions))
        ))  # fmt: skip
        return moved

    def faces_for(self, side: str) -> torch.Tensor:
        """(F, 3) faces with outward winding for a ``side`` hand."""
        return self.faces if side == "right" else self.faces[:, [0, 2, 1]]

    def forward(self, params: HandParams, vertex_ids: torch.Tensor | None = None) -> HandOutput:
        """Pose the hand.

        Args:
            params: batched :class:`HandParams` (dtype of its tensors decides the output dtype).
            vertex_ids: (K,) long, skin only these vertices (``vertices`` is then (B, K, 3));
                an empty tensor skips vertex skinning (keypoint fitting needs only keypoints).
        Returns:
            :class:`HandOutput` with (B, V, 3) vertices, (B, 16, 3) joints, (B, 21, 3)
            keypoints in OpenPose order, and the side's faces.
        """
        if not isinstance(params, HandParams):
            raise InvalidInputError(f"expected HandParams, got {type(params).__name__}")
        side = params.side
        p = mirror_params(params) if side == "left" else params
        dtype = p.pose.dtype
        betas = p.betas.to(dtype)
        tip_ids = self.tip_vertex_ids
        n_tips = len(tip_ids)
        if vertex_ids is None:
            v_rest, j_rest = self.shaped(betas)
            ids = torch.cat([tip_ids, torch.arange(v_rest.shape[1], device=tip_ids.device)])
            v_rest = v_rest[:, ids]
        else:
            ids = torch.cat([tip_ids, vertex_ids.to(torch.long)])
            v_rest, j_rest = self.shaped_subset(betas, ids)
        rotmats = axis_angle_to_matrix(p.full_pose)  # (B, 16, 3, 3)
        offsets = self.pose_offsets(rotmats)
        if offsets is not None:
            v_rest = v_rest + offsets[:, ids]
        joints, transforms = forward_kinematics(rotmats, j_rest, self.parents)
        weights = self.skin_weights.to(dtype)[ids]
        posed = skin(v_rest, transforms, weights) + p.transl[:, None]
        tips, verts = posed[:, :n_tips], posed[:, n_tips:]
        joints = joints + p.transl[:, None]
        keypoints = torch.cat([joints, tips], dim=1)[:, list(OPENPOSE_ORDER)]
        if side == "left":
            verts, joints, keypoints = (mirror_points(x) for x in (verts, joints, keypoints))
        return HandOutput(verts, joints, keypoints, self.faces_for(side))
