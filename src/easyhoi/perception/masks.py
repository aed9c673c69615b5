"""Classical (model-free) hand and held-object masks from hand keypoints.

Everything runs in a crop around the hand (side ``crop_factor`` x the hand's keypoint extent),
resampled so its longer side is at most ``work_side`` pixels; masks are mapped back to the full
image at the end.

Hand mask M_h (GrabCut seeded by the skeleton):
  * L = palm length (wrist -> middle MCP). Bones are drawn with width ``0.3 L`` and the palm
    polygon (wrist, thumb CMC, index/middle/ring/pinky MCP) filled: "probably foreground".
  * A colour model (median and robust spread in Lab) is fitted to pixels along the bones; the thin
    bone cores (width ``0.08 L``) that match it are "sure foreground" (occluded fingers drawn over
    an object do not match and stay "probable"). Far from the skeleton (> ``0.6 L``) is "sure
    background".
  * GrabCut refines; the component(s) overlapping the skeleton are kept, and the forearm is cut at
    ``0.25 L`` behind the wrist (the hand model ends at the wrist).

Object candidates: a second GrabCut in the crop with the hand as "sure foreground", the region
within ``near`` of the hand "probably foreground", the rest "probably background" and a thin
crop border "sure background"; foreground minus the (dilated) hand minus skin-coloured forearm
pixels gives candidate components. :func:`filter_by_hand_contact` (the paper's contour-guided
filtering) keeps those whose contour lies within ``max_gap_px`` of the hand's contour.

Held-object cues (:func:`component_cues`, :func:`held_object_verdict`) then drop touching
regions that are not a held object: a component must touch the hand on its fingers/palm side
(not only at the wrist), must not be a skin-coloured region larger than the hand (a face, an
arm), and its outline must be a real boundary (the colour must not continue across it, as it
does where a piece of a wall, a shirt or a body was cut out of a larger region). The kept
components together must be between ``min_object_area`` and ``max_object_area`` times the hand's
area. An empty result is reported as ``has_object=False``.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.io.image import check_image
from easyhoi.perception.base import HandDetection, Segmentation, register

logger = logging.getLogger(__name__)

#: Bones of the 21-keypoint OpenPose hand (parent, child).
BONES = tuple(
    (0 if j % 4 == 1 else j - 1, j) for j in range(1, 21)
)  # wrist->finger base, then along each finger
#: Palm polygon: wrist, thumb CMC, index, middle, ring, pinky MCP.
PALM = (0, 1, 5, 9, 13, 17)


def check_mask(mask: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    """Validate an (H, W) mask of the given shape and return it as bool."""
    if not isinstance(mask, np.ndarray) or mask.ndim != 2:
        got = getattr(mask, "shape", type(mask).__name__)
        raise InvalidInputError(f"{name} must be an (H, W) array, got {got}")
    if mask.shape != tuple(shape):
        raise InvalidInputError(
            f"{name} is {mask.shape[0]}x{mask.shape[1]} but the image is {shape[0]}x{shape[1]}"
        )
    return mask.astype(bool)


def palm_length(kp: np.ndarray) -> float:
    """Wrist-to-middle-MCP distance of (21, 2) keypoints (floored at 1 px)."""
    return max(1.0, float(np.linalg.norm(kp[9] - kp[0])))


def draw_skeleton(shape: tuple[int, int], kp: np.ndarray, width: float, palm: bool) -> np.ndarray:
    """(H, W) bool raster of the bones of (21, 2) keypoints ``width`` px wide (+ palm polygon)."""
    canvas = np.zeros(shape, np.uint8)
    w = max(1, int(round(width)))
    pts = np.round(kp).astype(np.int32)
    for a, b in BONES:
        cv2.line(canvas, tuple(map(int, pts[a])), tuple(map(int, pts[b])), 1, w, cv2.LINE_8)
    if palm:
        cv2.fillPoly(canvas, [pts[list(PALM)]], 1)
    return canvas.astype(bool)


def _components(mask: np.ndarray, min_area: int = 1) -> list[np.ndarray]:
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return [lab == i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= min_area]


def filter_by_hand_contact(
    candidates: list[np.ndarray] | tuple[np.ndarray, ...],
    hand_mask: np.ndarray,
    max_gap_px: float,
) -> list[np.ndarray]:
    """Contour-guided filtering: keep candidate components adjacent to the hand.

    Each candidate mask is split into connected components; a component is kept when some pixel
    of its contour lies within ``max_gap_px`` (Euclidean) of the hand's contour, or when it
    overlaps the hand.

    Parameters
    ----------
    candidates : sequence of (H, W) bool
        Object candidate masks.
    hand_mask : (H, W) bool
        Visible hand mask.
    max_gap_px : float
        Largest allowed gap between the two contours, in pixels (>= 0).

    Returns
    -------
    list of (H, W) bool
        The kept components (possibly empty).
    """
    hand = np.asarray(hand_mask).astype(bool)
    if max_gap_px < 0:
        raise InvalidInputError(f"max_gap_px must be >= 0, got {max_gap_px}")
    if not hand.any():
        return []
    # distance of every pixel to the nearest hand pixel (0 on the hand)
    dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
    kept = []
    for cand in candidates:
        cand = check_mask(np.asarray(cand), hand.shape, "object candidate")
        for comp in _components(cand):
            # contour pixels = component minus its erosion; distance to the hand's contour equals
            # the distance to the hand region for pixels outside it
            edge = comp & ~cv2.erode(comp.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            if (comp & hand).any() or float(dist[edge].min()) <= max_gap_px + 1.0:
                kept.append(comp)
    return kept


def grip_contact_share(
    component: np.ndarray, hand_dist: np.ndarray, along: np.ndarray, palm_len: float, gap: float
) -> float:
    """Share of a component's contact with the hand on the fingers/palm side of the hand.

    Contact pixels are the component's pixels within ``gap`` (+1) of the hand (``hand_dist``:
    distance to the hand mask). ``along`` is each pixel's coordinate along the wrist -> middle
    MCP axis, 0 at the wrist; contact less than ``0.5 * palm_len`` past the wrist is on the
    wrist/forearm side. Returns 0 when the component does not touch the hand.
    """
    contact = component & (hand_dist <= gap + 1.0)
    if not contact.any():
        return 0.0
    return float((along[contact] >= 0.5 * palm_len).mean())


def outline_continuation(
    component: np.ndarray, hand: np.ndarray, lab: np.ndarray, width: int, tol: float = 10.0
) -> tuple[float, float]:
    """How much of a component's outline its colour continues across: (share, length in px).

    For each pixel 2..``width`` px outside the component (and not on or next to the hand), the
    smoothed Lab colour is compared with that of the nearest component pixel; a difference below
    ``tol`` means the region continues past the outline there. ``share`` is the fraction of such
    band pixels, ``length`` their count divided by the band's thickness (``width - 1``): the
    length of outline along which the region continues. A real object's outline is an image
    boundary (both near 0); a piece cut out of a larger region (a wall, a shirt, a body)
    continues along part of its outline. Both are 0 when there is no such band.
    """
    dist, labels = cv2.distanceTransformWithLabels(
        (~component).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    near_hand = cv2.dilate(hand.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    band = (dist >= 2) & (dist <= width) & ~near_hand
    if not band.any():
        return 0.0, 0.0
    # DIST_LABEL_PIXEL numbers the zero pixels (the component) in raster order from 1
    zy, zx = np.nonzero(component)
    idx = labels[band] - 1
    same = np.linalg.norm(lab[band] - lab[zy[idx], zx[idx]], axis=-1) < tol
    return float(same.mean()), float(same.sum()) / max(1, width - 1)


@dataclass(frozen=True)
class ComponentCues:
    """Held-object cues of one candidate component (see :func:`component_cues`).

    Attributes:
        area_ratio: component area / the hand's reference area.
        grip_share: share of its hand contact on the fingers/palm side (not the wrist).
        skin_share: share of its pixels matching the hand's own colour model.
        continuation: share of the band outside its outline where its colour continues.
        continuing_length: length of outline its colour continues across, in palm lengths.
    """

    area_ratio: float
    grip_share: float
    skin_share: float
    continuation: float
    continuing_length: float


def component_cues(
    component: np.ndarray,
    hand: np.ndarray,
    hand_dist: np.ndarray,
    along: np.ndarray,
    lab: np.ndarray,
    skin_d2: np.ndarray,
    palm_len: float,
    gap: float,
    hand_area: float,
) -> ComponentCues:
    """The held-object cues of one (h, w) bool component in the working crop.

    ``hand_dist`` is the distance to the hand mask, ``along`` the coordinate along the hand's
    axis (0 at the wrist), ``lab`` the smoothed Lab image, ``skin_d2`` the squared normalised
    distance to the hand's colour model (< 9 is skin) and ``hand_area`` the hand's reference
    area in pixels.
    """
    share, length = outline_continuation(component, hand, lab, max(3, int(0.15 * palm_len)))
    return ComponentCues(
        area_ratio=float(component.sum()) / max(1.0, hand_area),
        grip_share=grip_contact_share(component, hand_dist, along, palm_len, gap),
        skin_share=float((skin_d2[component] < 9.0).mean()) if component.any() else 0.0,
        continuation=share,
        continuing_length=length / palm_len,
    )


def held_object_verdict(
    cues: ComponentCues,
    min_grip_share: float = 0.5,
    body_skin_share: float = 0.5,
    body_area_ratio: float = 1.6,
    max_continuing_length: float = 0.8,
) -> str | None:
    """Why a hand-touching component is not (part of) a held object, or None when it may be.

    * ``"wrist"``: less than ``min_grip_share`` of its contact is on the fingers/palm side;
    * ``"body"``: skin-coloured (share >= ``body_skin_share``) and larger than
      ``body_area_ratio`` x the hand: another body part such as a face or an arm. Skin-like
      objects (cardboard, beige cups) pass when they are not larger than the hand;
    * ``"continues"``: its colour continues across >= ``max_continuing_length`` palm lengths of
      its outline (a length, not a share: a small, partly segmented piece of an object may
      continue along a good share of its short outline; a cut-out piece of a wall, a shirt or a
      body continues along a long one).
    """
    if cues.grip_share < min_grip_share:
        return "wrist"
    if cues.skin_share >= body_skin_share and cues.area_ratio > body_area_ratio:
        return "body"
    if cues.continuing_length >= max_continuing_length:
        return "continues"
    return None


class _ColourModel:
    """Robust Gaussian in Lab fitted to sample pixels (median and 1.4826 x MAD per channel)."""

    def __init__(self, lab_samples: np.ndarray, min_sigma: float = 6.0):
        self.mu = np.median(lab_samples, axis=0)
        mad = np.median(np.abs(lab_samples - self.mu), axis=0) * 1.4826
        self.sigma = np.maximum(mad, min_sigma)
        self.sigma[0] = max(self.sigma[0], 25.0)  # lightness varies with shading

    def d2(self, lab: np.ndarray) -> np.ndarray:
        return (((lab - self.mu) / self.sigma) ** 2).sum(-1)


@register("segmenter", "classical")
class ClassicalHOISegmenter:
    """Hand and held-object masks by keypoint-seeded GrabCut and contour-guided filtering.

    Parameters
    ----------
    crop_factor : float
        Working crop side as a multiple of the hand's keypoint extent.
    work_side : int
        Longer side of the working crop in pixels (speed / quality trade-off).
    near : float
        Object search distance from the hand, in palm lengths.
    max_gap : float
        Contour-filter gap in palm lengths (converted to pixels per image).
    min_object_area : float
        Smallest kept object (all kept components), as a fraction of the hand's area.
    max_object_area : float
        Largest kept object, as a multiple of the hand's area (bigger: background, no object).
        The hand's area is that of its mask, floored at ``2 L^2`` (L: palm length).
    min_grip_share, body_skin_share, body_area_ratio, max_continuing_length : float
        Thresholds of :func:`held_object_verdict`.
    iterations : int
        GrabCut iterations.
    bg_colour_dist : float
        Object pixels closer than this (Lab) to a colour of the crop border are background.
    max_border_share : float
        Candidates covering more than this share of the crop's perimeter are background.
    seed : int
        Seed of OpenCV's RNG (GrabCut's GMM initialisation uses k-means).
    """

    def __init__(
        self,
        crop_factor: float = 3.0,
        work_side: int = 256,
        near: float = 1.2,
        max_gap: float = 0.08,
        min_object_area: float = 0.08,
        max_object_area: float = 2.5,
        min_grip_share: float = 0.5,
        body_skin_share: float = 0.5,
        body_area_ratio: float = 1.6,
        max_continuing_length: float = 0.8,
        iterations: int = 5,
        bg_colour_dist: float = 10.0,
        max_border_share: float = 0.12,
        seed: int = 0,
    ):
        self.bg_colour_dist = float(bg_colour_dist)
        self.max_border_share = float(max_border_share)
        self.crop_factor = float(crop_factor)
        self.work_side = int(work_side)
        self.near = float(near)
        self.max_gap = float(max_gap)
        self.min_object_area = float(min_object_area)
        self.max_object_area = float(max_object_area)
        self.verdict_args = {
            "min_grip_share": float(min_grip_share),
            "body_skin_share": float(body_skin_share),
            "body_area_ratio": float(body_area_ratio),
            "max_continuing_length": float(max_continuing_length),
        }
        self.iterations = int(iterations)
        self.seed = int(seed)

    # -- crop ----------------------------------------------------------------------------------
    def _crop(self, shape, kp):
        h, w = shape
        lo, hi = kp.min(0), kp.max(0)
        c = (lo + hi) / 2
        side = self.crop_factor * max(float((hi - lo).max()), 2.0 * palm_length(kp))
        x0, y0 = int(max(0, c[0] - side / 2)), int(max(0, c[1] - side / 2))
        x1, y1 = int(min(w, c[0] + side / 2)), int(min(h, c[1] + side / 2))
        if x1 - x0 < 8 or y1 - y0 < 8:
            raise InvalidInputError(f"hand keypoints {lo}..{hi} lie outside the {w}x{h} image")
        s = min(1.0, self.work_side / max(x1 - x0, y1 - y0))
        return (x0, y0, x1, y1), s

    def _grabcut(self, img, init):
        if not ((init == cv2.GC_FGD) | (init == cv2.GC_PR_FGD)).any():
            return np.zeros(init.shape, bool)
        if not ((init == cv2.GC_BGD) | (init == cv2.GC_PR_BGD)).any():
            return np.ones(init.shape, bool)
        cv2.setRNGSeed(self.seed)
        m = init.copy()
        bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
        cv2.grabCut(img, m, None, bgd, fgd, self.iterations, cv2.GC_INIT_WITH_MASK)
        return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)

    # -- main ----------------------------------------------------------------------------------
    def segment(self, image: np.ndarray, hand: HandDetection) -> Segmentation:
        """Masks for ``hand`` in an (H, W, 3) uint8 RGB image; all outputs (H, W) bool."""
        image = check_image(image)
        kp_full = np.asarray(hand.keypoints2d, dtype=np.float64)
        if kp_full.shape != (21, 2) or not np.isfinite(kp_full).all():
            raise InvalidInputError(f"hand keypoints must be finite (21, 2), got {kp_full.shape}")
        H, W = image.shape[:2]
        (x0, y0, x1, y1), s = self._crop((H, W), kp_full)
        crop = image[y0:y1, x0:x1]
        cw, ch = max(8, round((x1 - x0) * s)), max(8, round((y1 - y0) * s))
        img = cv2.resize(crop, (cw, ch), interpolation=cv2.INTER_AREA) if s < 1 else crop.copy()
        img = np.ascontiguousarray(img)
        kp = (kp_full - [x0, y0]) * [cw / (x1 - x0), ch / (y1 - y0)]
        L = palm_length(kp)
        shape = img.shape[:2]
        lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)

        hand_mask, core, skin_d2 = self._hand(img, lab, kp, L)
        yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
        axis = (kp[9] - kp[0]) / L
        along = (xx - kp[0, 0]) * axis[0] + (yy - kp[0, 1]) * axis[1]
        arm = (along < 0.0) & (skin_d2 < 9.0)

        obj_cands = self._objects(img, hand_mask, arm, L)
        gap = self.max_gap * L + 1.0
        touching = filter_by_hand_contact(obj_cands, hand_mask, gap)
        kept, judged, verdict = self._held(touching, hand_mask, lab, skin_d2, along, L, gap)
        obj = np.any(kept, axis=0) if kept else np.zeros(shape, bool)

        def full(m):
            out = np.zeros((H, W), bool)
            if m.shape != (y1 - y0, x1 - x0):
                m = (
                    cv2.resize(
                        m.astype(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST
                    )
                    > 0
                )
            out[y0:y1, x0:x1] = m
            return out

        return Segmentation(
            hand_mask=full(hand_mask),
            object_mask=full(obj),
            has_object=bool(obj.any()),
            candidates=tuple(full(c) for c in obj_cands),
            meta={
                "crop": [x0, y0, x1, y1],
                "work_scale": s,
                "palm_length_px": L / s,
                "max_gap_px": gap / s,
                "n_candidates": len(obj_cands),
                "n_touching": len(touching),
                "n_kept": len(kept),
                "components": judged,
                "verdict": verdict,
            },
        )

    def _held(self, touching, hand, lab, skin_d2, along, L, gap):
        """Apply the held-object cues: (kept components, per-component records, verdict)."""
        hand_area = max(float(hand.sum()), 2.0 * L * L)
        hand_dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
        smooth = cv2.GaussianBlur(lab.astype(np.float32), (0, 0), 1.0)
        kept, judged = [], []
        for comp in touching:
            if comp.sum() < 0.02 * hand_area:
                judged.append(
                    {"area_ratio": round(float(comp.sum()) / hand_area, 3), "rejected": "tiny"}
                )
                continue
            cues = component_cues(comp, hand, hand_dist, along, smooth, skin_d2, L, gap, hand_area)
            why = held_object_verdict(cues, **self.verdict_args)
            judged.append({**{k: round(v, 3) for k, v in asdict(cues).items()}, "rejected": why})
            if why is None:
                kept.append(comp)
        total = sum(float(k.sum()) for k in kept) / hand_area
        if not kept:
            verdict = "no hand-touching candidate passed the cues"
        elif total < self.min_object_area:
            verdict, kept = f"object too small ({total:.2f} x hand)", []
        elif total > self.max_object_area:
            verdict, kept = f"object too large ({total:.2f} x hand): background", []
        else:
            verdict = f"held object ({total:.2f} x hand)"
        return kept, judged, verdict

    def _hand(self, img, lab, kp, L):
        shape = img.shape[:2]
        core = draw_skeleton(shape, kp, 0.08 * L, palm=False)
        wide = draw_skeleton(shape, kp, 0.3 * L, palm=True)
        samples = lab[draw_skeleton(shape, kp, 0.12 * L, palm=False)]
        if len(samples) < 10:
            samples = lab[wide]
        model = _ColourModel(samples)
        d2 = model.d2(lab)
        dist = cv2.distanceTransform((~wide).astype(np.uint8), cv2.DIST_L2, 5)
        init = np.full(shape, cv2.GC_PR_BGD, np.uint8)
        init[dist > 0.6 * L] = cv2.GC_BGD
        init[wide] = cv2.GC_PR_FGD
        init[wide & (d2 > 25.0)] = cv2.GC_PR_BGD
        palm_core = cv2.erode(
            draw_skeleton(shape, kp, 1, palm=True).astype(np.uint8),
            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (int(0.3 * L) | 1,) * 2),
        ).astype(bool)
        init[(core | palm_core) & (d2 < 9.0)] = cv2.GC_FGD
        fg = self._grabcut(img, init)
        fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
        # forearm cut: the hand model ends at the wrist
        yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
        axis = (kp[9] - kp[0]) / L
        along = (xx - kp[0, 0]) * axis[0] + (yy - kp[0, 1]) * axis[1]
        fg &= along > -0.25 * L
        keep = [c for c in _components(fg) if (c & (core | palm_core)).any()]
        hand = np.any(keep, axis=0) if keep else (fg & wide)
        return hand, core, d2

    def _objects(self, img, hand, arm, L):
        shape = img.shape[:2]
        if not hand.any():
            return []
        dist = cv2.distanceTransform((~hand).astype(np.uint8), cv2.DIST_L2, 5)
        init = np.full(shape, cv2.GC_PR_BGD, np.uint8)
        init[dist < self.near * L] = cv2.GC_PR_FGD
        b = max(2, int(0.02 * max(shape)))
        border = np.zeros(shape, bool)
        border[:b], border[-b:], border[:, :b], border[:, -b:] = True, True, True, True
        init[border] = cv2.GC_BGD
        init[arm] = cv2.GC_BGD
        init[hand] = cv2.GC_FGD
        fg = self._grabcut(img, init)
        grown = cv2.dilate(hand.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        cand = fg & ~grown & ~arm & ~self._background_like(img, border)
        k = max(3, int(0.05 * L) | 1)
        cand = cv2.morphologyEx(cand.astype(np.uint8), cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
        comps = _components(cand > 0, min_area=max(4, int(0.01 * hand.sum())))
        # regions running along the crop border are background structures (walls, faces,
        # clothes), not an object held in the hand
        ring = np.zeros(shape, bool)
        ring[: 2 * b], ring[-2 * b :], ring[:, : 2 * b], ring[:, -2 * b :] = (True,) * 4
        perim = 2 * (shape[0] + shape[1])
        return [c for c in comps if (c & ring).sum() / (2 * b) < self.max_border_share * perim]

    def _background_like(self, img: np.ndarray, border: np.ndarray) -> np.ndarray:
        """(h, w) bool: pixels within ``bg_colour_dist`` (Lab) of a crop-border colour cluster."""
        lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float32)
        samples = lab[border]
        k = min(6, len(samples))
        if k < 1:
            return np.zeros(img.shape[:2], bool)
        cv2.setRNGSeed(self.seed)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
        _, labels, centres = cv2.kmeans(samples, k, None, crit, 2, cv2.KMEANS_PP_CENTERS)
        # only clusters that are a real part of the border count (not a few stray pixels)
        share = np.bincount(labels.ravel(), minlength=k) / len(samples)
        centres = centres[share > 0.1]
        d = np.linalg.norm(lab[:, :, None, :] - centres[None, None], axis=-1).min(-1)
        return d < self.bg_colour_dist
