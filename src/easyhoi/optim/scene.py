"""Shared per-run state of the optimizer: object tensors, masks per resolution, SDF, hand model.

Frames and units used by every stage (see :mod:`easyhoi.hoi`):

- **object frame**: the object mesh's own canonical frame, in its own (arbitrary) unit. The
  object never moves; the object camera ``x_cam = R x_obj + t`` (object units) is fitted in
  stage 1 and the hand is placed in this frame in stages 2 and 3.
- **metric scale** ``m``: metres per object unit. The hand model is metric, so a hand of
  parameters ``p`` has vertices ``model(p).vertices / m`` in object units.
- **metric object frame**: the object frame scaled by ``m``; the final hand parameters live
  there (``HOIResult.hand_params``).
- **normalised object units**: object units divided by the object's largest bounding-box side
  (``Scene.extent``); SDF values of the losses and the penetration threshold are in these units
  (the reference implementation normalises the object the same way).
- **object camera frame, metric**: stage 2 keeps the hand in the object camera's frame in metres
  (``HandParams`` as the estimator gives them, moved to the object camera); object-frame
  vertices are ``R^T (V_cam / m - t)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from easyhoi.errors import InvalidInputError, OptimizationError
from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle
from easyhoi.hand.base import HandModel, HandRegions
from easyhoi.hoi import HOIInput
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import DEFAULT_CULL_EPS, cull_margin, soft_silhouette
from easyhoi.structures import Camera, HandParams

logger = logging.getLogger(__name__)

__all__ = [
    "SILHOUETTE_SIGMA",
    "Scene",
    "StageLoop",
    "camera_hand_to_object",
    "check_finite_loss",
    "hand_in_camera",
    "hard_iou",
    "move_hand",
    "phase_sizes",
    "rest_wrist",
]

#: Sharpness (pixels squared) of every soft silhouette of the optimizer. Smaller than the
#: renderer's default (1 px^2): coverage is a probabilistic union that counts back faces, so at
#: a silhouette edge the front and back faces both spill coverage outside; at 1 px^2 that
#: inflates a 30 px object's soft area by 15-25 % and biases the fitted camera and hand (the
#: optimum shrinks them). At 0.1 px^2 the inflation is 4-8 % and gradients still reach the
#: boundary pixels.
SILHOUETTE_SIGMA = 0.1

#: Padding of the object SDF grid beyond the mesh, as a fraction of its largest side.
SDF_PADDING = 0.3

#: Voxels around the surface where the SDF grid is exact (penetration and contact terms act
#: there); farther nodes carry exact signs and bounded values, and the build is ~5x faster.
SDF_EXACT_BAND = 4.0


@dataclass
class Scene:
    """Everything the stages share for one run (built once by :meth:`from_input`).

    Attributes
    ----------
    object_verts : (V_o, 3) tensor
        Object vertices in object units (the input mesh, unchanged).
    object_faces : (F_o, 3) long tensor
    watertight : trimesh.Trimesh
        A watertight version of the object (the input itself when already watertight), used
        for the SDF and the plausibility metrics.
    center : (3,) tensor
        Centre of the object's bounding box (object units).
    extent : float
        Largest side of the object's bounding box (object units): one normalised unit.
    hand_model : HandModel
    regions : HandRegions
    dtype : torch.dtype
    image_size : (H, W)
    masks : dict of str -> (H, W) tensor
        Full-resolution float masks ``hand`` (M_h), ``object`` (M_o), ``amodal`` (M^_o).
    """

    object_verts: torch.Tensor
    object_faces: torch.Tensor
    watertight: object
    center: torch.Tensor
    extent: float
    hand_model: HandModel
    regions: HandRegions
    dtype: torch.dtype
    image_size: tuple[int, int]
    masks: dict
    _mask_cache: dict = field(default_factory=dict, repr=False)
    _sdf_cache: dict = field(default_factory=dict, repr=False)
    _depth_cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_input(cls, inp: HOIInput, hand_model: HandModel, dtype: torch.dtype) -> Scene:
        """Build the shared state of one run from an :class:`HOIInput`."""
        mesh = inp.object_mesh
        if mesh.is_watertight:
            wt = mesh
        else:
            from easyhoi.geometry.watertight import make_watertight

            logger.info("object mesh is not watertight: repairing it for the SDF and metrics")
            wt, _ = make_watertight(mesh)
        v = torch.as_tensor(np.asarray(mesh.vertices), dtype=dtype)
        lo, hi = v.min(0).values, v.max(0).values
        extent = float((hi - lo).max())
        if not extent > 0:
            raise InvalidInputError("object mesh is degenerate (zero extent)")
        masks = {
            "hand": torch.from_numpy(np.array(inp.hand_mask)).to(dtype),
            "object": torch.from_numpy(np.array(inp.object_mask)).to(dtype),
            "amodal": torch.from_numpy(np.array(inp.amodal_mask)).to(dtype),
        }
        return cls(
            object_verts=v,
            object_faces=torch.as_tensor(np.asarray(mesh.faces), dtype=torch.long),
            watertight=wt,
            center=0.5 * (lo + hi),
            extent=extent,
            hand_model=hand_model,
            regions=hand_model.regions,
            dtype=dtype,
            image_size=inp.size,
            masks=masks,
        )

    # -- resolution -----------------------------------------------------------------------------
    def render_size(self, fraction: float, render_size: int) -> tuple[int, int]:
        """(h, w) of a render whose long side is ``fraction * render_size`` pixels."""
        H, W = self.image_size
        s = fraction * render_size / max(H, W)
        return max(1, int(round(H * s))), max(1, int(round(W * s)))

    def masks_at(self, h: int, w: int) -> dict:
        """Masks area-resampled to (h, w): soft values in [0, 1] (cached)."""
        key = (h, w)
        if key not in self._mask_cache:
            out = {}
            for k, m in self.masks.items():
                if m.shape == (h, w):
                    out[k] = m
                else:
                    out[k] = F.interpolate(m[None, None], size=(h, w), mode="area")[0, 0]
            self._mask_cache[key] = out
        return self._mask_cache[key]

    # -- object SDF -----------------------------------------------------------------------------
    def sdf_grid(self, resolution: int):
        """The object's SDF grid (object units) at ``resolution`` nodes per side (cached)."""
        if resolution not in self._sdf_cache:
            from easyhoi.geometry.sdf import build_sdf_grid

            self._sdf_cache[resolution] = build_sdf_grid(
                self.watertight, resolution, padding=SDF_PADDING, dtype=self.dtype,
                exact_band=SDF_EXACT_BAND,
            )  # fmt: skip
        return self._sdf_cache[resolution]

    def sdf(self, points: torch.Tensor, resolution: int) -> torch.Tensor:
        """(..., 3) object-unit points -> (...,) signed distance in normalised units."""
        from easyhoi.geometry.sdf import query

        return query(self.sdf_grid(resolution), points) / self.extent

    # -- occlusion-aware hand mask ----------------------------------------------------------------
    def object_depth(self, camera: Camera) -> torch.Tensor:
        """(h, w) object z-buffer for a fixed camera (cached on the camera's values)."""
        c = camera.detach()
        key = (c.width, c.height, tuple(c.K.flatten().tolist()), tuple(c.R.flatten().tolist()),
               tuple(c.t.tolist()))  # fmt: skip
        if key not in self._depth_cache:
            if len(self._depth_cache) > 8:
                self._depth_cache.clear()
            self._depth_cache[key] = depth_map(self.object_verts, self.object_faces, c)
        return self._depth_cache[key]

    def hand_silhouettes(self, hand_verts: torch.Tensor, camera: Camera, sigma=None):
        """Soft complete and visible hand silhouettes against the fixed object.

        Same rule as :func:`easyhoi.render.composite.hoi_masks` (``hand * [z_hand_ext <=
        z_object]``) but the object's z-buffer is cached, since the object and the camera do
        not move in stages 2 and 3.

        Parameters
        ----------
        hand_verts : (V, 3) tensor
            Hand vertices in object units.
        camera : Camera
            Object camera at the render resolution.

        Returns
        -------
        hand : (h, w) complete soft silhouette; visible : (h, w); hand_depth : (h, w) no grad.
        """
        sigma = SILHOUETTE_SIGMA if sigma is None else sigma
        faces = self.hand_model.faces
        hand = soft_silhouette(hand_verts, faces, camera, sigma=sigma)
        zh = depth_map(hand_verts.detach(), faces, camera.detach())
        zo = self.object_depth(camera)
        radius = math.ceil(cull_margin(sigma, DEFAULT_CULL_EPS))
        if radius > 0:
            k = 2 * radius + 1
            zmin = -F.max_pool2d(-zh[None, None], k, stride=1, padding=radius)[0, 0]
            zh_ext = torch.where(torch.isfinite(zh), zh, zmin)
        else:
            zh_ext = zh
        visible = hand * (zh_ext <= zo).to(hand.dtype)
        return hand, visible, zh


