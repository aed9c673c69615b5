"""Hand removal by classical inpainting (offline stand-in for the paper's GLIDE inpainter).

The hand mask is dilated by ``dilate_px`` (so the hand's blurred edge and shadow go too) and
filled with OpenCV's fast-marching method (Telea 2004). Large holes are filled at a reduced
resolution (``work_side``) and upsampled, which is both faster and smoother; the known pixels are
copied back unchanged at full resolution.
"""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.io.image import check_image
from easyhoi.perception.base import register
from easyhoi.perception.masks import check_mask


@register("inpainter", "opencv")
class OpenCVInpainter:
    """Telea inpainting of a dilated mask.

    Args:
        dilate_px (int): Dilation of the mask before filling, in pixels of the input image (>= 0).
        radius (float): Telea neighbourhood radius in working pixels.
        work_side (int): The fill is computed on the image downscaled so its longer side is at most
            this.
        method (str): ``"telea"`` or ``"ns"`` (Navier-Stokes).
    """

    def __init__(
        self, dilate_px: int = 7, radius: float = 5.0, work_side: int = 512, method: str = "telea"
    ):
        if dilate_px < 0:
            raise InvalidInputError(f"dilate_px must be >= 0, got {dilate_px}")
        if method not in ("telea", "ns"):
            raise InvalidInputError(f"method must be 'telea' or 'ns', got {method!r}")
        self.dilate_px = int(dilate_px)
        self.radius = float(radius)
        self.work_side = int(work_side)
        self.flag = cv2.INPAINT_TELEA if method == "telea" else cv2.INPAINT_NS

    def inpaint(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB ``image`` with the (H, W) bool ``mask`` region filled."""
        image = check_image(image)
        mask = check_mask(mask, image.shape[:2], "inpainting mask")
        if not mask.any():
            return image.copy()
        m = mask.astype(np.uint8)
        if self.dilate_px > 0:
            k = 2 * self.dilate_px + 1
            m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        H, W = m.shape
        s = min(1.0, self.work_side / max(H, W))
        if s < 1.0:
            size = (max(1, round(W * s)), max(1, round(H * s)))
            small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
            ms = (cv2.resize(m, size, interpolation=cv2.INTER_AREA) > 0).astype(np.uint8)
            filled = cv2.inpaint(small, ms, self.radius, self.flag)
            filled = cv2.resize(filled, (W, H), interpolation=cv2.INTER_CUBIC)
        else:
            filled = cv2.inpaint(image, m, self.radius, self.flag)
        out = image.copy()
        out[m > 0] = filled[m > 0]
        return out
