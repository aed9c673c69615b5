"""Background points: pixels the user marks as not the held object (``--background-point``).

A background point answers a leak: the mask takes in something that is not the object (the
table the object stands on, a sleeve of the object's colour). Each point becomes a small disk
that every segmentation path treats like another hand's pixels: sure background for GrabCut
(whose graph cut then has to separate the object points from it along the weakest edge
between them) and left out of the region proposals. That alone is not enough: a region or a
GrabCut result can flow around the disk, so a candidate that *encloses* a background point (the
point lies inside the region's outline) is dropped too. A disk is enclosed when most of the
ring around it lies in the candidate.

The disk's radius is in palm lengths (:data:`RADIUS`), like every length of the segmenter, so
it does not depend on the photo's resolution: a tenth of a palm, half a finger's width, marks
the spot without reaching across a typical object's edge next to it.
"""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.perception.proposals import Proposals, membership, segment_sums

#: Radius of a background point's disk, in palm lengths.
RADIUS = 0.1
#: Share of the ring around a disk (off the hands) that a candidate covers when it encloses it.
ENCLOSED = 0.5


def disks(shape: tuple[int, int], points: np.ndarray, palm: float) -> list[np.ndarray]:
    """One (h, w) bool disk per point (u, v) inside the crop; points outside it are dropped."""
    h, w = shape
    r = max(2, int(round(RADIUS * palm)))
    out = []
    for u, v in np.asarray(points, np.float64).reshape(-1, 2):
        if 0 <= u < w and 0 <= v < h:
            d = np.zeros(shape, np.uint8)
            cv2.circle(d, (int(round(u)), int(round(v))), r, 1, -1)
            out.append(d.astype(bool))
    return out


def rings(shape: tuple[int, int], disk_masks: list[np.ndarray], off: np.ndarray) -> list:
    """The ring (2 px wide) around each disk, without the pixels of ``off`` (the hands)."""
    k = np.ones((5, 5), np.uint8)
    out = []
    for d in disk_masks:
        ring = cv2.dilate(d.astype(np.uint8), k).astype(bool) & ~d & ~off
        out.append(ring)
    return out


def encloses(mask: np.ndarray, ring_masks: list[np.ndarray]) -> bool:
    """Whether ``mask`` encloses any background point (covers most of the ring around it)."""
    for ring in ring_masks:
        n = int(ring.sum())
        if n and float((mask & ring).sum()) > ENCLOSED * n:
            return True
    return False


def enclosing_regions(props: Proposals, ring_masks: list[np.ndarray]) -> np.ndarray:
    """(n_regions,) bool: the proposals that enclose a background point."""
    n = len(props.regions)
    out = np.zeros(n, bool)
    if not n or not ring_masks:
        return out
    member = membership(props)
    for ring in ring_masks:
        total = float(ring.sum())
        if total:
            covered = member @ segment_sums(props.labels, ring, props.n_base)
            out |= np.asarray(covered).reshape(-1) > ENCLOSED * total
    return out