# ------------------------------------------------------------------------------------------------
# hand placement helpers
# ------------------------------------------------------------------------------------------------


def rest_wrist(model: HandModel, betas: torch.Tensor) -> torch.Tensor:
    """(3,) wrist joint of the flat rest pose for ``betas`` (the centre of global_orient)."""
    with torch.no_grad():
        _, joints = model.shaped(betas.reshape(1, -1))
    return joints[0, 0]


def move_hand(p: HandParams, R: torch.Tensor, t: torch.Tensor, wrist: torch.Tensor) -> HandParams:
    """Parameters of the hand ``R x + t`` (rigid motion applied to every vertex).

    ``wrist`` (3,) is the rest wrist joint (:func:`rest_wrist`); ``R`` (3, 3), ``t`` (3,).

    Right hands: the model is ``Rot(go) (x - J) + J + transl``; left hands are mirrored, so the
    motion is conjugated by the mirror before it is applied to the mirrored parameters.
    """
    if p.side == "left":
        M = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=R.dtype))
        R_, t_ = M @ R @ M, M @ t
    else:
        R_, t_ = R, t
    go = matrix_to_axis_angle(R_ @ axis_angle_to_matrix(_right(p).global_orient[0]))
    tr = R_ @ (wrist + _right(p).transl[0]) + t_ - wrist
    out = HandParams(go[None], tr[None], _right(p).pose, _right(p).betas, "right")
    if p.side == "left":
        from easyhoi.hand.base import mirror_params

        return mirror_params(out)
    return out


