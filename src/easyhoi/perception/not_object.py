"""Background points: pixels the user marks as not the held object (``--background-point``).

A background point answers a leak: the mask takes in something that is not the object (the
table the object stands on, a sleeve of the object's colour). Each point becomes a small disk,
grown into the patch it lies on (:func:`patch`: the connected pixels of the disk's colour within
half a palm length), that every segmentation path treats like another hand's pixels: sure
background for GrabCut (whose colour model then learns what the user marked, and whose graph
cut has to separate the object points from it along the weakest edge between them) and left
out of the region proposals. The patch, not the disk alone: a leak is a region of the object's
colour or near it, and a few pixels of it do not move GrabCut's colour model, so a region of
that colour beside the disk wins instead. The reach is bounded because the object may have
the same colour farther on (a white pen on a white sleeve). That alone is not enough: a region
or a GrabCut result can flow around the patch, so a candidate that *encloses* a background
point (the point lies inside the region's outline) is dropped too. A point is enclosed when
most of the ring around its disk lies in the candidate.

The disk's radius is in palm lengths (:data:`RADIUS`), like every length of the segmenter, so
it does not depend on the photo's resolution: a tenth of a palm, half a finger's width, marks
the spot without reaching across a typical object's edge next to it.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from easyhoi.perception.proposals import Proposals, membership, segment_sums
from easyhoi.perception.skin import components_at

#: Radius of a background point's disk, in palm lengths.
RADIUS = 0.1
#: Share of the ring around a disk (off the hands) that a candidate covers when it encloses it.
ENCLOSED = 0.5
#: Reach of a background point's patch (palm lengths) and the largest colour difference (Lab
#: distance to the disk's median colour) of the pixels it takes in.
PATCH_REACH = 0.5
PATCH_COLOUR = 10.0


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


def rings(disk_masks: Sequence[np.ndarray], off: np.ndarray) -> tuple[np.ndarray, ...]:
    """The ring (2 px wide) around each disk, without the pixels of ``off`` (the hands)."""
    k = np.ones((5, 5), np.uint8)
    return tuple(cv2.dilate(d.astype(np.uint8), k).astype(bool) & ~d & ~off for d in disk_masks)


def encloses(mask: np.ndarray, ring_masks: Sequence[np.ndarray]) -> bool:
    """Whether ``mask`` encloses any background point (covers most of the ring around it)."""
    for ring in ring_masks:
        n = int(ring.sum())
        if n and float((mask & ring).sum()) > ENCLOSED * n:
            return True
    return False


def enclosing_regions(props: Proposals, ring_masks: Sequence[np.ndarray]) -> np.ndarray:
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


def patch(lab: np.ndarray, disk: np.ndarray, palm: float) -> np.ndarray:
    """The disk grown over the connected pixels of its colour within PATCH_REACH L."""
    med = np.median(lab[disk], axis=0)
    near = np.linalg.norm(lab - med, axis=-1) < PATCH_COLOUR
    ys, xs = np.nonzero(disk)
    c = np.array([xs.mean(), ys.mean()])
    h, w = disk.shape
    yy, xx = np.mgrid[0:h, 0:w]
    near &= (xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= (PATCH_REACH * palm) ** 2
    return components_at(near | disk, disk)
