"""Classical (model-free) hand and held-object masks from hand keypoints.

Everything runs in a working crop around the hand (side ``crop_factor`` x the hand's keypoint
extent, grown to contain any prompt), resampled so its longer side is ``work_side`` pixels;
masks are mapped back to the full image at the end.

1. Hand: this hand's colour model and GrabCut seeded by its skeleton (:mod:`.skin`).
2. Proposals: Felzenszwalb segments outside the hands, grouped hierarchically into
   hypotheses (:mod:`.proposals`); the automatic path pools the hierarchies of three scales.
3. Held object: every hypothesis is scored by grasp cues (:mod:`.held_object`); the best one is
   refined by GrabCut seeded by it. With prompts, the hypotheses are those containing the
   object points / filling the box (:mod:`.prompted`).
4. Confidence of the hand and the object masks from the same cues (:mod:`.seg_confidence`).

No hypothesis scoring above ``min_score`` means no held object (``has_object=False``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.io.image import check_image
from easyhoi.perception import held_object as ho
from easyhoi.perception import not_object, ranker
from easyhoi.perception.base import HandDetection, Segmentation, register
from easyhoi.perception.prompts import N_CHOICES, Prompts
from easyhoi.perception.proposals import Proposals, propose, propose_scales
from easyhoi.perception.seg_confidence import hand_confidence, object_confidence
from easyhoi.perception.skin import (  # noqa: F401  (re-exported: the masks' drawing helpers)
    BONES,
    PALM,
    components,
    draw_skeleton,
    fill_holes,
    hand_mask,
    palm_length,
    skin_model,
)

logger = logging.getLogger(__name__)

_components = components  # the name other perception modules import


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


def filter_by_hand_contact(
    candidates: list[np.ndarray] | tuple[np.ndarray, ...],
    hand_mask: np.ndarray,
    max_gap_px: float,
) -> list[np.ndarray]:
    """Contour-guided filtering: keep candidate components adjacent to the hand.

    Each candidate mask is split into connected components; a component is kept when some pixel
    of its contour lies within ``max_gap_px`` (Euclidean) of the hand's contour, or when it
    overlaps the hand.

    Args:
        candidates (sequence of (H, W) bool): Object candidate masks.
        hand_mask ((H, W) bool): Visible hand mask.
        max_gap_px (float): Largest allowed gap between the two contours, in pixels (>= 0).

    Returns:
        list of (H, W) bool: The kept components (possibly empty).
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


def _check_keypoints(hand: HandDetection) -> np.ndarray:
    kp = np.asarray(hand.keypoints2d, dtype=np.float64)
    if kp.shape != (21, 2) or not np.isfinite(kp).all():
        raise InvalidInputError(f"hand keypoints must be finite (21, 2), got {kp.shape}")
    return kp


def _resample(
    mask: np.ndarray,
    src: tuple[int, int, int, int],
    dst: tuple[int, int, int, int],
    size: tuple[int, int],
) -> np.ndarray:
    """``mask``, which covers the photo window ``src`` (x0, y0, x1, y1), sampled at the pixel
    centres of the window ``dst`` drawn at ``size`` (w, h) (nearest pixel; False where ``dst``
    leaves ``src``)."""
    (sx0, sy0, sx1, sy1), (dx0, dy0, dx1, dy1) = src, dst
    mh, mw = mask.shape
    xs = dx0 + (np.arange(size[0]) + 0.5) * (dx1 - dx0) / size[0]
    ys = dy0 + (np.arange(size[1]) + 0.5) * (dy1 - dy0) / size[1]
    u = np.floor((xs - sx0) * mw / (sx1 - sx0)).astype(np.int64)
    v = np.floor((ys - sy0) * mh / (sy1 - sy0)).astype(np.int64)
    ok_u, ok_v = (u >= 0) & (u < mw), (v >= 0) & (v < mh)
    out = mask[np.ix_(np.clip(v, 0, mh - 1), np.clip(u, 0, mw - 1))].copy()
    out &= ok_v[:, None] & ok_u[None, :]
    return out


