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
  object from both sides along the view; when the whole hand is on one side the cue is absent.
  ``confidence`` grows with the number of keypoints on the lesser side (1 with three or more).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Keypoints count only this far inside the outline, as a fraction of its largest inscribed
#: radius (module docs).
INTERIOR_FRACTION = 0.3
#: Soft tissue between a keypoint (joint centre) and the surface the finger presses, metres.
PAD_M = 0.009


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
    """

    px_per_m: float
    grip_px: np.ndarray | None
    depth_m: float | None
    confidence: float
    grip_depth_m: float
    front: tuple = ()
    behind: tuple = ()

    def to_dict(self) -> dict:
        return {
            "px_per_m": round(self.px_per_m, 3),
            "grip_px": None if self.grip_px is None else [round(float(x), 2) for x in self.grip_px],
            "depth_m": None if self.depth_m is None else round(self.depth_m, 5),
            "confidence": round(self.confidence, 4),
            "front": list(self.front),
            "behind": list(self.behind),
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
        from scipy import ndimage

        H, W = object_mask.shape
        dist = ndimage.distance_transform_edt(object_mask)
        inner = INTERIOR_FRACTION * float(dist.max())
        for i, (u, v) in enumerate(k2):
            r, c = int(np.floor(v)), int(np.floor(u))
            if not (0 <= r < H and 0 <= c < W) or dist[r, c] < max(inner, 1.0):
                continue
            # the hand seen in a small neighbourhood: in front; else the object hides it
            win = hand_mask[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
            (front if win.mean() >= 0.5 else behind).append(i)
    if not front or not behind:
        return HandCues(s, None, None, 0.0, 0.0, tuple(front), tuple(behind))
    zf, zb = float(np.median(z[front])), float(np.median(z[behind]))
    depth = zb - zf - 2 * PAD_M
    if depth <= 0:  # inconsistent ordering (keypoint noise): no cue
        return HandCues(s, None, None, 0.0, 0.0, tuple(front), tuple(behind))
    conf = float(min(1.0, min(len(front), len(behind)) / 3))
    grip = 0.5 * (k2[front].mean(0) + k2[behind].mean(0))
    return HandCues(s, grip, depth, conf, 0.5 * (zf + zb), tuple(front), tuple(behind))
