"""The optimizer's per-run state: object tensors, masks per resolution, SDF, hand model.

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

from easyhoi.errors import InvalidInputError
from easyhoi.hand.base import HandModel
from easyhoi.hand.regions import HandRegions
from easyhoi.hoi import HOIInput
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import DEFAULT_CULL_EPS, cull_margin, soft_silhouette
from easyhoi.structures import Camera

logger = logging.getLogger(__name__)

__all__ = ["SILHOUETTE_SIGMA", "PhotoKeypoints", "Scene", "hard_iou"]

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


@dataclass(frozen=True)
class PhotoKeypoints:
    """The 2D keypoint detector's evidence: 21 keypoints (OpenPose / MANO order, pixels of the
    full photo), per-joint confidences in [0, 1] (1 where the detector gives none) and the
    hand's size in the photo (the larger side of the keypoints' box, pixels)."""

    points: torch.Tensor
    confidence: torch.Tensor
    size: float

    @classmethod
    def from_meta(cls, meta: dict, dtype: torch.dtype, device="cpu") -> PhotoKeypoints | None:
        """From ``meta["keypoints2d"]`` (21 x 2) and optional ``meta["keypoints2d_confidence"]``
        (21,); None when absent. Malformed values raise :class:`InvalidInputError`."""
        raw = (meta or {}).get("keypoints2d")
        if raw is None:
            return None
        pts = np.asarray(raw, dtype=np.float64)
        if pts.shape != (21, 2) or not np.isfinite(pts).all():
            raise InvalidInputError(
                f"meta['keypoints2d'] must be 21 finite (u, v) pixels, got shape {pts.shape}"
            )
        conf = np.asarray(meta.get("keypoints2d_confidence", np.ones(21)), dtype=np.float64)
        if conf.shape != (21,) or not np.isfinite(conf).all() or (conf < 0).any():
            raise InvalidInputError("meta['keypoints2d_confidence'] must be 21 values >= 0")
        size = float(np.ptp(pts, axis=0).max())
        if not size > 0 or not conf.sum() > 0:
            return None
        return cls(
            torch.as_tensor(pts, dtype=dtype, device=device),
            torch.as_tensor(conf, dtype=dtype, device=device),
            size,
        )


@dataclass
class Scene:
    """Everything the stages share for one run (built once by :meth:`from_input`).

    Attributes:
        object_verts ((V_o, 3) tensor): Object vertices in object units (the input mesh, unchanged).
        object_faces: (F_o, 3) long tensor
        watertight (trimesh.Trimesh): A watertight version of the object (the input itself when
            already watertight), used for the SDF and the plausibility metrics.
        center ((3,) tensor): Centre of the object's bounding box (object units).
        extent (float): Largest side of the object's bounding box (object units): one normalised
            unit.
        hand_model: HandModel
        regions: HandRegions
        dtype: torch.dtype
        image_size: (H, W)
        masks (dict of str -> (H, W) tensor): Full-resolution float masks ``hand`` (M_h), ``object``
            (M_o), ``amodal`` (M^_o).
        keypoints (PhotoKeypoints or None): The detector's 2D hand keypoints
            (``HOIInput.meta["keypoints2d"]``), when given.
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
    keypoints: PhotoKeypoints | None = None
    _mask_cache: dict = field(default_factory=dict, repr=False)
    _sdf_cache: dict = field(default_factory=dict, repr=False)
    _depth_cache: dict = field(default_factory=dict, repr=False)
    _axes: torch.Tensor | None = field(default=None, repr=False)

    @classmethod
    def from_input(
        cls, inp: HOIInput, hand_model: HandModel, dtype: torch.dtype, device="cpu"
    ) -> Scene:
        """Build the shared state of one run from an :class:`HOIInput`, its tensors on
        ``device`` (``hand_model`` must already be there: :meth:`HandModel.on_device`)."""
        mesh = inp.object_mesh
        if mesh.is_watertight:
            wt = mesh
        else:
            from easyhoi.geometry.watertight import make_watertight

            logger.info("object mesh is not watertight: repairing it for the SDF and metrics")
            wt, _ = make_watertight(mesh)
        v = torch.as_tensor(np.asarray(mesh.vertices), dtype=dtype, device=device)
        lo, hi = v.min(0).values, v.max(0).values
        extent = float((hi - lo).max())
        if not extent > 0:
            raise InvalidInputError("object mesh is degenerate (zero extent)")
        masks = {
            "hand": torch.from_numpy(np.array(inp.hand_mask)).to(device, dtype),
            "object": torch.from_numpy(np.array(inp.object_mask)).to(device, dtype),
            "amodal": torch.from_numpy(np.array(inp.amodal_mask)).to(device, dtype),
        }
        return cls(
            object_verts=v,
            object_faces=torch.as_tensor(np.asarray(mesh.faces), dtype=torch.long, device=device),
            watertight=wt,
            center=0.5 * (lo + hi),
            extent=extent,
            hand_model=hand_model,
            regions=hand_model.regions,
            dtype=dtype,
            image_size=inp.size,
            masks=masks,
            keypoints=PhotoKeypoints.from_meta(inp.meta, dtype, device),
        )

    def flexion_axes(self) -> torch.Tensor:
        """(15, 3) flexion axes of the hand model's joints (:func:`~easyhoi.hand.regions.
        flexion_axes`, cached)."""
        if self._axes is None:
            from easyhoi.hand.regions import flexion_axes

            self._axes = torch.as_tensor(
                flexion_axes(self.hand_model), dtype=self.dtype, device=self.device
            )
        return self._axes

    @property
    def device(self) -> torch.device:
        """Where every tensor of the run lives."""
        return self.object_verts.device

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
            ).to(device=self.device)  # fmt: skip
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

        Args:
            hand_verts ((V, 3) tensor): Hand vertices in object units.
            camera (Camera): Object camera at the render resolution.

        Returns:
            hand: (h, w) complete soft silhouette; visible : (h, w); hand_depth : (h, w) no grad.
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


def hard_iou(pred: torch.Tensor, target: torch.Tensor) -> float:
    """IoU of two masks thresholded at 0.5."""
    a, b = pred.detach() > 0.5, target.detach() > 0.5
    union = int((a | b).sum())
    return float((a & b).sum()) / union if union else 1.0
