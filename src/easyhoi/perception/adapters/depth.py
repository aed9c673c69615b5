"""Object mesh from a monocular depth model (transformers, local folder) and the silhouette.

:class:`DepthObjectReconstructor` runs the shape hypotheses of :mod:`easyhoi.perception.shapes`
with the depth map's front relief as one more piece of evidence (a cylinder's front bulges, a
slab's is flat), and refines the fallback: when no parametric family wins, the mesh is the
relief mesh of :func:`relief_mesh` below. ``metadata["easyhoi"]["method"]`` is ``"depth"``;
``metadata["easyhoi"]["shape"]`` records the family that won (``"relief"`` for the refinement).

Relief mesh: the model (``AutoModelForDepthEstimation``: DPT, Depth Anything, ...) gives the
visible front surface ``F(u, v)`` inside the mask, up to scale and shift. The back is not seen;
it is the reflection of the front about the mid-surface ``F + h``, where ``h = sqrt(d (2R - d))``
is the silhouette-width half-thickness of
:func:`~easyhoi.perception.objects.half_thickness_sq` (``d`` = distance to the contour, ``R`` =
local half-width). So the back is ``F + 2h``, both surfaces meet on the contour, and the solid
``{ |z - (F + h)| <= h }`` is extracted as one closed mesh by marching cubes. A disk with a
spherical front gives a sphere; a flat front gives the pure inflation.

Scale: relative depth has no unit. By default the front relief (5th-95th percentile range inside
the mask) is set to ``relief`` x the silhouette's largest half-width; pass ``depth_scale``
(pixels per model unit) to use the model's values as they are. Frame and metadata as
:class:`~easyhoi.perception.objects.SilhouetteReconstructor` (x right, y down, z away from the
camera, unit max extent).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.perception.adapters import check_bool_mask, check_image, resolve_model_dir
from easyhoi.perception.base import register
from easyhoi.perception.objects import (
    canonical_mesh,
    half_thickness_sq,
    implicit_slab_mesh,
    signed_distance_2d,
)

OUTPUT_KINDS = ("disparity", "depth")


def relief_mesh(
    mask: np.ndarray,
    prediction: np.ndarray,
    kind: str = "disparity",
    relief: float = 1.0,
    depth_scale: float | None = None,
    max_faces: int = 8000,
) -> trimesh.Trimesh:
    """Closed mesh from a front-surface prediction and the silhouette (see module docs).

    Args:
        mask: (H, W) bool object mask (>= 16 pixels).
        prediction: (H, W) float model output; "disparity" (larger = closer, what DPT and Depth
            Anything predict) or "depth" (larger = farther).
        relief: front relief range as a fraction of the largest half-width (auto scale).
        depth_scale: pixels per model unit; overrides the automatic scale when given.
        max_faces: face budget.

    Returns:
        trimesh.Trimesh, watertight, canonical frame, ``metadata["easyhoi"]["method"] == "depth"``.
    """
    m = np.asarray(mask).astype(bool)
    pred = np.asarray(prediction, dtype=np.float64)
    if pred.shape != m.shape:
        raise InvalidInputError(f"prediction is {pred.shape} but the mask is {m.shape}")
    if kind not in OUTPUT_KINDS:
        raise InvalidInputError(f"kind must be one of {OUTPUT_KINDS}, got {kind!r}")
    if m.sum() < 16:
        raise InvalidInputError(f"object mask has {int(m.sum())} pixels; at least 16 are needed")
    if not np.isfinite(pred[m]).all():
        raise InvalidInputError("depth prediction has NaN or infinite values inside the mask")
    z = pred if kind == "depth" else -pred
    z = z - np.median(z[m])
    if depth_scale is not None:
        if not (np.isfinite(depth_scale) and depth_scale > 0):
            raise InvalidInputError(f"depth_scale must be > 0, got {depth_scale}")
        front = z * float(depth_scale)
    else:
        lo, hi = np.percentile(z[m], [5, 95])
        span = hi - lo
        rmax = float(signed_distance_2d(m).max())
        front = z * (relief * rmax / span) if span > 1e-12 else np.zeros_like(z)
    # extend the front outside the mask with the nearest inside value (continuous field)
    _, (ri, ci) = ndimage.distance_transform_edt(~m, return_indices=True)
    front = front[ri, ci]
    h2 = half_thickness_sq(m)
    mid = front + np.sqrt(np.maximum(h2, 0.0))
    verts, faces = implicit_slab_mesh(m, h2, mid=mid, max_faces=max_faces)
    return canonical_mesh(verts, faces, dict(method="depth", kind=kind))


@register("object", "depth")
class DepthObjectReconstructor:
    """:class:`~easyhoi.perception.base.ObjectReconstructor` from a monocular depth model.

    Args:
        model_dir: local folder with a transformers depth-estimation checkpoint and its image
            processor (``config.json``, weights, ``preprocessor_config.json``).
        output: "disparity" (default: DPT, Depth Anything) or "depth" (metric models).
        relief, depth_scale, max_faces: see :func:`relief_mesh`.
        device: torch device string.
    """

    def __init__(
        self,
        model_dir: str | Path | None = None,
        output: str = "disparity",
        relief: float = 1.0,
        depth_scale: float | None = None,
        max_faces: int = 8000,
        device: str = "cpu",
    ):
        tf = require("transformers", extra="depth", purpose="monocular depth object meshes")
        import torch

        if output not in OUTPUT_KINDS:
            raise InvalidInputError(f"output must be one of {OUTPUT_KINDS}, got {output!r}")
        folder = resolve_model_dir(model_dir, "depth", marker="config.json")
        try:
            self.processor = tf.AutoImageProcessor.from_pretrained(folder, local_files_only=True)
            self.model = tf.AutoModelForDepthEstimation.from_pretrained(
                folder, local_files_only=True
            )
        except (OSError, ValueError) as exc:
            raise BackendError(f"could not load the depth model from '{folder}': {exc}") from exc
        self.model.eval().to(device)
        self.device = torch.device(device)
        self.output, self.relief, self.depth_scale = output, float(relief), depth_scale
        self.max_faces = int(max_faces)

    def predict(self, image: np.ndarray) -> np.ndarray:
        """(H, W) float32 model output, bilinearly resized to the image."""
        import torch

        img = check_image(image)
        inputs = {k: v.to(self.device) for k, v in self.processor(images=img,
                  return_tensors="pt").items()}  # fmt: skip
        with torch.no_grad():
            pred = self.model(**inputs).predicted_depth  # (1, h, w)
        pred = torch.nn.functional.interpolate(
            pred[:, None].float(), size=img.shape[:2], mode="bilinear", align_corners=False
        )[0, 0]
        return pred.cpu().numpy()

    def reconstruct(
        self,
        image: np.ndarray,
        mask: np.ndarray,
        *,
        visible_mask: np.ndarray | None = None,
        hand_mask: np.ndarray | None = None,
        hand_keypoints2d: np.ndarray | None = None,
        hand_keypoints3d: np.ndarray | None = None,
    ) -> trimesh.Trimesh:
        """Watertight mesh of the masked object (canonical frame, see module docs).

        The shape hypotheses of :mod:`easyhoi.perception.shapes` compete with the depth map's
        front relief as extra evidence; when none of the parametric families wins (the
        fallback, inflation), the relief mesh refines it: front from the depth map, back
        mirrored. The hand arguments are those of
        :meth:`~easyhoi.perception.objects.SilhouetteReconstructor.reconstruct`.
        """
        from easyhoi.perception.objects import shape_mesh

        img = check_image(image)
        m = check_bool_mask(mask, img.shape[:2], "object mask")
        pred = self.predict(img)
        z = pred if self.output == "depth" else -pred
        mesh = shape_mesh(m, img, None, visible_mask, hand_mask, hand_keypoints2d,
                          hand_keypoints3d, front=z, method="depth")  # fmt: skip
        md = mesh.metadata["easyhoi"]
        if md["shape"]["shape"] != "inflation":
            return mesh
        relief = relief_mesh(m, pred, self.output, self.relief, self.depth_scale, self.max_faces)
        rmd = relief.metadata["easyhoi"]
        rmd["shape"] = dict(md["shape"], shape="relief")
        for key in ("hand_cues", "grip_depth_m"):
            if key in md:
                rmd[key] = md[key]
        if "meters_per_unit" in md:
            rmd["meters_per_unit"] = rmd["pixels_per_unit"] * md["meters_per_unit"] / md[
                "pixels_per_unit"]  # fmt: skip
        return relief
