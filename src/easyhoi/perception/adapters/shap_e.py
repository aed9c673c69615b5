"""Object mesh from Shap-E image-to-3D (diffusers ``ShapEImg2ImgPipeline``, local folder).

The paper gets its object shapes from an image-to-3D model; this adapter runs one for users who
have the weights (``openai/shap-e-img2img`` saved with ``save_pretrained`` or a downloaded
snapshot). Input: the hand-removed (inpainted) photo cropped square around the amodal mask, white
outside it (:func:`~easyhoi.perception.objects.object_crop`): one object on a plain background,
as Shap-E was trained. The pipeline returns Shap-E's latent; the latent sets the weights of the
renderer's implicit network (as diffusers' own mesh decoding does), its signed distance is
sampled on a ``grid`` ^ 3 lattice over the renderer's volume and the surface (positive inside)
is extracted by marching cubes (scikit-image), then closed with
:func:`~easyhoi.geometry.watertight.make_watertight` when it is not.

Placement, as the offline mesh: Shap-E's meshes are z-up; they are turned into the camera frame
(x right, y down, z away from the camera) by ``(x, y, z) -> (x, -z, y)``, so the object stands
as it was generated; its azimuth about the up axis is left to the optimizer's rotation. The mesh
is scaled and centred so that its orthographic outline's bounding box matches the amodal mask's
(``pixels_per_unit``, ``center_px`` in the metadata), and with hand keypoints it gets the same
metric size as the offline route (``meters_per_unit``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.perception.adapters import check_bool_mask, check_image, resolve_model_dir
from easyhoi.perception.base import register

#: Shap-E's z-up frame -> the camera frame (x right, y down, z away): (x, y, z) -> (x, -z, y).
TO_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@register("object", "shap-e")
class ShapEObjectReconstructor:
    """:class:`~easyhoi.perception.base.ObjectReconstructor` backed by Shap-E image-to-3D.

    Args:
        model_dir: local folder of a diffusers ``ShapEImg2ImgPipeline`` (``model_index.json``).
        steps: diffusion steps (64 in Shap-E's examples).
        guidance_scale: classifier-free guidance (3.0 in Shap-E's examples).
        grid: signed-distance lattice size per axis (>= 16).
        seed: seed of the diffusion noise (same photo + seed -> same mesh).
        device: torch device string.
    """

    def __init__(
        self,
        model_dir: str | Path | None = None,
        steps: int = 64,
        guidance_scale: float = 3.0,
        grid: int = 96,
        seed: int = 0,
        device: str = "cpu",
    ):
        dif = require("diffusers", extra="diffusion", purpose="Shap-E image-to-3D object meshes")
        if steps < 1 or grid < 16:
            raise InvalidInputError(f"need steps >= 1 and grid >= 16, got {steps}, {grid}")
        folder = resolve_model_dir(model_dir, "Shap-E", marker="model_index.json")
        try:
            self.pipe = dif.ShapEImg2ImgPipeline.from_pretrained(folder, local_files_only=True)
        except (OSError, ValueError) as exc:
            msg = f"could not load the Shap-E pipeline from '{folder}': {exc}"
            raise BackendError(msg) from exc
        self.pipe.to(device)
        self.pipe.set_progress_bar_config(disable=True)
        self.steps, self.guidance_scale, self.grid = int(steps), float(guidance_scale), int(grid)
        self.seed, self.device = int(seed), device

    def latent(self, crop_image: np.ndarray):
        """Shap-E's latent (1, ...) of an (S, S, 3) uint8 object crop."""
        import torch
        from PIL import Image

        gen = torch.Generator(device="cpu").manual_seed(self.seed)
        with torch.no_grad():
            out = self.pipe(
                Image.fromarray(crop_image), num_inference_steps=self.steps,
                guidance_scale=self.guidance_scale, output_type="latent", generator=gen,
            )  # fmt: skip
        return out.images[:1]

    def signed_distance(self, latent) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(grid, grid, grid) signed distance (positive inside), volume min and max corners."""
        import torch

        r = self.pipe.shap_e_renderer
        with torch.no_grad():
            params = r.params_proj(latent)
            for name, prm in r.mlp.state_dict().items():
                if f"nerstf.{name}" in params:
                    prm.copy_(params[f"nerstf.{name}"].squeeze(0))
            lo = r.volume.bbox_min.detach().cpu().double().reshape(3)
            hi = r.volume.bbox_max.detach().cpu().double().reshape(3)
            axes = [torch.linspace(float(lo[i]), float(hi[i]), self.grid) for i in range(3)]
            pts = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(1, -1, 3)
            pts = pts.to(device=self.device, dtype=r.mlp.dtype)
            vals = [r.mlp(position=pts[:, i : i + 32768], direction=None, ts=None,
                          nerf_level="fine", rendering_mode="stf").signed_distance
                    for i in range(0, pts.shape[1], 32768)]  # fmt: skip
        sdf = torch.cat(vals, dim=1).float().cpu().numpy().reshape((self.grid,) * 3)
        return sdf, lo.numpy(), hi.numpy()

    def generate(self, crop_image: np.ndarray) -> trimesh.Trimesh:
        """Shap-E mesh (its own frame) of an (S, S, 3) uint8 object crop."""
        from skimage.measure import marching_cubes

        sdf, lo, hi = self.signed_distance(self.latent(crop_image))
        if not (sdf.max() > 0 > sdf.min()):
            raise BackendError("Shap-E produced an empty shape for this object crop")
        padded = np.pad(sdf, 1, constant_values=-1.0)  # closed at the volume's border
        step = (hi - lo) / (self.grid - 1)
        verts, faces, _, _ = marching_cubes(padded, level=0.0, spacing=tuple(step))
        verts = verts - step + lo
        mesh = trimesh.Trimesh(verts, faces[:, ::-1], process=True)  # outward for +inside
        if mesh.volume < 0:
            mesh.invert()
        return mesh

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
        """Watertight mesh of the masked object, placed as the offline mesh (module docs)."""
        from easyhoi.geometry.watertight import make_watertight
        from easyhoi.perception.objects import canonical_mesh, object_crop
        from easyhoi.perception.shapes import hand_cues

        img = check_image(image)
        m = check_bool_mask(mask, img.shape[:2], "object mask")
        occ = None if hand_mask is None else check_bool_mask(hand_mask, m.shape, "hand mask")
        raw = self.generate(object_crop(img, m).image)
        if not raw.is_watertight:
            raw, _ = make_watertight(raw)
        v = np.asarray(raw.vertices) @ TO_CAMERA.T
        rows, cols = np.nonzero(m)
        u0, u1, v0, v1 = cols.min(), cols.max() + 1.0, rows.min(), rows.max() + 1.0
        lo, hi = v.min(0), v.max(0)
        span = np.maximum(hi[:2] - lo[:2], 1e-9)
        s = float(np.sqrt((u1 - u0) / span[0] * (v1 - v0) / span[1]))  # pixels per Shap-E unit
        px = (v - 0.5 * (lo + hi)) * s + np.array([0.5 * (u0 + u1), 0.5 * (v0 + v1), 0.0])
        mesh = canonical_mesh(px, np.asarray(raw.faces), dict(method="shap-e"))
        cues = hand_cues(hand_keypoints2d, hand_keypoints3d, m, occ)
        if cues is not None:
            md = mesh.metadata["easyhoi"]
            md["hand_cues"] = cues.to_dict()
            md["meters_per_unit"] = md["pixels_per_unit"] / cues.px_per_m
            md["grip_depth_m"] = cues.grip_depth_m
        return mesh