@dataclass(frozen=True)
class _Work:
    """The working crop of one hand (see :meth:`ClassicalHOISegmenter._setup`)."""

    full_shape: tuple[int, int]
    crop: tuple[int, int, int, int]
    scale: float
    side: int
    prompts: Prompts | None
    clicks: bool
    img: np.ndarray
    lab: np.ndarray
    scene: ho.Scene
    excl: np.ndarray
    min_size: int
    to_work: Callable[[np.ndarray], np.ndarray]

    @property
    def inside(self) -> tuple[bool, bool, bool, bool]:
        """Whether the photo goes on beyond the crop's left, top, right and bottom side."""
        (x0, y0, x1, y1), (H, W) = self.crop, self.full_shape
        return (x0 > 0, y0 > 0, x1 < W, y1 < H)


@register("segmenter", "classical")
class ClassicalHOISegmenter:
    """Hand mask from the skeleton; held object by ranked region proposals.

    Args:
        crop_factor (float): Working crop side as a multiple of the hand's keypoint extent (at least
            2 palm lengths).
        work_side (int): Longer side of the working crop in pixels (speed / quality trade-off).
        segment_scale (float): Felzenszwalb scale at ``work_side`` (larger: fewer, bigger base
            segments).
        min_score (float): Best hypothesis score below which the hand holds no object.
        click_side (int): Longer side of the working crop when the prompts are object points
            only: the clicked object is grown from the points by GrabCut at this resolution
            (thin objects need the detail), and the region proposals are only computed when
            GrabCut collapses.
        box_side (int): Longer side of the window (the box grown by half its size) in which an
            object box is cut by GrabCut on its own (a small box seen in detail).
        refine_top (int): Number of best distinct hypotheses refined by GrabCut and scored again.
        iterations (int): GrabCut iterations.
        seed (int): Seed of OpenCV's RNG for the k-means runs that start GrabCut's colour
            models (:func:`~easyhoi.perception.skin.gmm_model`).
        auto_scales (tuple of float): Felzenszwalb scales whose hierarchies are pooled on the
            automatic path (fine: small objects stay apart; coarse: textured objects stay whole).
        rank_top (int): Hypotheses (best by the cheap cues) that get the cues needing the mask
            drawn (contrast, solidity) before the final ranking.
    """

    #: The automatic path numbers its best distinct object regions, and ``--object-choice K``
    #: takes region K (:attr:`Segmentation.candidates` holds them, the chosen one first); with
    #: object points, the regions are the first point's distinct candidates, the best first.
    offers_choices = True

    def __init__(
        self,
        crop_factor: float = 3.0,
        work_side: int = 256,
        segment_scale: float = 150.0,
        min_score: float = 1.0,
        iterations: int = 5,
        click_side: int = 384,
        box_side: int = 384,
        refine_top: int = 1,
        seed: int = 0,
        auto_scales: tuple[float, ...] = (100.0, 300.0, 600.0),
        rank_top: int = ranker.RANK_TOP,
    ):
        self.auto_scales = tuple(float(v) for v in auto_scales)
        self.rank_top = int(rank_top)
        self.refine_top = int(refine_top)
        self.click_side = int(click_side)
        self.box_side = int(box_side)
        self.crop_factor = float(crop_factor)
        self.work_side = int(work_side)
        self.segment_scale = float(segment_scale)
        self.min_score = float(min_score)
        self.iterations = int(iterations)
        self.seed = int(seed)

    # -- crop ----------------------------------------------------------------------------------
    def _crop(self, shape, kp, prompts: Prompts | None, work_side: int):
        h, w = shape
        lo, hi = kp.min(0), kp.max(0)
        c = (lo + hi) / 2
        side = self.crop_factor * max(float((hi - lo).max()), 2.0 * palm_length(kp))
        x0, y0, x1, y1 = c[0] - side / 2, c[1] - side / 2, c[0] + side / 2, c[1] + side / 2
        if prompts is not None:
            pts = [*prompts.object_points[:1]]
            if prompts.object_box is not None:
                bx0, by0, bx1, by1 = prompts.object_box
                pts += [(bx0, by0), (bx1, by1)]
            L = palm_length(kp)
            if pts:  # the prompted object and a margin around it: a clicked object may reach
                # a few palm lengths from the click
                p = np.asarray(pts, dtype=np.float64)
                m = max(0.25 * side, 3.0 * L)
                x0, y0 = min(x0, p[:, 0].min() - m), min(y0, p[:, 1].min() - m)
                x1, y1 = max(x1, p[:, 0].max() + m), max(y1, p[:, 1].max() + m)
            if len(prompts.object_points) > 1:  # further points: inside, with a palm length
                # around them; they add parts to the first point's object without re-framing it
                p = np.asarray(prompts.object_points[1:], dtype=np.float64)
                x0, y0 = min(x0, p[:, 0].min() - L), min(y0, p[:, 1].min() - L)
                x1, y1 = max(x1, p[:, 0].max() + L), max(y1, p[:, 1].max() + L)
        x0, y0 = int(max(0, x0)), int(max(0, y0))
        x1, y1 = int(min(w, np.ceil(x1))), int(min(h, np.ceil(y1)))
        if x1 - x0 < 8 or y1 - y0 < 8:
            raise InvalidInputError(f"hand keypoints {lo}..{hi} lie outside the {w}x{h} image")
        s = work_side / max(x1 - x0, y1 - y0)
        return (x0, y0, x1, y1), s

    # -- main ----------------------------------------------------------------------------------
    def segment(
        self,
        image: np.ndarray,
        hand: HandDetection,
        prompts: Prompts | None = None,
        others: tuple[HandDetection, ...] | list[HandDetection] = (),
    ) -> Segmentation:
        """Masks for ``hand`` in an (H, W, 3) uint8 RGB image; all outputs (H, W) bool.

        ``prompts`` (object points / box, in photo pixels) make the object the region that
        contains the points / fills the box; ``others`` are the other detected hands (never
        part of the object).
        """
        from easyhoi.perception.prompted import clicked_object, prompted_object

        w = self._setup(image, hand, prompts, others)
        prompts, clicks = w.prompts, w.clicks
        img, scene, to_work, shape = w.img, w.scene, w.to_work, w.img.shape[:2]
        H, W = w.full_shape
        (x0, y0, x1, y1), s = w.crop, w.scale
        hand_m, kp, d2, L, excl = scene.hand, scene.kp, scene.skin_d2, scene.palm, w.excl
        prompted = prompts is not None and prompts.has_object_prompt

        def proposals():
            return self._prompt_proposals(w)

        props, click_margin, box_agreement, choices = None, None, None, []
        if clicks:
            obj, hyp, best, props, click_margin, regions = clicked_object(
                img,
                scene,
                to_work(prompts.object_points),
                proposals,
                self.iterations,
                self.seed,
                inside=w.inside,
                choice=prompts.object_choice or 1,
            )
            has_object = bool(obj.any())
            # the point's other regions, numbered for --object-choice K (the object among them)
            choices = [(k, m & ~excl) for k, m in enumerate(regions)] if len(regions) > 1 else []
        elif prompted:
            props = proposals()
            pts = to_work(prompts.object_points) if prompts.object_points else np.zeros((0, 2))
            box = None
            if prompts.object_box is not None:
                b = to_work(np.reshape(prompts.object_box, (2, 2)))
                box = (b[0, 0], b[0, 1], b[1, 0], b[1, 1])
            obj, hyp, best, box_agreement = prompted_object(
                img, props, scene, pts, box, self.iterations, self.seed,
                box_cut=None if prompts.object_box is None else lambda: self._box_cut(image, w),
            )  # fmt: skip
            has_object = bool(obj.any())
        else:
            props = self._auto_proposals(w)
            hyp = ranker.rank(props, scene, self.rank_top) if props.regions else None
            if hyp is not None:  # never a region around a background point
                hyp.scores[not_object.enclosing_regions(props, scene.background_rings)] = -np.inf
            best, obj = None, np.zeros(shape, bool)
            if hyp is not None and np.isfinite(hyp.scores).any():
                best, obj, hyp = self._refine_best(img, props, scene, hyp, excl)
            # the hand holds something when some ranked region has the evidence of a held
            # object, whichever the ranking chose
            has_object = best is not None and float(np.max(hyp.evidence)) >= self.min_score
            if not has_object:
                obj = np.zeros(shape, bool)
            choices = self._choices(props, hyp, best, obj, excl)
            picked = None if prompts is None else prompts.object_choice
            if picked is not None:
                best, obj = self._pick(img, props, scene, hyp, choices, picked, excl)
                has_object = prompted = bool(obj.any())
        if prompted and prompts.object_box is None:
            # the user clicked the object: what the object took from the hand mask is object
            hand_m &= ~obj
        obj &= ~hand_m
        runner = ho.runner_up(hyp, best) if (hyp is not None and best is not None) else None
        # a further point is the fix for an unsure first one: the margin counts for one alone
        one_click_margin = click_margin if clicks and len(prompts.object_points) == 1 else None
        point_skin = None
        if prompted and prompts.object_points:
            from easyhoi.perception.click import point_skin as skin_at

            point_skin = max(skin_at(scene, p) for p in to_work(prompts.object_points))
        conf = {
            "hand": hand_confidence(hand, hand_m, kp, d2),
            "object": object_confidence(
                hyp,
                best,
                runner,
                has_object,
                prompted,
                self.min_score,
                one_click_margin,
                box_agreement,
                point_skin,
            ),
        }

        def full(m):
            out = np.zeros((H, W), bool)
            out[y0:y1, x0:x1] = (
                cv2.resize(m.astype(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
                > 0
            )
            return out

        top = []
        if hyp is not None:
            for i in np.argsort(-hyp.scores, kind="stable")[:5]:
                if np.isfinite(hyp.scores[i]):
                    top.append({"score": round(float(hyp.scores[i]), 3), **hyp.cue(int(i))})
        return Segmentation(
            hand_mask=full(hand_m),
            object_mask=full(obj),
            has_object=has_object,
            candidates=tuple(full(m) for _, m in choices),
            confidence=conf,
            meta={
                "crop": [x0, y0, x1, y1],
                "work_scale": s,
                "palm_length_px": L / s,
                "n_segments": None if props is None else props.n_base,
                "n_hypotheses": None if props is None else len(props.regions),
                "prompted": prompted,
                "score": None if best is None else round(float(hyp.scores[best]), 3),
                "evidence": None if best is None else round(hyp.strength(best), 3),
                "margin": None
                if runner is None or best is None
                else round(hyp.strength(best) - hyp.strength(runner), 3),
                "hypotheses": top,
                "object_choice": None if prompts is None else prompts.object_choice,
            },
        )

    def _choices(self, props, hyp, best, obj, excl) -> list[tuple[int, np.ndarray]]:
        """The automatic path's object regions a user may pick (``--object-choice K``): up to
        :data:`N_CHOICES` distinct ranked hypotheses, best first, as ``(index, mask)`` in the
        working crop. The first is the chosen one as refined (when there is one); the others
        are the regions as proposed, refined only when picked (:meth:`_pick`)."""
        if hyp is None or not np.isfinite(hyp.scores).any():
            return []
        out = [] if best is None or not obj.any() else [(best, obj)]
        # the best, when there is one, is among the distinct ones, which overlap it little
        for i in ho.distinct_best(hyp, N_CHOICES + 1):
            if len(out) == N_CHOICES:
                break
            if i == best:
                continue
            m = props.mask(props.regions[i]) & ~excl
            if m.any():
                out.append((i, m))
        return out

    def _pick(self, img, props, scene, hyp, choices, k, excl) -> tuple[int, np.ndarray]:
        """Choice ``k`` (1-based) of :meth:`_choices`, refined as the automatic choice is."""
        if k > len(choices):
            raise InvalidInputError(
                f"--object-choice {k}: the automatic path found {len(choices)} object "
                f"region(s) for this hand (masks.png numbers them)"
            )
        i, m = choices[k - 1]
        if k == 1:
            return i, m
        refined = fill_holes(ho.refine(img, m, excl, self.iterations, self.seed)) & ~excl
        if refined.any() and not not_object.encloses(refined, scene.background_rings):
            m = refined
        hyp.cues[i] = ho.mask_cues(m, scene)
        return i, m

    def _setup(self, image, hand, prompts, others) -> _Work:
        """The working crop of ``hand``: image, Lab, hand mask, the other hands, the scene."""
        image = check_image(image)
        H, W = image.shape[:2]
        kp_full = _check_keypoints(hand)
        if prompts is not None:
            prompts = prompts.check(W, H)
        clicks = prompts is not None and bool(prompts.object_points) and prompts.object_box is None
        side = self.click_side if clicks else self.work_side
        (x0, y0, x1, y1), s = self._crop((H, W), kp_full, prompts, side)
        cw, ch = max(8, round((x1 - x0) * s)), max(8, round((y1 - y0) * s))
        interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
        img = np.ascontiguousarray(cv2.resize(image[y0:y1, x0:x1], (cw, ch), interpolation=interp))
        sx, sy = cw / (x1 - x0), ch / (y1 - y0)

        def to_work(p):
            return (np.asarray(p, dtype=np.float64).reshape(-1, 2) - [x0, y0]) * [sx, sy]

        kp = to_work(kp_full)
        L = palm_length(kp)
        shape = img.shape[:2]
        lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float64)
        d2 = skin_model(lab, kp).d2(lab)
        disks = None
        if prompts is not None and prompts.has_object_prompt and prompts.object_points:
            # the user's object points are not the hand
            disks = np.zeros(shape, np.uint8)
            for u, v in to_work(prompts.object_points):
                cv2.circle(disks, (int(round(u)), int(round(v))), max(2, int(0.05 * L)), 1, -1)
            disks = disks.astype(bool)
        hand_m = hand_mask(img, lab, kp, d2, self.iterations, self.seed, not_hand=disks)
        other = np.zeros(shape, bool)
        for o in others:
            ko = to_work(_check_keypoints(o))
            other |= draw_skeleton(shape, ko, 0.3 * palm_length(ko), palm=True)
        other &= ~hand_m
        rings = ()
        if prompts is not None and prompts.background_points:
            # the user's background points: never the object, like the other hands
            bg = not_object.disks(shape, to_work(prompts.background_points), L)
            rings = not_object.rings(bg, hand_m | other)
            for d in bg:
                other |= not_object.patch(lab, d, L) & ~hand_m
        scene = ho.Scene(
            lab=lab, hand=hand_m, kp=kp, skin_d2=d2, other_hands=other, background_rings=rings
        )
        return _Work(
            full_shape=(H, W),
            crop=(x0, y0, x1, y1),
            scale=s,
            side=side,
            prompts=prompts,
            clicks=clicks,
            img=img,
            lab=lab,
            scene=scene,
            excl=hand_m | other,
            min_size=max(8, int((0.12 * L) ** 2)),
            to_work=to_work,
        )

    def _box_cut(self, image: np.ndarray, w: _Work) -> np.ndarray:
        """GrabCut of the user's box at the box's own resolution
        (:func:`easyhoi.perception.prompted.box_grabcut`), in working-crop pixels."""
        from easyhoi.perception.prompted import box_grabcut

        pts = np.asarray(w.prompts.object_points, np.float64).reshape(-1, 2)

        def excl_at(win, size):
            return _resample(w.excl, w.crop, win, size)

        win, m = box_grabcut(
            image, w.prompts.object_box, pts, excl_at, self.box_side, self.iterations, self.seed
        )
        h, wd = w.img.shape[:2]
        return _resample(m, win, w.crop, (wd, h))

    def _prompt_proposals(self, w: _Work) -> Proposals:
        """Hypotheses of the prompted paths: one hierarchy at :attr:`segment_scale`."""
        return propose(
            w.img,
            w.lab,
            w.excl,
            self.segment_scale * w.side / self.work_side,
            w.min_size,
            max_size=4.0 * ho.AREA_RANGE[1] * w.scene.hand_area,
        )

    def click_candidates(
        self,
        image: np.ndarray,
        hand: HandDetection,
        point: tuple[float, float],
        others: tuple[HandDetection, ...] | list[HandDetection] = (),
    ) -> tuple[tuple[int, int, int, int], list[tuple[np.ndarray, float]]]:
        """The working crop (x0, y0, x1, y1) in photo pixels and every candidate the one-click
        path scores for the object point ``point`` (x, y, photo pixels) of ``hand``: (mask in
        crop pixels, score) pairs, best score first, each finished as the click finishes the one
        it keeps (what the hand mask took of it given back, its outline settled by GrabCut), so
        that the first one is the click's object mask. Used to measure how good the best
        candidate is, whichever the scoring picks."""
        from easyhoi.perception.click import click_proposals, finish_candidate, scored_candidates

        w = self._setup(image, hand, Prompts(object_points=(tuple(point),)), others)
        h, wd = w.img.shape[:2]
        p = np.clip(w.to_work([point])[0], 0, [wd - 1, h - 1])
        regions = click_proposals(w.img, w.scene, p, self._prompt_proposals(w))
        scored = scored_candidates(w.img, w.scene, p, regions, self.iterations, self.seed, w.inside)
        order = sorted(range(len(scored)), key=lambda i: -scored[i][0])
        return w.crop, [
            (finish_candidate(w.img, w.scene, scored[i][2], p, self.iterations, self.seed),
             float(scored[i][0]))
            for i in order
        ]  # fmt: skip

    def _auto_proposals(self, w: _Work) -> Proposals:
        """Hypotheses of the automatic path: the pooled hierarchies of :attr:`auto_scales`."""
        return propose_scales(
            w.img,
            w.lab,
            w.excl,
            self.auto_scales,
            w.min_size,
            max_size=4.0 * ho.AREA_RANGE[1] * w.scene.hand_area,
        )

    def automatic_hypotheses(
        self,
        image: np.ndarray,
        hand: HandDetection,
        others: tuple[HandDetection, ...] | list[HandDetection] = (),
    ) -> tuple[tuple[int, int, int, int], Proposals]:
        """The working crop (x0, y0, x1, y1) in photo pixels and every hypothesis the automatic
        path ranks for ``hand`` (in crop pixels, resampled to ``work_side``). Used to measure
        how good the best hypothesis is, whichever the ranking picks."""
        w = self._setup(image, hand, None, others)
        return w.crop, self._auto_proposals(w)

    def _refine_best(self, img, props, scene, hyp, excl):
        """Refine the ``refine_top`` best distinct hypotheses by GrabCut (its colour mixtures
        gather the parts of a textured object that the proposals split) and keep the best
        ranked one that GrabCut leaves non-empty. Returns (index, refined mask, hypotheses with
        the refined masks' cues and held-object evidence)."""
        cues, scores = hyp.cues.copy(), hyp.scores.copy()
        evidence = hyp.scores.copy() if hyp.evidence is None else hyp.evidence.copy()
        masks = {}
        for i in ho.distinct_best(hyp, self.refine_top):
            raw = props.mask(props.regions[i])
            m = fill_holes(ho.refine(img, raw, excl, self.iterations, self.seed)) & ~excl
            if not m.any() or not_object.encloses(m, scene.background_rings):
                continue
            # the refined mask's cues and held-object evidence; its ranking score stays the
            # hypothesis's (the ranking and its margin judge the proposals, GrabCut only
            # adjusts the chosen one's outline)
            cues[i] = ho.mask_cues(m, scene)
            evidence[i] = ho.score(cues[i][None])[0]
            masks[i] = m
        out = ho.Hypotheses(props, cues, scores, evidence)
        if not masks:
            return None, np.zeros(img.shape[:2], bool), out
        best = max(masks, key=lambda i: scores[i])
        return best, masks[best], out
