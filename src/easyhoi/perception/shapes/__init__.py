"""Shape hypotheses fitted to the object's outline, chosen by evidence.

Families (one module each): :mod:`.revolution` (bottles, cans, cups), :mod:`.slab` (phones,
books, boards), :mod:`.cuboid` (boxes), :mod:`.superquadric` (balls, fruit, mice, soap),
:mod:`.tube` (pens, tools, bananas), :mod:`.handled` (mugs, jugs: a round body with a handle)
and :mod:`.inflation` (anything else). Each is fitted to
the amodal outline in a working frame (:mod:`.common`) and scored::

    score = IoU_w - complexity + edge_bonus - depth_penalty

* ``IoU_w`` — weighted silhouette IoU of the re-projected hypothesis (:func:`.common.fit_iou`:
  outline pixels hidden by the hand or beyond the photo's edge count as unknown, amodal
  completion counts half). For the surface of revolution it is capped by the outline's mirror
  symmetry about the axis.
* ``complexity`` — :data:`COMPLEXITY`: families whose outline is free (slab, inflation) fit
  every outline and must not win against a family with few parameters that fits as well;
  among the parametric ones, the fewer parameters the smaller the penalty. Between the two
  free ones the silhouette rarely chooses (their IoUs mostly differ by a few thousandths), so
  without the grip's flat verdict (below) the slab, whose thickness is then a guess, ranks
  behind the inflation unless it fits clearly better: an outline no box fits that a grip has not
  shown to be thin was mostly a rounded object with an irregular outline (a mug with its
  handle, a bottle, a pen).
* ``edge_bonus`` — straight image edges where a fitted box's faces meet
  (:func:`.cuboid.edge_evidence`): a box shows its edges, a cylinder of the same outline none.
* ``depth_penalty`` — the hand gives the object's thickness along the view where it is gripped
  (:mod:`.hand_cues`): the gap between the fingers in front of it and behind it. The gap is a
  lower bound of the thickness (equal for flat faces pressed front to back), so a family whose
  depth follows from its outline (round cross-sections) is penalised when it is thinner than
  the gap (up to :data:`DEPTH_WEIGHT` per factor of 2, times the cue's confidence). A grip whose
  gap is much smaller than the outline's inscribed width (:data:`FLAT_RATIO`) says the object
  is flat: then the slab's complexity drops to :data:`FLAT_SLAB_COMPLEXITY` (an outline that a
  grip shows to be thin is a slab, not a pillow) and round families thicker than 1.5 x the gap
  are penalised too. Families with a free depth (slab, face-on cuboid, superquadric,
  inflation) take the gap: thinned to a flat grip's, or thickened to the lower bound.
* ``tilt`` — the selection and the fits see the object lying parallel to the image. When the
  keypoints on an elongated object give its axis's slope out of the image
  (:func:`.hand_cues.axis_slope`), the winner (all but the cuboid, whose 3D rotation is fitted,
  and a surface of revolution already tilted by the rim of its end)
  is sheared to it, ``z' = z + s b`` (``s`` along the outline's long axis, ``b`` the slope):
  the silhouette is unchanged and the length along the axis becomes ``L sqrt(1 + b^2)``.
* ``relief`` (with a depth model) — :data:`FRONT_WEIGHT` x the correlation between the depth
  map's front relief and the hypothesis's front surface on the visible object
  (:func:`.common.relief_agreement`): a cylinder's front bulges, a slab's is flat, a box shows
  a ridge where two faces meet.

:func:`fit_shape` returns the winner's mesh in source pixels with a record of every score.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from easyhoi.perception.shapes import (
    cuboid,
    handled,
    inflation,
    revolution,
    slab,
    superquadric,
    tube,
)
from easyhoi.perception.shapes.common import (
    Hypothesis,
    WorkFrame,
    front_depth,
    pixel_centres,
    relief_agreement,
    scale_depth,
    signed_distance_2d,
    view_chord,
    work_frame,
    work_resample,
)
from easyhoi.perception.shapes.hand_cues import HandCues, hand_cues

#: Complexity penalty per family (see module docs). Without the grip's flat verdict the slab's
#: thickness is a guess, and its penalty exceeds the inflation's by 0.04 of IoU, more than the
#: two free-outline families differ by on most outlines (module docs). The handled surface of
#: revolution pays for its second part (:mod:`.handled`).
COMPLEXITY = {
    "revolution": 0.0,
    "superquadric": 0.005,
    "tube": 0.015,
    "cuboid": 0.06,
    "slab": 0.12,
    "inflation": 0.08,
    "handled": 0.03,
}
#: Slab complexity when the grip says the object is flat.
FLAT_SLAB_COMPLEXITY = 0.02
#: Thickness / inscribed width below which a gripped object counts as flat.
FLAT_RATIO = 0.6
#: Cue confidence needed to call a grip flat.
FLAT_CONFIDENCE = 0.6
#: Penalty per factor of 2 between a rigid family's thickness and the grip's (at confidence 1).
DEPTH_WEIGHT = 0.08
#: Weight of the agreement with a depth model's front relief (correlation in [-1, 1]).
FRONT_WEIGHT = 0.08
#: Bonus of the cuboid at full edge evidence.
EDGE_WEIGHT = 0.05
FAMILIES = tuple(COMPLEXITY)

__all__ = ["FAMILIES", "HandCues", "Hypothesis", "fit_shape", "hand_cues"]


def _grip_depth(h: Hypothesis, grip: np.ndarray, mask: np.ndarray, radius: float) -> float:
    """Largest view chord of ``h`` on a small grid around the grip point (inside the mask)."""
    best = 0.0
    for du in (-radius, 0.0, radius):
        for dv in (-radius, 0.0, radius):
            u, v = grip[0] + du, grip[1] + dv
            i, j = int(np.floor(v)), int(np.floor(u))
            if 0 <= i < mask.shape[0] and 0 <= j < mask.shape[1] and mask[i, j]:
                best = max(best, view_chord(h.verts, h.faces, u, v))
    return best


def tilt_about_axis(verts: np.ndarray, mask: np.ndarray, axis, slope: float) -> np.ndarray:
    """(V, 3) source-pixel vertices sheared so that the long ``axis`` (u, v) rises by ``slope``
    out of the image, with the silhouette unchanged (module docs, ``tilt``)."""
    rows, cols = np.nonzero(mask)
    c = np.array([cols.mean() + 0.5, rows.mean() + 0.5])
    out = np.array(verts, dtype=np.float64)
    out[:, 2] += ((out[:, :2] - c) @ np.asarray(axis, dtype=np.float64)) * slope
    return out


def _nearest_inside(mask: np.ndarray, p: np.ndarray) -> np.ndarray:
    pts = pixel_centres(mask)
    return pts[int(np.argmin(((pts - p) ** 2).sum(1)))]


def fit_shape(
    mask: np.ndarray,
    image: np.ndarray | None = None,
    visible: np.ndarray | None = None,
    occluder: np.ndarray | None = None,
    cues: HandCues | None = None,
    families: tuple[str, ...] = FAMILIES,
    front: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Fit every family to the amodal ``mask`` and keep the best (module docs).

    Args:
        mask: (H, W) bool amodal object mask.
        image: (H, W, 3) uint8 hand-free photo (edge evidence), optional.
        visible: (H, W) bool visible object mask, optional (amodal-only pixels count half).
        occluder: (H, W) bool hand mask, optional (unknown pixels outside ``mask``).
        cues: :class:`HandCues`, optional (thickness at the grip).
        families: the families to try.
        front: (H, W) float front surface from a monocular depth model (larger = farther, any scale
            and shift), optional: adds ``FRONT_WEIGHT x relief agreement`` to each score.

    Returns:
        verts : (V, 3) (u, v, z) source pixels (z away from the camera), faces : (F, 3), info : dict
        with ``shape`` (the winner), ``scores`` (family -> score, IoU, reasons) and
        ``depth_cue_px``.
    """
    wf: WorkFrame = work_frame(mask, visible, occluder, image)
    width = 2 * float(signed_distance_2d(wf.mask).max())
    t_obs = conf = None
    grip = None
    if cues is not None and cues.depth_m is not None and cues.confidence > 0:
        t_obs = cues.depth_m * cues.px_per_m / wf.scale
        conf = cues.confidence
        grip = _nearest_inside(wf.mask, wf.to_work(cues.grip_px))
    flat = t_obs is not None and conf >= FLAT_CONFIDENCE and t_obs < FLAT_RATIO * width
    hyps: list[Hypothesis] = []
    round_axes = None  # the axis search the two round families share, done once
    for name in families:
        if name in ("revolution", "handled") and round_axes is None:
            round_axes = revolution.searched_axes(wf.mask, wf.weight)
        if name == "revolution":
            h = revolution.fit(wf, axes=round_axes)
        elif name == "superquadric":
            h = superquadric.fit(wf)
        elif name == "tube":
            h = tube.fit(wf)
        elif name == "cuboid":
            h = cuboid.fit(wf, depth=t_obs if flat else None, min_depth=t_obs)
        elif name == "slab":
            h = slab.fit(wf, thickness=t_obs if flat else None, min_thickness=t_obs)
        elif name == "inflation":
            h = inflation.fit(wf)
        elif name == "handled":
            h = handled.fit(wf, alone=len(families) == 1, axes=round_axes)
        else:
            raise ValueError(f"unknown shape family {name!r}")
        if h is not None:
            hyps.append(h)
    radius = 0.06 * wf.mask.shape[0]
    front_w = None
    if front is not None:
        front_w = work_resample(np.asarray(front, np.float64), wf, mask)
        keep = ndimage.binary_erosion(wf.visible, iterations=2)
    for h in hyps:
        reasons = {}
        pen = COMPLEXITY[h.name]
        if h.name == "slab" and flat:
            pen = FLAT_SLAB_COMPLEXITY
        score = h.iou - pen
        if h.name == "cuboid":
            bonus = EDGE_WEIGHT * h.info["edge_evidence"]
            score += bonus
            reasons["edge_bonus"] = round(bonus, 4)
        if t_obs is not None:
            d = _grip_depth(h, grip, wf.mask, radius)
            reasons["grip_depth_px"] = round(d * wf.scale, 2)
            if d > 0 and h.rigid_depth:
                # the gap between the fingers in front and behind is a lower bound of the
                # thickness (equal for flat faces); a flat grip also bounds it from above
                too_thin = d < t_obs / 1.25
                too_thick = flat and d > 1.5 * t_obs
                if too_thin or too_thick:
                    miss = abs(np.log(d / t_obs)) / np.log(2)
                    dp = DEPTH_WEIGHT * conf * min(miss, 1.5)
                    score -= dp
                    reasons["depth_penalty"] = round(float(dp), 4)
            elif d > 0 and h.name != "slab" and (flat or d < t_obs):
                # free depth: thin to a flat grip's gap, or thicken to the lower bound
                factor = float(np.exp(conf * np.log(t_obs / d)))
                h.verts = scale_depth(h.verts, factor)
                reasons["depth_scaled"] = round(factor, 4)
        if front_w is not None:
            agree = relief_agreement(front_w, front_depth(h.verts, h.faces, wf.mask.shape), keep)
            score += FRONT_WEIGHT * agree
            reasons["relief_agreement"] = round(agree, 4)
        h.score = float(score)
        h.info.update(reasons, iou=round(h.iou, 4), complexity=pen, score=round(h.score, 4))
    order = {n: i for i, n in enumerate(FAMILIES)}
    win = max(hyps, key=lambda h: (round(h.score, 6), -order[h.name]))
    verts = np.array(win.verts, dtype=np.float64)
    verts[:, :2] = wf.to_source(verts[:, :2])
    verts[:, 2] *= wf.scale
    slope = 0.0
    if (
        cues is not None
        and cues.axis_slope
        and win.name != "cuboid"
        and not win.info.get("tilt_deg")
    ):
        slope = cues.axis_slope
        verts = tilt_about_axis(verts, mask, cues.axis_px, slope)
    info = {
        "shape": win.name,
        "scores": {h.name: h.info for h in hyps},
        "depth_cue_px": None if t_obs is None else round(t_obs * wf.scale, 3),
        "depth_cue_confidence": conf,
        "depth_cue_from": None if t_obs is None else cues.depth_from,
        "flat_by_grip": bool(flat),
        "tilt_deg": round(float(np.degrees(np.arctan(slope))), 2),
    }
    return verts, win.faces, info