def _right(p: HandParams) -> HandParams:
    from easyhoi.hand.base import mirror_params

    return mirror_params(p) if p.side == "left" else p


def hand_in_camera(params: HandParams, camera: Camera, model: HandModel) -> HandParams:
    """Hand parameters given in ``camera``'s world frame -> the camera's own frame (metres)."""
    wrist = rest_wrist(model, params.betas.to(params.pose.dtype))
    p = params.to(dtype=camera.K.dtype)
    return move_hand(p, camera.R.detach(), camera.t.detach(), wrist.to(camera.K.dtype))


def camera_hand_to_object(
    params_cam: HandParams, camera: Camera, metric_scale: float, model: HandModel
) -> HandParams:
    """Hand in the object camera's frame (metres) -> hand in the metric object frame.

    Object-unit vertices are ``R^T (V_cam / m - t)``; in the metric object frame (times ``m``)
    that is the rigid motion ``x -> R^T x - m R^T t`` of the camera-frame hand.
    """
    wrist = rest_wrist(model, params_cam.betas).to(params_cam.pose.dtype)
    R = camera.R.detach().to(params_cam.pose.dtype)
    t = camera.t.detach().to(params_cam.pose.dtype)
    return move_hand(params_cam, R.T, -metric_scale * (R.T @ t), wrist)


# ------------------------------------------------------------------------------------------------
# small shared utilities
# ------------------------------------------------------------------------------------------------


def phase_sizes(max_iters: int, phases: int) -> list[int]:
    """Split ``max_iters`` into ``phases`` near-equal parts (earlier phases get the remainder)."""
    base, rest = divmod(int(max_iters), phases)
    return [base + (1 if i < rest else 0) for i in range(phases)]


