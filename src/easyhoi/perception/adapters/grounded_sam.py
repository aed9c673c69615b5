"""Held-object segmentation by a text-prompted detector feeding SAM, both from local folders.

The paper finds the held object with a large reasoning segmenter. This route does the same with
two open models a user may have on disk:

1. the hand mask: SAM prompted with the 21 hand keypoints (all inside the hand) and their box,
   grown by :attr:`GroundedSamSegmenter.hand_margin`;
2. the object box: the detector is asked for ``query`` ("an object held by a hand"); among its
   boxes the one kept is the best by ``detector score x exp(-d / s)``, where ``d`` is the
   distance from the grasp centre to the box (0 inside it) and ``s`` the hand's size. The grasp
   centre is the mean of the finger bases and fingertips: a held object lies between the palm
   and the fingers that close on it, whatever the photo. Boxes covering most of the photo are
   dropped (that is the scene, not a held object);
3. the object mask: SAM prompted with that box, minus the hand mask (the fingers in front of
   the object occlude it).

Each mask's confidence is SAM's own prediction of its IoU (:func:`mask_confidences`).

Prompts take precedence over the detector: an ``object_box`` replaces its box, and
``object_points`` are given to SAM as positive points (with the box when there is one); with
either, the detector is not run. ``background_points`` are given to SAM as negative points
whichever gave the box.

The detector is OWLv2 (``Owlv2ForObjectDetection``, e.g. a saved
``google/owlv2-base-patch16-ensemble``) or Grounding DINO (``GroundingDinoForObjectDetection``,
e.g. ``IDEA-Research/grounding-dino-tiny``) in transformers format with its processor; SAM as
for :mod:`easyhoi.perception.adapters.sam`. Both load with ``local_files_only=True``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from easyhoi.errors import BackendError, InvalidInputError, require
from easyhoi.perception.adapters import check_image, resolve_model_dir
from easyhoi.perception.base import HandDetection, Segmentation, register

#: Keypoints (OpenPose order) whose mean is the grasp centre: finger bases and fingertips.
GRASP_KEYPOINTS = (5, 9, 13, 17, 4, 8, 12, 16, 20)
#: Detector model types this adapter reads (config.json "model_type").
DETECTOR_TYPES = ("owlv2", "grounding-dino")


def grasp_centre(keypoints2d: np.ndarray) -> np.ndarray:
    """(2,) pixel centre of the grasp: mean of the finger bases and fingertips."""
    k = np.asarray(keypoints2d, float).reshape(-1, 2)
    return k[list(GRASP_KEYPOINTS)].mean(axis=0)


def hand_size(keypoints2d: np.ndarray) -> float:
    """The longer side of the keypoints' box, in pixels (at least 1)."""
    k = np.asarray(keypoints2d, float).reshape(-1, 2)
    return float(max(np.ptp(k[:, 0]), np.ptp(k[:, 1]), 1.0))


def box_distance(point: np.ndarray, box) -> float:
    """Distance in pixels from ``point`` (x, y) to the box (x0, y0, x1, y1); 0 inside."""
    x, y = float(point[0]), float(point[1])
    x0, y0, x1, y1 = (float(v) for v in box)
    dx = max(x0 - x, 0.0, x - x1)
    dy = max(y0 - y, 0.0, y - y1)
    return float(np.hypot(dx, dy))


