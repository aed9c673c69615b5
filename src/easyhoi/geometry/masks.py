"""Measures of boolean image masks."""

from __future__ import annotations

import numpy as np

from easyhoi.errors import InvalidInputError

__all__ = ["mask_iou"]


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
