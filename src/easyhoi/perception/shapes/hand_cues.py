"""What the holding hand says about the object: its metric scale and its thickness.

Inputs are the hand's 21 keypoints (OpenPose order) in pixels and in metres in a camera-aligned
frame (x right, y down, z away from the camera; any translation), from the detector or from
the fitted hand model — a hand model has a known size, so its keypoints are metric.

* **Scale.** Over a hand's depth range the camera is close to a scaled orthographic one, so
  ``k2d - mean ~ s (k3d_xy - mean)``; the least-squares ``s`` is the image scale in pixels per
  metre at the hand, and the held object is at the hand's depth (it touches the hand).
* **Thickness.** A held object lies between the parts of the hand in front of it and the parts
  behind it. A keypoint that projects inside the object's outline is in front of the object when
  the hand is seen there (the visible hand mask covers it) and behind it when the object is seen
  there. With both kinds present, the gap ``median z(behind) - median z(in front)`` less the
  finger's soft tissue on both sides (:data:`PAD_M` each; keypoints are joint centres) is the
  object's thickness along the view where it is gripped when the fingers press flat faces (a
  phone, a book, a box pinched front to back), and a lower bound of its largest thickness when
  they touch a rounded object away from its front-most point. Only keypoints at least
  :data:`INTERIOR_FRACTION` of the largest inscribed radius inside the outline count: on a ball of
  radius r, a finger that projects that far inside touches within 44 degrees of the pole facing
  it, so front and back fingers are at least 1.4 r apart and a round object is not mistaken for a
  flat one. It holds for any grasp type (pinch, power wrap, lateral) as long as the hand holds the
  object from both sides along the view; when the whole hand is on one side the gap is absent
  (a pinch may still give the thickness, below).
  ``confidence`` grows with the number of keypoints on the lesser side (1 with three or more).
* **Pinch aperture.** The hand mask cannot always tell a finger hidden behind the object from
  one in front of it (the mask is grown from the skeleton), and most grasps hold the object at
  its edge, where few keypoints lie well inside the outline; then the gap above is absent. A
  pinch still measures the object: the thumb opposes the index or middle finger across it, so
  the distance between the thumb's tip and the nearer of the two fingertips, less the pads of
  both (:data:`TIP_PAD_M` each), is the object's thickness between them. It counts as the
  thickness along the view only when the pinch runs mostly along the view (at least
  :data:`PINCH_MIN_VIEW` of the aperture along the camera axis: front face to back face; a
  pinch across the image measures a width the outline already shows) and when both fingertips
  and their midpoint project inside the outline: a fingertip pressing a face lies over it, in
  front of it or hidden behind it, while fingertips at the outline's edge pinch a rim or a
  wall (a bowl's, a cup's), whose thickness is not the object's. Its confidence is
  :data:`PINCH_CONFIDENCE`, below the two-sided gap's: the cue rests on the depth of two
  keypoints alone.
* **Tilt of an elongated object.** The silhouette cannot tell an object lying parallel to the
  image from a longer one tilted towards the camera. The keypoints that project inside the
  outline touch the object (or lie across it), so their depths follow the object's axis: in
  front of it by half its thickness and the finger's pad, or behind it by as much (the thickness
  is the grip gap above when the hand holds it from both sides; from one side the offset is the
  same for every keypoint and does not change the slope). A line fitted to
  those corrected depths against the position along the outline's long axis gives the axis's
  slope out of the image, ``dz / ds`` (:func:`axis_slope`). It needs at least
  :data:`TILT_MIN_KEYPOINTS` keypoints spread over :data:`TILT_MIN_SPREAD_M` along the axis (a
  pinch at one point says nothing about the tilt) on an outline at least
  :data:`TILT_MIN_ASPECT` times longer than wide (a round outline has no axis), and is capped at
  :data:`TILT_MAX_DEG`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from easyhoi.perception.shapes.common import pixel_centres

#: Keypoints count only this far inside the outline, as a fraction of its largest inscribed
#: radius (module docs).
INTERIOR_FRACTION = 0.3
#: Soft tissue between a keypoint (joint centre) and the surface the finger presses, metres.
PAD_M = 0.009
#: Pinch aperture (module docs): a fingertip keypoint's distance to the pad surface it presses
#: with (metres), the least share of the aperture along the view, and the cue's confidence.
TIP_PAD_M = 0.005
PINCH_MIN_VIEW = 0.6
PINCH_CONFIDENCE = 0.6
#: Tilt cue (module docs): keypoints inside the outline, their spread along the axis (metres),
#: the outline's aspect ratio, and the largest tilt out of the image (degrees).
TILT_MIN_KEYPOINTS = 3
TILT_MIN_SPREAD_M = 0.02
TILT_MIN_ASPECT = 2.0
TILT_MAX_DEG = 60.0


@dataclass(frozen=True)
class HandCues:
    """Cues from the hand (module docs). Lengths in metres, positions in source pixels.

    Attributes:
        px_per_m: image scale at the hand (pixels per metre).
        grip_px: (2,) where the thickness was measured (u, v), or None.
        depth_m: object thickness along the view where gripped, or None.
        confidence: trust in ``depth_m``, in [0, 1] (0 without it).
        grip_depth_m: camera z of the grip (mid-thickness) relative to the keypoints' mean z.
        front, behind: keypoints (indices) found in front of / behind the object.
        axis_px: (2,) unit long axis of the outline in the image (u, v), or None.
        axis_slope: the object's axis slope out of the image along ``axis_px`` (dz / ds, z away
            from the camera); 0 when the cue is absent.
        depth_from: where ``depth_m`` comes from: "gap" (keypoints in front of and behind the
            object), "pinch" (the pinch aperture) or None.
    """

    px_per_m: float
    grip_px: np.ndarray | None
    depth_m: float | None
    confidence: float
    grip_depth_m: float
    front: tuple = ()
    behind: tuple = ()
    axis_px: np.ndarray | None = None
    axis_slope: float = 0.0
    depth_from: str | None = None

    def to_dict(self) -> dict:
        return {
            "px_per_m": round(self.px_per_m, 3),
            "grip_px": None if self.grip_px is None else [round(float(x), 2) for x in self.grip_px],
            "depth_m": None if self.depth_m is None else round(self.depth_m, 5),
            "confidence": round(self.confidence, 4),
            "front": list(self.front),
            "behind": list(self.behind),
            "axis_slope": round(self.axis_slope, 4),
            "depth_from": self.depth_from,
        }


def hand_cues(keypoints2d, keypoints3d, object_mask=None, hand_mask=None) -> HandCues | None:
    """:class:`HandCues` from (21, 2) pixel and (21, 3) metric keypoints, or None if unusable.

    ``object_mask`` (amodal) and ``hand_mask`` (visible hand), (H, W) bool, give the thickness;
    without them only the scale is known.
    """
    if keypoints2d is None or keypoints3d is None:
        return None
    k2 = np.asarray(keypoints2d, dtype=np.float64)
    k3 = np.asarray(keypoints3d, dtype=np.float64)
    if (
        k2.shape != (21, 2)
        or k3.shape != (21, 3)
        or not (np.isfinite(k2).all() and np.isfinite(k3).all())
    ):
        return None
    a2 = k2 - k2.mean(0)
    a3 = k3[:, :2] - k3[:, :2].mean(0)
    den = float((a3**2).sum())
    if den <= 1e-12:
        return None
    s = float((a2 * a3).sum() / den)
    if not s > 0:
        return None
    z = k3[:, 2] - k3[:, 2].mean()
    front, behind = [], []
    if object_mask is not None and hand_mask is not None and object_mask.any():
        from easyhoi.perception.shapes.common import inside_distance

        H, W = object_mask.shape
        dist = inside_distance(object_mask)
        inner = INTERIOR_FRACTION * float(dist.max())
        for i, (u, v) in enumerate(k2):
            r, c = int(np.floor(v)), int(np.floor(u))
            if not (0 <= r < H and 0 <= c < W) or dist[r, c] < max(inner, 1.0):
                continue
            # the hand seen in a small neighbourhood: in front; else the object hides it
            win = hand_mask[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
            (front if win.mean() >= 0.5 else behind).append(i)
    axis, slope = None, 0.0
    if not front or not behind:
        if object_mask is None or hand_mask is None or not object_mask.any():
            return HandCues(s, None, None, 0.0, 0.0, tuple(front), tuple(behind))
        pinch = pinch_aperture(k2, k3, object_mask)
        if pinch is None:
            axis, slope = axis_slope(k2, z, s, object_mask, hand_mask, 0.0)
            return HandCues(s, None, None, 0.0, 0.0, tuple(front), tuple(behind), axis, slope)
        depth, grip, pair = pinch
        axis, slope = axis_slope(k2, z, s, object_mask, hand_mask, depth)
        near, far = sorted(pair, key=lambda i: z[i])
        return HandCues(s, grip, depth, PINCH_CONFIDENCE, float(z[list(pair)].mean()), (near,),
                        (far,), axis, slope, "pinch")  # fmt: skip
    zf, zb = float(np.median(z[front])), float(np.median(z[behind]))
    depth = zb - zf - 2 * PAD_M
    if depth <= 0:  # inconsistent ordering (keypoint noise): no cue
        return HandCues(s, None, None, 0.0, 0.0, tuple(front), tuple(behind))
    axis, slope = axis_slope(k2, z, s, object_mask, hand_mask, depth)
    conf = float(min(1.0, min(len(front), len(behind)) / 3))
    grip = 0.5 * (k2[front].mean(0) + k2[behind].mean(0))
    return HandCues(s, grip, depth, conf, 0.5 * (zf + zb), tuple(front), tuple(behind), axis,
                    slope, "gap")  # fmt: skip


def pinch_aperture(k2, k3, object_mask) -> tuple[float, np.ndarray, tuple] | None:
    """(thickness in metres, grip pixel, (thumb tip, fingertip)) of a pinch across the object
    along the view, or None (module docs, "Pinch aperture").

    Args:
        k2: (21, 2) keypoints in pixels; k3: (21, 3) metric keypoints (camera-aligned).
        object_mask: (H, W) bool amodal object mask.
    """
    thumb = 4
    j = min((8, 12), key=lambda f: float(np.linalg.norm(k3[f] - k3[thumb])))
    a = k3[j] - k3[thumb]
    aperture = float(np.linalg.norm(a))
    if aperture <= 0 or abs(float(a[2])) < PINCH_MIN_VIEW * aperture:
        return None
    H, W = object_mask.shape
    grip = 0.5 * (k2[thumb] + k2[j])
    for p in (k2[thumb], k2[j], grip):
        r, c = int(np.floor(p[1])), int(np.floor(p[0]))
        if not (0 <= r < H and 0 <= c < W and object_mask[r, c]):
            return None
    depth = max(aperture - 2 * TIP_PAD_M, 0.002)
    return depth, grip, (thumb, j)


def axis_slope(
    k2, z, px_per_m, object_mask, hand_mask, thickness_m: float
) -> tuple[np.ndarray | None, float]:
    """(axis, slope) of an elongated held object from the keypoints on it (module docs).

    Args:
        k2: (21, 2) keypoints in pixels; z: (21,) their depths in metres (any offset).
        px_per_m: image scale at the hand.
        object_mask, hand_mask: (H, W) bool amodal object and visible hand.
        thickness_m: the object's thickness along the view (0 when unknown).

    Returns:
        the outline's unit long axis (u, v) (None for an outline with no long axis) and the
        slope dz / ds along it (0 when the cue is absent).
    """
    pts = pixel_centres(object_mask)
    c = pts.mean(0)
    w, vec = np.linalg.eigh(np.cov((pts - c).T))
    if w[0] <= 0 or np.sqrt(w[1] / w[0]) < TILT_MIN_ASPECT:
        return None, 0.0
    axis = vec[:, 1] if vec[np.argmax(np.abs(vec[:, 1])), 1] > 0 else -vec[:, 1]
    H, W = object_mask.shape
    half = 0.5 * thickness_m + PAD_M
    S, Z = [], []
    for i, (u, v) in enumerate(k2):
        r, q = int(np.floor(v)), int(np.floor(u))
        if not (0 <= r < H and 0 <= q < W and object_mask[r, q]):
            continue
        seen = hand_mask[max(r - 1, 0) : r + 2, max(q - 1, 0) : q + 2].mean() >= 0.5
        S.append(float((np.array([u, v]) - c) @ axis) / px_per_m)
        Z.append(z[i] + (half if seen else -half))
    S, Z = np.asarray(S), np.asarray(Z)
    if len(S) < TILT_MIN_KEYPOINTS or np.ptp(S) < TILT_MIN_SPREAD_M:
        return axis, 0.0
    dS = S - S.mean()
    b = float(dS @ (Z - Z.mean()) / (dS @ dS))
    cap = np.tan(np.radians(TILT_MAX_DEG))
    return axis, float(np.clip(b, -cap, cap))