def choose_box(
    boxes: np.ndarray,
    scores: np.ndarray,
    keypoints2d: np.ndarray,
    image_size: tuple[int, int],
    max_area: float = 0.9,
) -> int | None:
    """Index of the detection that is the held object (see the module docs), or None.

    Args:
        boxes: (N, 4) (x0, y0, x1, y1) pixels.
        scores: (N,) detector scores in [0, 1].
        keypoints2d: (21, 2) hand keypoints.
        image_size: (width, height).
        max_area: boxes covering more than this fraction of the photo are dropped.
    """
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    scores = np.asarray(scores, float).reshape(-1)
    if len(boxes) == 0:
        return None
    W, H = image_size
    g, s = grasp_centre(keypoints2d), hand_size(keypoints2d)
    areas = (boxes[:, 2] - boxes[:, 0]).clip(0) * (boxes[:, 3] - boxes[:, 1]).clip(0)
    dist = np.array([box_distance(g, b) for b in boxes])
    rank = scores * np.exp(-dist / s)
    rank[(areas > max_area * W * H) | (areas <= 0)] = -np.inf
    best = int(np.argmax(rank))
    return None if not np.isfinite(rank[best]) else best


def mask_confidences(
    hand_iou: float, object_iou: float | None, detector_score: float | None = None
) -> dict:
    """Confidence of the masks from SAM's predicted IoU (and the detector's score).

    SAM is trained to predict the IoU of each mask it returns with the true mask, so that
    prediction is the score. A detector score under 0.1 is named as a weak cue: the box SAM
    was given is itself a guess.
    """
    from easyhoi.perception.confidence import MaskConfidence

    def one(iou, extra=()):
        iou = float(np.clip(iou, 0.0, 1.0))
        why = [f"SAM predicts an IoU of {iou:.2f}"] if iou < 0.5 else []
        return MaskConfidence(iou, (*why, *extra))

    out = {"hand": one(hand_iou)}
    if object_iou is not None:
        weak = ()
        if detector_score is not None and detector_score < 0.1:
            weak = (f"the detector found the object box with score {detector_score:.2f} only",)
        out["object"] = one(object_iou, weak)
    return out


def _model_type(folder: Path) -> str:
    try:
        return str(json.loads((folder / "config.json").read_text()).get("model_type", ""))
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"cannot read {folder / 'config.json'}: {exc}") from None


