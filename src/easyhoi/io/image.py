"""Robust photo and mask loading.

Photos are decoded by their content (Pillow sniffs the format), never by the file extension, so a
WebP file named ``.jpg`` loads. EXIF orientation is applied, every pixel format is converted to
8-bit RGB, and photos larger than ``max_side`` are downscaled (area-averaging) so that the
perception chain runs in bounded time; :attr:`LoadedImage.scale` records the factor so that
pixel coordinates can be mapped back to the original file (``u_original = u / scale``).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from easyhoi.errors import InvalidInputError

logger = logging.getLogger(__name__)

#: Smallest accepted photo side in pixels; smaller images carry no usable hand.
MIN_SIDE = 32


@dataclass(frozen=True)
class LoadedImage:
    """A decoded photo.

    Attributes:
        rgb: (H, W, 3) uint8 RGB pixels after orientation, conversion and downscaling.
        original_size: (width, height) of the decoded photo after EXIF orientation, before
            downscaling.
        scale: factor applied to the original (<= 1); ``rgb`` is ``original * scale``.
        source_format: container format as detected from the content (``"JPEG"``, ``"WEBP"``...).
        path: the file it came from.
    """

    rgb: np.ndarray
    original_size: tuple[int, int]
    scale: float
    source_format: str
    path: str = ""

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of :attr:`rgb`."""
        return int(self.rgb.shape[1]), int(self.rgb.shape[0])


def check_image(image: np.ndarray, name: str = "image") -> np.ndarray:
    """Validate an (H, W, 3) uint8 RGB image and return it C-contiguous."""
    if not isinstance(image, np.ndarray):
        raise InvalidInputError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise InvalidInputError(f"{name} must have shape (H, W, 3), got {tuple(image.shape)}")
    if image.dtype != np.uint8:
        raise InvalidInputError(f"{name} must be uint8, got {image.dtype}")
    if min(image.shape[:2]) < 32:
        raise InvalidInputError(f"{name} must be at least 32x32, got {image.shape[:2]}")
    return np.ascontiguousarray(image)


def _open(path: str | Path):
    from PIL import Image

    from easyhoi.limits import check_image_header, unreadable_image_error

    p = Path(path)
    check_image_header(p)  # missing, empty, too many bytes or pixels: refused before decoding
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(p)
            img.load()
    except (OSError, SyntaxError, ValueError) as exc:
        raise unreadable_image_error(p, exc) from exc
    return img


