"""SAM (Segment Anything) amodal re-segmentation through transformers, from a local folder.

The paper's prompts (method step 2.1.4): positive points inside every sub-mask of the visible
object mask (the hand splits the object into parts) and a box that loosely covers it.
:func:`prompts_from_mask` builds them; :class:`SamAmodalSegmenter` runs SAM with all of them
at once, asks for its three candidate masks and keeps the one with the highest predicted IoU,
resized to the image.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.perception.adapters import check_bool_mask, check_image, resolve_model_dir
from easyhoi.perception.base import register


def prompts_from_mask(
    visible_mask: np.ndarray, margin: float = 0.1, min_pixels: int = 20
) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Point and box prompts from the visible object mask.

    Args:
        visible_mask: (H, W) bool.
        margin: the box is the mask's bounding box grown by ``margin`` x its size on each side,
            clipped to the image.
        min_pixels: components smaller than this get no point (specks).

    Returns:
        points: (N, 2) float (u, v) pixel centres, one per component: its most interior pixel
            (maximum of the distance transform; ties broken by raster order, deterministic).
        box: (u0, v0, u1, v1) float.
    """
    m = np.asarray(visible_mask).astype(bool)
    if m.ndim != 2 or not m.any():
        raise InvalidInputError("visible mask must be a non-empty (H, W) mask")
    labels, n = ndimage.label(m)
    dist = ndimage.distance_transform_edt(m)
    points = []
    for k in range(1, n + 1):
        comp = labels == k
        if comp.sum() < min_pixels and points:
            continue
        flat = np.argmax(np.where(comp, dist, -1.0))
        i, j = np.unravel_index(flat, m.shape)
        points.append((j + 0.5, i + 0.5))
    rows, cols = np.nonzero(m)
    H, W = m.shape
    u0, u1, v0, v1 = cols.min(), cols.max() + 1.0, rows.min(), rows.max() + 1.0
    du, dv = margin * (u1 - u0), margin * (v1 - v0)
    box = (max(0.0, u0 - du), max(0.0, v0 - dv), min(float(W), u1 + du), min(float(H), v1 + dv))
    return np.asarray(points, dtype=np.float64), box


@register("amodal", "sam")
class SamAmodalSegmenter:
    """SAM prompted by points + box (:class:`~easyhoi.perception.base.AmodalSegmenter`).

    Args:
        model_dir: local folder with a SAM checkpoint in transformers format (``config.json``,
            weights and the processor config), e.g. a saved ``facebook/sam-vit-base``.
        device: torch device string; "cpu" by default.

    Attributes:
        last_scores: (3,) predicted IoU of the candidates of the latest call.
    """

    def __init__(self, model_dir: str | Path | None = None, device: str = "cpu"):
        tf = require("transformers", extra="sam", purpose="SAM amodal segmentation")
        import torch

        folder = resolve_model_dir(model_dir, "SAM", marker="config.json")
        try:
            self.processor = tf.SamProcessor.from_pretrained(folder, local_files_only=True)
            self.model = tf.SamModel.from_pretrained(folder, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise BackendError(f"could not load SAM from '{folder}': {exc}") from exc
        self.model.eval().to(device)
        self.device = torch.device(device)
        self.last_scores: np.ndarray | None = None
        self._embedding = None  # (image key, embedding) of the latest photo

    def segment(
        self,
        image: np.ndarray,
        points: np.ndarray | None,
        box: tuple[float, float, float, float] | None,
        visible_mask: np.ndarray,
    ) -> np.ndarray:
        """(H, W) bool amodal mask.

        Args:
            image: (H, W, 3) uint8, the inpainted photo.
            points: (N, 2) (u, v) positive points, or None to derive them (and the box) from
                ``visible_mask`` with :func:`prompts_from_mask`.
            box: (u0, v0, u1, v1) or None (derived likewise).
            visible_mask: (H, W) bool visible object mask.
        """
        img = check_image(image)
        H, W = img.shape[:2]
        vis = check_bool_mask(visible_mask, (H, W), "visible object mask")
        if points is None or box is None:
            auto_pts, auto_box = prompts_from_mask(vis)
            points = auto_pts if points is None else points
            box = auto_box if box is None else box
        return self.predict(img, points, box)

    def predict(
        self,
        image: np.ndarray,
        points: np.ndarray | None,
        box: tuple[float, float, float, float] | None = None,
        negative: np.ndarray | None = None,
    ) -> np.ndarray:
        """(H, W) bool: the best of SAM's three masks for positive ``points`` and/or a ``box``
        (and ``negative`` points: (M, 2) (u, v) pixels that are not the object).

        The image embedding of the latest photo is kept, so prompting the same photo again
        costs only the mask decoder.
        """
        import hashlib

        import torch

        img = check_image(image)
        H, W = img.shape[:2]
        pts = np.zeros((0, 2)) if points is None else np.asarray(points, np.float64).reshape(-1, 2)
        neg = np.zeros((0, 2)) if negative is None else np.asarray(negative, np.float64)
        neg = neg.reshape(-1, 2)
        if not np.isfinite(pts).all() or (len(pts) == 0 and box is None):
            raise InvalidInputError("SAM needs finite (u, v) point prompts, a box, or both")
        if not np.isfinite(neg).all():
            raise InvalidInputError("SAM needs finite (u, v) negative points")
        kw = {}
        if len(pts) or len(neg):
            allp = np.concatenate([pts, neg])
            labels = [1] * len(pts) + [0] * len(neg)
            kw.update(input_points=[[allp.tolist()]], input_labels=[[labels]])
        if box is not None:
            b = [float(x) for x in np.asarray(box, dtype=np.float64).reshape(4)]
            if not (b[0] < b[2] and b[1] < b[3]):
                raise InvalidInputError(f"box must be (u0, v0, u1, v1) with u0 < u1, v0 < v1: {b}")
            kw["input_boxes"] = [[b]]
        inputs = self.processor(images=img, return_tensors="pt", **kw)
        sizes = (inputs.pop("original_sizes"), inputs.pop("reshaped_input_sizes"))
        pixels = inputs.pop("pixel_values")
        inputs = {k: v.to(self.device) for k, v in inputs.items()}
        key = (img.shape, hashlib.sha1(img.tobytes()).hexdigest())
        with torch.no_grad():
            if self._embedding is None or self._embedding[0] != key:
                emb = self.model.get_image_embeddings(pixels.to(self.device))
                self._embedding = (key, emb)
            out = self.model(image_embeddings=self._embedding[1], multimask_output=True, **inputs)
        masks = self.processor.image_processor.post_process_masks(
            out.pred_masks.cpu(), sizes[0], sizes[1]
        )[0][0]  # (C, H, W)
        scores = out.iou_scores[0, 0].float().cpu().numpy()
        self.last_scores = scores
        mask = masks[int(np.argmax(scores))].numpy().astype(bool)
        if mask.shape != (H, W):
            raise BackendError(f"SAM returned a {mask.shape} mask for a {H}x{W} image")
        return mask