@register("segmenter", "grounded-sam")
class GroundedSamSegmenter:
    """Text-prompted detector + SAM (:class:`~easyhoi.perception.base.HOISegmenter`).

    Args:
        detector_dir: local folder of an OWLv2 or Grounding DINO detector (transformers format).
        sam_dir: local folder of a SAM model (transformers format).
        query: what the detector is asked for.
        min_score: detections scoring below this are ignored.
        hand_margin: the hand's SAM box is the keypoint box grown by this fraction per side.
        device: torch device string.

    Attributes:
        last_detections: (boxes (N, 4), scores (N,)) of the latest detector run, or None.
    """

    def __init__(
        self,
        detector_dir: str | Path | None = None,
        sam_dir: str | Path | None = None,
        query: str = "an object held by a hand",
        min_score: float = 0.05,
        hand_margin: float = 0.15,
        device: str = "cpu",
    ):
        tf = require("transformers", extra="sam", purpose="the grounded-sam segmenter")
        import torch

        from easyhoi.perception.adapters.sam import SamAmodalSegmenter

        folder = resolve_model_dir(detector_dir, "detector", marker="config.json")
        kind = _model_type(folder)
        if kind not in DETECTOR_TYPES:
            raise InvalidInputError(
                f"'{folder}' holds a {kind or 'unknown'!r} model; the grounded-sam segmenter "
                f"reads {', '.join(DETECTOR_TYPES)} detectors"
            )
        self.sam = SamAmodalSegmenter(model_dir=sam_dir, device=device)
        self.kind = kind
        try:
            self.processor = tf.AutoProcessor.from_pretrained(folder, local_files_only=True)
            detector_cls = tf.AutoModelForZeroShotObjectDetection
            self.detector = detector_cls.from_pretrained(folder, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise BackendError(f"could not load the detector from '{folder}': {exc}") from exc
        self.detector.eval().to(device)
        self.device = torch.device(device)
        self.query = str(query)
        self.min_score = float(min_score)
        self.hand_margin = float(hand_margin)
        self.last_detections: tuple[np.ndarray, np.ndarray] | None = None

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Detections of :attr:`query`: ((N, 4) boxes in pixels, (N,) scores), best first."""
        import torch

        img = check_image(image)
        H, W = img.shape[:2]
        if self.kind == "owlv2":
            inputs = self.processor(text=[[self.query]], images=img, return_tensors="pt")
            # OWLv2 pads the photo to a square (right and bottom) before resizing: boxes are
            # fractions of the padded side
            scale = np.array([max(H, W), max(H, W)], float)
        else:  # Grounding DINO: a lower-case phrase ending with a dot; boxes are fractions
            text = self.query.lower().rstrip(".") + "."  # of the photo's width and height
            inputs = self.processor(images=img, text=text, return_tensors="pt")
            scale = np.array([W, H], float)
        inputs = {k: v.to(self.device) for k, v in inputs.items()}
        with torch.no_grad():
            out = self.detector(**inputs)
        # a box's score: its best text token (padding tokens carry -inf logits)
        scores = torch.sigmoid(out.logits[0].float()).amax(dim=-1).cpu().numpy()
        cxcywh = out.pred_boxes[0].float().cpu().numpy()
        c, wh = cxcywh[:, :2] * scale, cxcywh[:, 2:] * scale
        boxes = np.concatenate([c - wh / 2, c + wh / 2], axis=1)
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, W)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, H)
        keep = scores >= self.min_score
        order = np.argsort(-scores[keep], kind="stable")
        self.last_detections = (boxes[keep][order], scores[keep][order])
        return self.last_detections

    def segment(self, image: np.ndarray, hand: HandDetection, prompts=None) -> Segmentation:
        """Visible hand and held-object masks for ``hand`` (see the module docs)."""
        img = check_image(image)
        H, W = img.shape[:2]
        k = np.asarray(hand.keypoints2d, float).reshape(-1, 2)
        if k.shape[0] < max(GRASP_KEYPOINTS) + 1 or not np.isfinite(k).all():
            raise InvalidInputError("the grounded-sam segmenter needs the 21 hand keypoints")
        empty = np.zeros((H, W), bool)
        u0, v0 = k.min(axis=0)
        u1, v1 = k.max(axis=0)
        m = self.hand_margin * max(u1 - u0, v1 - v0, 1.0)
        hand_box = (
            max(0.0, u0 - m),
            max(0.0, v0 - m),
            min(float(W), u1 + m),
            min(float(H), v1 + m),
        )
        inside = k.clip([0, 0], [W - 1e-3, H - 1e-3])
        hand_mask = self.sam.predict(img, inside, hand_box)
        hand_score = float(np.max(self.sam.last_scores))

        points = () if prompts is None else tuple(prompts.object_points)
        box = None if prompts is None else prompts.object_box
        meta = {"query": self.query, "source": "prompts" if (points or box) else "detector"}
        if box is None and not points:
            boxes, scores = self.detect(img)
            best = choose_box(boxes, scores, k, (W, H))
            if best is None:
                meta["hand_sam_iou"] = hand_score
                conf = mask_confidences(hand_score, None)
                return Segmentation(hand_mask, empty, False, meta=meta, confidence=conf)
            box = tuple(float(v) for v in boxes[best])
            meta["detector_score"] = float(scores[best])
        # a box alone is SAM's box prompt: its centre may lie on the fingers in front
        neg = () if prompts is None else tuple(prompts.background_points)
        obj = self.sam.predict(
            img,
            np.asarray(points, float) if points else None,
            box,
            negative=np.asarray(neg, float) if neg else None,
        )
        obj &= ~hand_mask
        obj_score = float(np.max(self.sam.last_scores))
        meta.update(hand_sam_iou=hand_score, object_sam_iou=obj_score,
                    object_box=None if box is None else [float(v) for v in box])  # fmt: skip
        conf = mask_confidences(hand_score, obj_score, meta.get("detector_score"))
        return Segmentation(hand_mask, obj, bool(obj.any()), (obj,), meta, conf)
