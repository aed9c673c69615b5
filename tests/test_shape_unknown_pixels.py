"""Unknown outline pixels in the shape fit: beyond the photo's edge the silhouette fit counts
nothing, as it counts nothing of the hand outside the object."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from easyhoi.perception.shapes.common import fit_iou, work_frame


def _disk(h, w, cu, cv, r):
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return (u - cu) ** 2 + (v - cv) ** 2 <= r**2


def test_pixels_beyond_the_photo_weigh_nothing():
    # a disk cut by the photo's right edge
    mask = _disk(100, 100, 92.0, 50.0, 20.0)
    wf = work_frame(mask)
    src_u, src_v = _source_centres(wf)
    inside = (src_u >= 0) & (src_u < 100) & (src_v >= 0) & (src_v < 100)  # the photo
    assert not inside.all()
    assert (wf.weight[~inside] == 0).all() and (wf.weight[inside] == 1).all()
    # the whole disk, drawn in working pixels, fits as well as the cut one: past the edge the
    # photo says nothing
    whole = (src_u - 92.0) ** 2 + (src_v - 50.0) ** 2 <= 20.0**2
    assert (whole & ~inside).sum() > 50
    assert fit_iou(whole, wf) == pytest.approx(fit_iou(whole & inside, wf), abs=1e-12)
    assert fit_iou(whole, wf) > 0.95
    # counted as seen background, the part past the edge would have cost the whole disk
    seen = replace(wf, weight=np.where(inside, wf.weight, 1.0))
    assert fit_iou(whole, seen) < fit_iou(whole, wf) - 0.1
    # an object well inside the photo: its frame is all inside and weighs 1 off the object
    inner = work_frame(_disk(100, 100, 50.0, 50.0, 20.0))
    u, v = _source_centres(inner)
    assert ((u >= 0) & (u < 100) & (v >= 0) & (v < 100)).all() and (inner.weight == 1).all()


def _source_centres(wf):
    """Source-photo coordinates (u, v) of the working pixels' centres."""
    h, w = wf.mask.shape
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return wf.to_source(np.stack([u, v], -1)).transpose(2, 0, 1)