def check_finite_loss(stage: str, terms: dict) -> None:
    """Raise :class:`OptimizationError` naming ``stage`` when a loss term is NaN or infinite."""
    for k, v in terms.items():
        if not math.isfinite(float(v)):
            raise OptimizationError(
                f"stage {stage!r}: loss term {k!r} became {float(v)} (diverged); try a smaller "
                "learning rate or check the input masks and meshes"
            )


def hard_iou(pred: torch.Tensor, target: torch.Tensor) -> float:
    """IoU of two masks thresholded at 0.5."""
    a, b = pred.detach() > 0.5, target.detach() > 0.5
    union = int((a | b).sum())
    return float((a & b).sum()) / union if union else 1.0


class Patience:
    """Early stopping: exhausted once ``patience`` steps pass without a ``min_delta`` gain.

    ``patience = 0`` never stops (the paper preset runs its full schedule).
    """

    def __init__(self, patience: int, min_delta: float):
        self.patience = int(patience)
        self.min_delta = float(min_delta)
        self.reset()

    def reset(self) -> None:
        self.best = math.inf
        self.since_best = 0

    def exhausted(self, value: float) -> bool:
        """Record ``value``; True when the caller should stop."""
        if value < self.best - self.min_delta:
            self.best, self.since_best = value, 0
        else:
            self.since_best += 1
        return bool(self.patience) and self.since_best >= self.patience


class StageLoop:
    """Bookkeeping shared by the stages: history, progress callback, best state, stopping.

    Parameters
    ----------
    name : str
        Stage name (for the callback and errors).
    max_iters : int
        Iteration cap (for the callback).
    history_every : int
        Record every this many iterations.
    progress : callable or None
        ``progress(stage, iteration, max_iters, terms)``.
    """

    def __init__(self, name: str, max_iters: int, history_every: int, progress=None):
        self.name = name
        self.max_iters = max_iters
        self.every = max(1, int(history_every))
        self.progress = progress
        self.history: list[dict] = []
        self.best_score = math.inf
        self.best_state = None
        self.best_iter = -1

    def record(self, it: int, terms: dict, force: bool = False) -> None:
        """Check the terms for NaN; store and report them every ``history_every`` iterations."""
        plain = {k: float(v) for k, v in terms.items()}
        check_finite_loss(self.name, plain)
        if force or it % self.every == 0:
            self.history.append({"iter": int(it), **plain})
            if self.progress is not None:
                self.progress(self.name, int(it), int(self.max_iters), plain)

    def offer(self, score: float, state, it: int) -> bool:
        """Keep ``state`` when ``score`` is the lowest so far; returns True when kept."""
        if score < self.best_score:
            self.best_score, self.best_state, self.best_iter = float(score), state, int(it)
            return True
        return False

    def reset_best(self) -> None:
        self.best_score, self.best_state, self.best_iter = math.inf, None, -1

    @staticmethod
    def step(opt, loss: torch.Tensor) -> None:
        """One optimizer step on ``loss`` (gradients cleared first)."""
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    def restore_best(self, load) -> None:
        """``load(best_state)`` when a state was kept (the stage's variables go back to it)."""
        if self.best_state is not None:
            load(self.best_state)


def early_stop(loss: float, stop_loss: float, patience: Patience, total: float) -> str | None:
    """``"stop_loss"`` once ``loss < stop_loss``, else ``"patience"`` once ``total`` stopped
    improving (:meth:`Patience.exhausted`), else None."""
    if loss < stop_loss:
        return "stop_loss"
    if patience.exhausted(total):
        return "patience"
    return None


def snapshot(tensors) -> tuple[torch.Tensor, ...]:
    """Detached copies of ``tensors``: a state for :meth:`StageLoop.offer`."""
    return tuple(t.detach().clone() for t in tensors)


def restore(tensors, state) -> None:
    """Copy a :func:`snapshot` back into ``tensors`` in place."""
    with torch.no_grad():
        for t, s in zip(tensors, state, strict=True):
            t.copy_(s)
