"""Masks as outlines for ``result.json``: the object regions offered for ``--object-choice``.

A mask is stored as its outer outlines (one polygon per connected piece, holes filled), in
photo pixels and simplified to within a pixel: a few hundred numbers instead of a bitmap,
enough to draw the region and to read where it lies.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["mask_outlines", "outlines_mask"]

#: Largest distance (pixels) of a simplified outline from the mask's own.
TOLERANCE_PX = 1.0


def mask_outlines(mask: np.ndarray, scale: float = 1.0) -> list[list[list[int]]]:
    """Outer outlines of ``mask``'s pieces, each ``[[x, y], ...]`` (ints), times ``scale``."""
    m = np.ascontiguousarray(np.asarray(mask, bool), dtype=np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in contours:
        c = cv2.approxPolyDP(c, TOLERANCE_PX, True).reshape(-1, 2)
        if len(c) >= 3:
            out.append(np.rint(c * scale).astype(int).tolist())
    return out


def outlines_mask(outlines, shape: tuple[int, int], scale: float = 1.0) -> np.ndarray:
    """(H, W) bool: the polygons of :func:`mask_outlines` filled, their points times
    ``scale``."""
    m = np.zeros(shape, np.uint8)
    polys = [np.rint(np.asarray(p, np.float64) * scale).astype(np.int32) for p in outlines]
    if polys:
        cv2.fillPoly(m, polys, 1)
    return m.astype(bool)
