"""PNG encoding of uint8 arrays: one filter for every row, one zlib call.

A PNG encoder chooses a filter per row (the difference to the left pixel, to the pixel above,
...) before deflating; Pillow tries all five on every row and keeps the one with the smallest
sum, which costs about as much as the deflate itself at zlib level 1. The result pictures
(photos under shaded meshes, figures with flat backgrounds) compress about as well with the
"up" filter on every row, which NumPy computes for the whole picture in one subtraction: the
encoding takes about half the time, for files of about the same size, and decodes to the same
pixels. The same array gives the same bytes at every run.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from easyhoi.errors import InvalidInputError

__all__ = ["encode_png"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG colour type per channel count: grey, grey + alpha, RGB, RGBA.
_COLOR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}
_UP = 2  # the PNG filter type "up": each byte minus the byte above it (modulo 256)


def _chunk(tag: bytes, data: bytes) -> tuple[bytes, ...]:
    crc = zlib.crc32(data, zlib.crc32(tag))
    return struct.pack(">I", len(data)), tag, data, struct.pack(">I", crc)


def encode_png(image: np.ndarray, level: int) -> bytes:
    """PNG bytes of an (H, W) or (H, W, C) uint8 array with zlib ``level``.

    C is 2 (grey and alpha), 3 (RGB) or 4 (RGBA); (H, W) is grey. 8 bits per sample, no
    interlacing, no ancillary chunks; every row filtered with "up".
    """
    a = np.asarray(image)
    channels = 1 if a.ndim == 2 else a.shape[-1] if a.ndim == 3 else 0
    if a.dtype != np.uint8 or channels not in _COLOR_TYPE:
        raise InvalidInputError(f"expected an (H, W) or (H, W, 2-4) uint8 image, got {a.shape}")
    if a.size == 0:
        raise InvalidInputError(f"cannot encode an empty image {a.shape}")
    h, w = a.shape[:2]
    rows = np.ascontiguousarray(a).reshape(h, w * channels)
    filtered = np.empty((h, w * channels + 1), np.uint8)
    filtered[:, 0] = _UP
    filtered[0, 1:] = rows[0]  # the row above the first is zeros
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # uint8 arithmetic wraps mod 256
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOR_TYPE[channels], 0, 0, 0)
    return b"".join((
        _SIGNATURE,
        *_chunk(b"IHDR", header),
        *_chunk(b"IDAT", zlib.compress(filtered, level)),
        *_chunk(b"IEND", b""),
    ))  # fmt: skip