def _to_uint8_array(img) -> np.ndarray:
    """Any Pillow mode -> (H, W) or (H, W, C) uint8 array (16-bit and float rescaled)."""
    arr = np.asarray(img)
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype == bool:
        return arr.astype(np.uint8) * 255
    if np.issubdtype(arr.dtype, np.integer):
        # 16-bit (I;16) or 32-bit (I) images: scale by the container's range when the data use
        # it, otherwise by the data's own maximum (many "I" images hold 16-bit values).
        hi = 65535.0 if arr.max() > 255 else 255.0
        if arr.max() > 65535:
            hi = float(arr.max())
        return np.clip(arr.astype(np.float64) * (255.0 / hi) + 0.5, 0, 255).astype(np.uint8)
    arr = arr.astype(np.float64)
    if arr.max() > 1.0:
        arr = arr / arr.max()
    return np.clip(arr * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _to_rgb(img) -> np.ndarray:
    """Pillow image of any mode -> (H, W, 3) uint8 RGB; alpha composited on white."""
    mode = img.mode
    if mode in ("RGBA", "LA", "PA") or (mode == "P" and "transparency" in img.info):
        rgba = np.asarray(img.convert("RGBA")).astype(np.float64)
        alpha = rgba[..., 3:4] / 255.0
        rgb = rgba[..., :3] * alpha + 255.0 * (1.0 - alpha)
        return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
    if mode in ("RGB",):
        return np.asarray(img)
    if mode in ("I;16", "I;16B", "I;16L", "I", "F", "1", "L"):
        gray = _to_uint8_array(img)
        return np.repeat(gray[..., None], 3, axis=2)
    return np.asarray(img.convert("RGB"))


def load_image(path: str | Path, max_side: int | None = 1600) -> LoadedImage:
    """Load a photo as 8-bit RGB.

    Args:
        path (str or Path): Photo file; the format is detected from the content, not the extension.
        max_side (int or None): Photos whose longer side exceeds this are downscaled (aspect kept,
            area interpolation) so that the longer side equals ``max_side``; None keeps the full
            resolution.

    Returns:
        LoadedImage: ``rgb`` is (H, W, 3) uint8.

    Raises:
        InvalidInputError: Missing, empty, corrupt or unsupported files, and photos with a side < 32
            px.
    """
    from PIL import Image, ImageOps

    img = _open(path)
    fmt = str(img.format or "unknown")
    try:
        ImageOps.exif_transpose(img, in_place=True)  # no copy of an upright photo
    except Exception as exc:  # malformed EXIF must not make a readable photo unusable
        logger.warning("ignoring unreadable EXIF orientation of %s: %s", path, exc)
    w, h = img.size
    if min(h, w) < MIN_SIDE:
        raise InvalidInputError(
            f"image {path} is {w}x{h} pixels; at least {MIN_SIDE} px per side are needed"
        )
    if max_side is not None and max_side < MIN_SIDE:
        raise InvalidInputError(f"max_side must be >= {MIN_SIDE}, got {max_side}")
    scale = 1.0
    if max_side is not None and max(h, w) > max_side:
        scale = max_side / float(max(h, w))
        nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
        if img.mode == "RGB":  # the same pixels as through an array, without two copies
            rgb = np.asarray(img.resize((nw, nh), Image.Resampling.BOX))
        else:  # other modes are converted (alpha composited, 16-bit rescaled) first
            rgb = np.asarray(Image.fromarray(_to_rgb(img)).resize((nw, nh), Image.Resampling.BOX))
        logger.info("downscaled %s from %dx%d to %dx%d", path, w, h, nw, nh)
    else:
        rgb = _to_rgb(img)
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    return LoadedImage(
        rgb=rgb, original_size=(w, h), scale=scale, source_format=fmt, path=str(path)
    )


def _mask_polarity(values: np.ndarray) -> np.ndarray:
    """(H, W) two-level array -> bool mask, foreground = the level that is the object.

    Rule: the foreground is the level that touches the image border less (objects rarely fill
    the border, backgrounds do); on a tie the minority level (fewer pixels) is foreground.
    """
    lo, hi = values.min(), values.max()
    if lo == hi:  # a constant mask: non-zero means everything, zero means nothing
        return np.full(values.shape, bool(hi > 0))
    high = values > (float(lo) + float(hi)) / 2.0
    border = np.concatenate([high[0], high[-1], high[1:-1, 0], high[1:-1, -1]])
    hi_border = float(border.mean())
    if hi_border < 0.5:
        return high
    if hi_border > 0.5:
        return ~high
    return high if high.mean() <= 0.5 else ~high


def load_mask(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Load a binary mask written by another tool (LISA, SAM, an editor).

    Accepts 0/255, 0/1 and inverted masks, grey-scale or colour (any non-zero channel counts),
    with or without alpha (an alpha channel that is not constant is used as the mask). Polarity is
    decided by :func:`_mask_polarity`: the foreground is the level touching the image border
    less, the minority level on a tie.

    Args:
        path (str or Path): Mask file.
        size ((width, height) or None): Expected size (the image's); a mismatch raises.

    Returns:
        np.ndarray: (H, W) bool mask.

    Raises:
        InvalidInputError: Unreadable file, or a size different from ``size``.
    """
    img = _open(path)
    arr = _to_uint8_array(img)
    if arr.ndim == 3:
        if arr.shape[2] in (2, 4) and arr[..., -1].min() != arr[..., -1].max():
            arr = arr[..., -1]
        else:
            arr = arr[..., : 3 if arr.shape[2] >= 3 else 1].max(axis=2)
    h, w = arr.shape
    if size is not None and (int(size[0]), int(size[1])) != (w, h):
        raise InvalidInputError(
            f"mask is {h}x{w} but the image is {int(size[1])}x{int(size[0])} (height x width): "
            f"{path}"
        )
    # Binarise: a mask saved with anti-aliasing or JPEG noise still has two dominant levels.
    binary = (arr > 127).astype(np.uint8) if arr.max() > 1 else arr
    return _mask_polarity(binary)
