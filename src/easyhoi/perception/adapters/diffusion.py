"""Hand removal with a text-guided diffusion inpainting pipeline (diffusers, local folder).

Method step 2.1.3: the (dilated) hand region is inpainted with a prompt asking to remove the hand
and complete the object; the reference uses GLIDE at 256 px with guidance 5. Any diffusers
inpainting pipeline saved in a folder works (``AutoPipelineForInpainting``: Stable Diffusion
inpainting, Kandinsky, ...). The photo is resized so its longer side is ``resolution`` (sides
rounded to what the pipeline accepts), inpainted with a seeded generator on the CPU, resized
back, and pasted so that pixels outside the mask are exactly the input's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.perception.adapters import check_bool_mask, check_image, resolve_model_dir
from easyhoi.perception.base import register

DEFAULT_PROMPT = (
    "the whole object alone, the hand removed, the hidden part of the object completed, "
    "same lighting and background"
)
DEFAULT_NEGATIVE_PROMPT = "hand, fingers, arm, person"


@register("inpainter", "diffusion")
class DiffusionInpainter:
    """:class:`~easyhoi.perception.base.Inpainter` backed by a diffusers pipeline.

    Args:
        model_dir: local folder written by ``pipeline.save_pretrained`` (``model_index.json``).
        prompt, negative_prompt: text guidance.
        guidance_scale: classifier-free guidance (5, as the paper).
        steps: denoising steps.
        resolution: longer side of the working image, pixels.
        dilate: extra dilation of the mask in pixels (0 when the caller already dilated it).
        seed: generator seed; same input + seed -> same output.
        device: torch device string.
    """

    def __init__(
        self,
        model_dir: str | Path | None = None,
        prompt: str = DEFAULT_PROMPT,
        negative_prompt: str | None = DEFAULT_NEGATIVE_PROMPT,
        guidance_scale: float = 5.0,
        steps: int = 25,
        resolution: int = 512,
        dilate: int = 0,
        seed: int = 0,
        device: str = "cpu",
    ):
        diffusers = require("diffusers", extra="diffusion", purpose="diffusion inpainting")
        require("transformers", extra="diffusion", purpose="the inpainting text encoder")
        if steps < 1 or resolution < 8 or dilate < 0:
            raise InvalidInputError(
                f"need steps >= 1, resolution >= 8, dilate >= 0; got {steps}, {resolution}, "
                f"{dilate}"
            )
        folder = resolve_model_dir(model_dir, "inpainting", marker="model_index.json")
        try:
            self.pipe = diffusers.AutoPipelineForInpainting.from_pretrained(
                folder, local_files_only=True, safety_checker=None
            )
        except (OSError, ValueError) as exc:
            raise BackendError(f"could not load the inpainting pipeline: {exc}") from exc
        self.pipe.to(device)
        self.pipe.set_progress_bar_config(disable=True)
        self.device = device
        self.prompt, self.negative_prompt = prompt, negative_prompt
        self.guidance_scale, self.steps = float(guidance_scale), int(steps)
        self.resolution, self.dilate, self.seed = int(resolution), int(dilate), int(seed)

    @property
    def size_multiple(self) -> int:
        """Working sizes are multiples of this (VAE factor x UNet down-sampling)."""
        vae = getattr(self.pipe, "vae_scale_factor", 8)
        unet = getattr(self.pipe, "unet", None)
        blocks = len(unet.config.block_out_channels) if unet is not None else 1
        return int(vae) * 2 ** max(blocks - 1, 0)

    def working_size(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) of the working image: longer side ~ ``resolution``."""
        k = self.size_multiple
        s = self.resolution / max(width, height)
        return (max(k, int(round(width * s / k)) * k), max(k, int(round(height * s / k)) * k))

    def inpaint(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 ``image`` with the (H, W) bool ``mask`` region regenerated."""
        import torch
        from PIL import Image
        from scipy import ndimage

        img = check_image(image)
        H, W = img.shape[:2]
        m = check_bool_mask(mask, (H, W), "inpainting mask")
        if self.dilate:
            m = ndimage.binary_dilation(m, iterations=self.dilate)
        if not m.any():
            return img.copy()
        w, h = self.working_size(W, H)
        pil = Image.fromarray(img).resize((w, h), Image.BICUBIC)
        pil_m = Image.fromarray(m.astype(np.uint8) * 255).resize((w, h), Image.NEAREST)
        gen = torch.Generator(device="cpu").manual_seed(self.seed)
        with torch.no_grad():
            out = self.pipe(
                prompt=self.prompt,
                negative_prompt=self.negative_prompt,
                image=pil,
                mask_image=pil_m,
                guidance_scale=self.guidance_scale,
                num_inference_steps=self.steps,
                generator=gen,
                height=h,
                width=w,
                output_type="np",
            ).images
        arr = np.asarray(out[0] if len(out) else out, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[2] != 3 or not np.isfinite(arr).all():
            raise BackendError(f"the inpainting pipeline returned an unusable image {arr.shape}")
        gen_img = Image.fromarray(np.clip(arr * 255 + 0.5, 0, 255).astype(np.uint8))
        gen_img = np.asarray(gen_img.resize((W, H), Image.BICUBIC))
        result = img.copy()
        result[m] = gen_img[m]
        return result
