"""Measures of boolean image masks."""

from __future__ import annotations

import numpy as np

from easyhoi.errors import InvalidInputError

__all__ = ["mask_box", "mask_iou"]


def mask_iou(a: np.ndarray, b: np.ndarray, empty: float = float("nan")) -> float:
    """Intersection over union of two boolean masks of one shape.

    Args:
        a, b ((H, W) array-like): Masks (anything non-zero is inside).
        empty (float): The value when both masks are empty, where the ratio is undefined: NaN
            for a measurement (nothing to compare), 1 when two empty masks count as the same
            region, 0 when they count as no agreement.

    Raises:
        InvalidInputError: the masks differ in shape.
    """
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise InvalidInputError(f"masks differ in shape: {a.shape} vs {b.shape}")
    union = np.count_nonzero(a | b)
    return float(empty) if union == 0 else np.count_nonzero(a & b) / union


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """``(u0, v0, u1, v1)`` pixel box of a non-empty mask: its edges, ``u1`` and ``v1`` one past
    the last column and row inside.

    Raises:
        InvalidInputError: the mask is empty.
    """
    mask = np.asarray(mask, bool)
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if not len(rows):
        raise InvalidInputError("an empty mask has no box")
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1
