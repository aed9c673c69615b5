"""Surface of revolution with a handle: mugs, jugs, cups with a handle, spray bottles.

Many held objects are a round body with one part standing off its side: a mug's handle, a
jug's, a spray bottle's trigger. The outline is then mirror-symmetric about the body's axis
except for that part, and the surface of revolution, capped by its outline's mirror symmetry,
loses to the free-outline fallback (a pillow) although its body is what the object mostly is.

About each principal axis the most mirror-symmetric axis nearby is searched as the surface of
revolution searches it (:func:`.revolution.mirror_axis`; the handle lowers every axis's symmetry
alike, the body's least). The *core* is the mask where its mirror image about that axis is in the
mask too (or hidden: the hand or the photo's edge says nothing there); the rest is the
*handle*. The family applies only when the handle is a part, on
one side of the axis, and seen:

* it is between :data:`HANDLE_SHARE` of the outline (a mug's thin handle at the working frame's
  96 px can take as little as 3 %; larger is not a handle but an outline that is not round: a
  banana, a shoe), counted after the pieces under :data:`SLIVER` of it are dropped;
* at least :data:`ONE_SIDE` of it lies on one side of the axis (a handle stands off one side; an
  outline that differs from its mirror image on both sides is not a round body), and as much
  beside the body, not within :data:`END_MARGIN` of its length from either end (a corner of a box
  seen at an angle differs from its mirror image at the end of the axis);
* it is one piece (at least :data:`ONE_PIECE` of it connected: a mask's ragged edge differs
  from its mirror image in many slivers);
* its seen part alone is at least the smallest share above (the amodal completion behind the
  hand draws what it does not see, and a bulge it draws is no evidence of a handle).

The body is the core's profile revolved (:func:`.revolution.profile`), the handle a rounded
slab of its own outline as thick as its widest inscribed disk (a handle's cross-section is about
as deep as it is wide) on the body's mid-plane (a handle sticks out sideways, in the plane of the
axis). They are two closed surfaces that meet where the handle leaves the body's outline (the
handle lies outside the body's silhouette, so they do not overlap). The evidence is the lesser of
the silhouette fit and the IoU of the revolved body's silhouette with the core, as the
revolution's is capped by its symmetry; of the two axes the one with the better evidence wins.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes import revolution
from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    fit_iou,
    pixel_centres,
    rasterize,
)
from easyhoi.perception.shapes.inflation import implicit_slab_mesh
from easyhoi.perception.shapes.slab import slab_h2

#: Pieces of the outline off its mirror image smaller than this share of it are the mask's
#: raggedness, not a handle (:func:`split`).
SLIVER = 0.01
#: Share of the outline the handle may take (module docs).
HANDLE_SHARE = (0.025, 0.3)
#: Least share of the handle on its side of the axis.
ONE_SIDE = 0.9
#: A handle stands off the body's side: this share of the body's length at each end is not
#: beside it (where a corner of a tilted box differs from its mirror image).
END_MARGIN = 0.1
#: Least share of the handle in its largest connected piece.
ONE_PIECE = 0.8
#: Profile samples along the axis and vertices around it.
N_RINGS = 48
N_SEGMENTS = 40


def split(wf: WorkFrame, c: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(core, handle, largest): the mask where its mirror image about the axis through ``c``
    along ``a`` is in the mask or hidden, the rest without pieces under :data:`SLIVER` of the
    mask, and the share of that rest in its largest connected piece (1 when it is empty)."""
    hidden = wf.weight <= 0
    mirror = revolution.reflect_mask(wf.mask | hidden, c, a).astype(bool)
    core = wf.mask & mirror
    rest = wf.mask & ~core
    labels, n = ndimage.label(rest, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    keep = sizes >= SLIVER * float(wf.mask.sum())
    keep[0] = False
    handle = keep[labels]
    kept = sizes[keep]
    largest = float(kept.max()) / float(kept.sum()) if kept.size else 1.0
    return wf.mask & ~handle, handle, largest


def fit(
    wf: WorkFrame, max_faces: int = 6000, alone: bool = False, axes: list[tuple] | None = None
) -> Hypothesis | None:
    """The handled hypothesis of the working frame's mask, or None where the outline is not a
    round body with one handle about either searched axis (module docs). ``alone`` (the family
    was asked for by name): such an outline gives the plain surface of revolution instead, as a
    handle hidden behind the hand or the body leaves. ``axes``: the surface of revolution's
    :func:`.revolution.searched_axes` of the mask and its weight when already found."""
    if axes is None:
        axes = revolution.searched_axes(wf.mask, wf.weight)
    best = None
    for _, _, c, a in axes:
        h = _fit_axis(wf, c, a, max_faces)
        if h is not None and (best is None or h.iou > best.iou):
            best = h
    if best is None and alone:
        best = revolution.fit(wf, axes=axes)
        best.name = "handled"
        best.info["handle_share"] = 0.0
    return best


def _fit_axis(wf: WorkFrame, c, a, max_faces: int) -> Hypothesis | None:
    """The handled hypothesis about the axis through ``c`` along ``a``, or None where the rest
    of the outline beside its mirror-symmetric core is not a handle (module docs)."""
    core, handle, largest = split(wf, c, a)
    area = float(wf.mask.sum())
    share = float(handle.sum()) / area if area else 0.0
    if not HANDLE_SHARE[0] <= share <= HANDLE_SHARE[1] or not core.any():
        return None
    normal = np.array([-a[1], a[0]])
    p = pixel_centres(handle, c)
    side = p @ normal
    if max((side > 0).mean(), (side < 0).mean()) < ONE_SIDE:
        return None
    s_core = pixel_centres(core, c) @ a
    lo, hi = float(s_core.min()), float(s_core.max())
    margin = END_MARGIN * (hi - lo)
    along = p @ a
    if ((along > lo + margin) & (along < hi - margin)).mean() < ONE_SIDE:
        return None
    if float((handle & wf.visible).sum()) / area < HANDLE_SHARE[0]:
        return None
    if largest < ONE_PIECE:
        return None
    s, r, _ = revolution.profile(core, c, a, N_RINGS)
    bv, bf = revolution.tilted_revolution_mesh(c, a, s, r, 0.0, N_SEGMENTS)
    width = 2.0 * float(ndimage.distance_transform_edt(handle).max())
    hv, hf = implicit_slab_mesh(handle, slab_h2(handle, width), max_faces=max_faces // 2)
    verts = np.concatenate([bv, hv])
    faces = np.concatenate([bf, hf + len(bv)])
    body = revolution.profile_mask(wf.mask.shape, c, a, normal, s, r)
    iou = fit_iou(rasterize(verts[:, :2], faces, wf.mask.shape), wf)
    body_iou = float((body & core).sum()) / float((body | core).sum())
    info = dict(handle_share=round(share, 4), body_iou=round(body_iou, 4),
                axis=[round(float(x), 6) for x in a])  # fmt: skip
    return Hypothesis("handled", verts, faces, min(iou, body_iou), True, info=info)
