"""Offline hand keypoints with MediaPipe Hands (the model files ship inside the mediapipe wheel).

Two passes:

1. MediaPipe's own pipeline (palm detector -> landmark model), ``static_image_mode=True``. When
   it (or pass 2, when it runs) finds fewer than ``max_hands`` hands, the same pipeline runs on
   the left-right mirrored photo and the hands it finds that are not already found (keypoint
   centres more than half a hand apart) are added, mapped back (:func:`unmirror`). Why: the
   palm detector is a network, not a mirror-symmetric one, and a hand it misses at the edge of
   its confidence (seen side-on, gripping a bottle, partly hidden) is often one it finds
   mirrored. On the development photos the first run misses 6 of the 50 hands that hold the
   object; the mirrored run finds 2 of them (the only holding hand of `ihoi-demo_05`, the knife
   hand of `ihoi-demo_09`) and no hand that is not there. One more palm-pipeline run per photo
   (about 0.04 s CPU).
2. When the palm detector finds nothing (gloves, grey-scale photos, hands cut by the object), an
   ROI search: the landmark model alone is run on square windows over a grid of positions, three
   sizes (the largest the whole photo) and four rotations (the landmark model reports a hand only
   when its own presence score exceeds 0.5). Every hit is refined twice by re-cropping around its
   own landmarks (as MediaPipe's tracking does between frames), hits are clustered by keypoint
   centre, and each cluster with enough votes becomes one hand. The window grid is
   deterministic.

Conventions of the output (:class:`~easyhoi.perception.base.HandDetection`):

- ``keypoints2d``: MediaPipe's 21 landmarks already follow the OpenPose order of
  :data:`easyhoi.structures.KEYPOINT_NAMES` (wrist; thumb CMC, MCP, IP, tip; index MCP, PIP, DIP,
  tip; middle; ring; pinky), so the mapping is the identity; pixel units of the input image.
- ``keypoints3d``: ``hand_world_landmarks`` in metres, origin at MediaPipe's hand centre. They are
  already expressed with the image axes (x right, y down, z away from the camera), i.e. the
  camera-aligned frame; no axis flip is applied (verified in the tests by fitting the
  orthographic projection of the 3D points to the 2D keypoints).
- ``side``: MediaPipe's handedness label assumes a mirrored (selfie) image. For ordinary photos
  the label is swapped (verified on the shared photos: the left hand holding the reusable cup is
  labelled "Right" by MediaPipe). Pass ``mirrored=True`` for selfie-mirrored input.
- ``score``: MediaPipe exposes no detection score in this API; the handedness probability is
  used, halved for hands found only by the ROI search (``meta["pass"]`` says which pass).

Per-keypoint confidence (:meth:`MediaPipeHands.keypoint_confidence`): the landmark model gives
none, so it is measured. The model is run again on crops around the detected hand that are
rotated, scaled and shifted a little (:data:`CONFIDENCE_CROPS`); a keypoint the model has
located from clear evidence stays where it is, one it guesses (hidden behind the object or the
other fingers, blurred, cut off) moves with the crop. The spread of a keypoint (the median
distance of its positions to their median, over the hand's size) becomes the confidence
``1 / (1 + (spread / SPREAD_SCALE)^2)``. On the development photos with reference keypoints the
spread correlates with the detector's error joint by joint (correlation +0.44 on average over 13
photos; the wrist and the thumb's base, which the palm hides in many grasps, spread most), and
a detection that swapped the thumb and the fingers has a median confidence of 0.20 against
0.64-0.93 on the others.

A second look (:meth:`MediaPipeHands.mirrored_look`): the palm detector and the landmark model
are not mirror-symmetric networks, so the mirrored photo is a second, partly independent look at
the same hand. A skeleton the model only guesses in the photo (a low median confidence) may be
one it locates firmly in the mirrored photo; the chain fits the hand to whichever of the two
is steadier under the same crop changes (``perception.chain.second_look``; the masks stay those
of the first look). On the development photos the look runs for 3 of 54 hands: for the swapped
skeleton above the mirrored photo gives the thumb on the right side with a median confidence of
0.90 (mean error to the reference keypoints 58 px instead of 119 px); for the other two it
finds no steadier skeleton and nothing changes.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import math
import sys
import threading

import numpy as np

from easyhoi.errors import BackendError, InvalidInputError, MissingDependencyError
from easyhoi.io.image import check_image
from easyhoi.io.native_output import silenced
from easyhoi.perception.base import HandDetection, register

logger = logging.getLogger(__name__)

#: MediaPipe landmark index -> OpenPose keypoint index (identity: same order).
MEDIAPIPE_TO_OPENPOSE = tuple(range(21))

#: ROI search windows: side as a fraction of the image's longer side, and rotations (radians).
#: Windows overlap by half their side; the largest is the whole photo, for a photo cropped to the
#: hand (as hand-object datasets crop their frames), whose hand no smaller window contains. The
#: landmark model finds a hand that lies within about 45 degrees of its window's upright, and
#: hands are photographed at every angle (fingers down when a cup is held by its rim or a bag is
#: carried), so the windows are turned by quarter turns: upright, both sideways and upside down.
_ROI_SIZES = (0.35, 0.6, 1.0)
_ROI_ROTATIONS = (0.0, math.pi / 2, -math.pi / 2, math.pi)

#: Crops of the confidence measure, relative to MediaPipe's own crop around the hand:
#: (rotation in radians, scale of the side, shift along x and y in units of the side).
CONFIDENCE_CROPS = (
    (-0.3, 1.0, 0.0, 0.0), (-0.15, 1.0, 0.0, 0.0), (0.15, 1.0, 0.0, 0.0), (0.3, 1.0, 0.0, 0.0),
    (0.0, 0.85, 0.0, 0.0), (0.0, 1.15, 0.0, 0.0),
    (0.0, 1.0, 0.06, 0.0), (0.0, 1.0, -0.06, 0.0), (0.0, 1.0, 0.0, 0.06), (0.0, 1.0, 0.0, -0.06),
)  # fmt: skip
#: Spread (fraction of the hand's size) at which a keypoint's confidence is one half: about
#: half a finger's width, the distance at which a keypoint lands on another part of the hand.
SPREAD_SCALE = 0.05
#: Fewest crops (of :data:`CONFIDENCE_CROPS`) in which the model must find the hand again for
#: the spread to be measured at all.
MIN_CONFIDENCE_CROPS = 5

_ROI_GRAPH = """
input_stream: "image"
input_stream: "roi"
output_stream: "landmarks"
output_stream: "world_landmarks"
output_stream: "handedness"
node {
  calculator: "HandLandmarkCpu"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  input_side_packet: "MODEL_COMPLEXITY:model_complexity"
  output_stream: "LANDMARKS:landmarks"
  output_stream: "WORLD_LANDMARKS:world_landmarks"
  output_stream: "HANDEDNESS:handedness"
}
"""


#: MediaPipe graphs built in this process, by kind and settings. Building one loads its
#: TFLite models (about 0.08 s CPU); with ``static_image_mode`` a graph keeps no state between
#: images (each image is detected from scratch, tested: the same keypoints from a fresh and a
#: reused graph), so every detector of a process (one per photo) shares them. A graph runs one
#: image at a time: calls are serialised by ``_GRAPH_LOCK``.
_GRAPHS: dict[tuple, object] = {}
_GRAPH_LOCK = threading.RLock()


def _shared_graph(key: tuple, build):
    with _GRAPH_LOCK:
        if key not in _GRAPHS:
            _GRAPHS[key] = build()
        return _GRAPHS[key]


#: Packages whose ``__init__`` only gathers convenience names: ``mediapipe`` imports every
#: solution and the tasks API, ``mediapipe.python.solutions`` every solution, among them the
#: drawing utilities, which import ``matplotlib.pyplot`` (together 0.5-0.6 s CPU, against 0.05 s
#: for the modules the detector uses).
_LEAN_PACKAGES = ("mediapipe", "mediapipe.python.solutions")
_IMPORT_LOCK = threading.RLock()
#: Specs of the packages registered without running their ``__init__`` (name -> spec).
_PENDING_INIT: dict[str, object] = {}


def _run_init(name: str) -> None:
    """Run the ``__init__`` of a package imported lean, in place (once)."""
    with _IMPORT_LOCK:
        spec = _PENDING_INIT.pop(name, None)
        if spec is None:
            return
        module = sys.modules[name]
        module.__dict__.pop("__getattr__", None)
        if name == "mediapipe":  # the real import order: every solution, then the package
            _run_init("mediapipe.python.solutions")
        spec.loader.exec_module(module)


def _complete(name: str):
    """Module ``__getattr__`` of a package imported lean: on the first name it lacks, its
    ``__init__`` runs, then the name is looked up again."""

    def __getattr__(attr: str):
        _run_init(name)
        return getattr(sys.modules[name], attr)

    return __getattr__


def mediapipe_module(name: str):
    """Import ``name`` from the mediapipe wheel without the package-level ``__init__`` files.

    In a process that has not imported ``mediapipe`` yet, ``mediapipe`` and
    ``mediapipe.python.solutions`` are registered from their specs without running their
    ``__init__`` (which only import every solution, the drawing utilities with matplotlib, and the
    tasks API), then ``name`` is imported normally. Their ``__init__`` still runs, in place,
    the first time code asks either package for a name it lacks (``mediapipe.solutions``,
    ``mediapipe.__version__``...), so other users of the package see it whole.

    Raises:
        MissingDependencyError: mediapipe is not installed.
    """
    try:
        with _IMPORT_LOCK:
            if "mediapipe" not in sys.modules:
                _register_lean()
        return importlib.import_module(name)
    except ImportError as exc:
        raise MissingDependencyError("mediapipe", None, "hand keypoint detection") from exc


def _register_lean() -> None:
    registered = []
    try:
        for pkg in _LEAN_PACKAGES:
            spec = importlib.util.find_spec(pkg)
            if spec is None or spec.loader is None:
                raise ImportError(f"no module named {pkg!r}")
            module = importlib.util.module_from_spec(spec)
            module.__getattr__ = _complete(pkg)
            sys.modules[pkg] = module
            _PENDING_INIT[pkg] = spec
            registered.append(pkg)
            parent, _, child = pkg.rpartition(".")
            if parent:
                setattr(sys.modules[parent], child, module)
    except BaseException:
        for pkg in registered:
            sys.modules.pop(pkg, None)
            _PENDING_INIT.pop(pkg, None)
        raise


def landmark_pixels(landmarks, width: int, height: int) -> np.ndarray:
    """(21, 2) pixel keypoints in OpenPose order from MediaPipe's normalised landmarks."""
    kp = np.array([[p.x * width, p.y * height] for p in landmarks.landmark], dtype=np.float64)
    return kp[list(MEDIAPIPE_TO_OPENPOSE)]


def roi_from_keypoints(kp: np.ndarray, width: int, height: int) -> tuple[float, ...]:
    """Square, rotated crop around (21, 2) pixel keypoints, fingers pointing up in the crop.

    Returns (x_center, y_center, width, height, rotation) normalised as in MediaPipe's
    ``NormalizedRect`` (rotation clockwise, radians).
    """
    v = kp[9] - kp[0]  # wrist -> middle MCP
    rot = math.pi / 2 - math.atan2(-v[1], v[0])
    rot = (rot + math.pi) % (2 * math.pi) - math.pi
    c, s = math.cos(rot), math.sin(rot)
    # rotate points into the crop frame (the inverse of the crop rotation)
    R = np.array([[c, s], [-s, c]])
    q = kp @ R.T
    lo, hi = q.min(0), q.max(0)
    centre_q = (lo + hi) / 2
    size = 2.0 * float((hi - lo).max())
    centre_q = centre_q + np.array([0.0, -0.1 * size])  # shift towards the fingers
    centre = centre_q @ R  # back to the image frame
    return (centre[0] / width, centre[1] / height, size / width, size / height, rot)


def unmirror(d: HandDetection, width: int) -> HandDetection:
    """A detection made in the left-right mirrored photo (``width`` pixels wide), in the photo:
    x -> width - x for the 2D keypoints (pixel centres at half-integers), x -> -x for the
    camera-aligned 3D keypoints, the side swapped."""
    k = np.asarray(d.keypoints2d, dtype=np.float64).copy()
    k[:, 0] = width - k[:, 0]
    k3 = None if d.keypoints3d is None else np.asarray(d.keypoints3d) * [-1.0, 1.0, 1.0]
    side = {"left": "right", "right": "left"}[d.side]
    meta = {**d.meta, "pass": f"mirrored {d.meta.get('pass', '')}".strip()}
    return HandDetection(k, k3, side, d.score, meta=meta)


def same_hand(a: HandDetection, b: HandDetection) -> bool:
    """Two detections of one hand: their keypoint centres lie within half the hand's size (the
    larger side of the keypoints' box, the larger of the two: a skeleton the model guesses is
    often shrunk)."""
    ka = np.asarray(a.keypoints2d, dtype=np.float64).reshape(-1, 2)
    kb = np.asarray(b.keypoints2d, dtype=np.float64).reshape(-1, 2)
    size = max(float(np.ptp(ka, axis=0).max()), float(np.ptp(kb, axis=0).max()))
    return float(np.linalg.norm(ka.mean(axis=0) - kb.mean(axis=0))) < 0.5 * size


@register("hand", "mediapipe")
class MediaPipeHands:
    """MediaPipe Hands keypoint detector (offline, CPU, deterministic).

    Args:
        max_hands (int): Most hands returned.
        min_detection_confidence (float): Palm-detector threshold of pass 1.
        model_complexity (int): 0 (lite) or 1 (full) landmark model.
        roi_search (bool): Run pass 2 (ROI search) when pass 1 finds no hand.
        mirror_pass (bool): When passes 1 and 2 find fewer than ``max_hands`` hands, run the
            palm pipeline again on the left-right mirrored photo and add the hands it finds
            that they did not (see the module notes).
        mirrored (bool): The input is a mirrored selfie image (keep MediaPipe's handedness label).
    """

    def __init__(
        self,
        max_hands: int = 2,
        min_detection_confidence: float = 0.3,
        model_complexity: int = 1,
        roi_search: bool = True,
        mirror_pass: bool = True,
        mirrored: bool = False,
    ):
        if model_complexity not in (0, 1):
            raise InvalidInputError(f"model_complexity must be 0 or 1, got {model_complexity}")
        if max_hands < 1:
            raise InvalidInputError(f"max_hands must be >= 1, got {max_hands}")
        self._hands_api = mediapipe_module("mediapipe.python.solutions.hands")
        self.max_hands = int(max_hands)
        self.min_detection_confidence = float(min_detection_confidence)
        self.model_complexity = int(model_complexity)
        self.roi_search = bool(roi_search)
        self.mirror_pass = bool(mirror_pass)
        self.mirrored = bool(mirrored)
        self._hands = None
        self._roi = None

    # -- helpers -------------------------------------------------------------------------------
    def _side(self, label: str) -> str:
        label = label.lower()
        if label not in ("left", "right"):
            raise BackendError(f"unexpected MediaPipe handedness label {label!r}")
        if self.mirrored:
            return label
        return "left" if label == "right" else "right"

    def _make(self, lms, wlms, handed, w: int, h: int, pass_name: str, **meta) -> HandDetection:
        kp = landmark_pixels(lms, w, h)
        k3 = None
        if wlms is not None:
            k3 = np.array([[p.x, p.y, p.z] for p in wlms.landmark], dtype=np.float64)
            k3 = k3[list(MEDIAPIPE_TO_OPENPOSE)]
        cls = handed.classification[0]
        score = float(cls.score) * (1.0 if pass_name == "palm" else 0.5)
        rel_z = [float(p.z) for p in lms.landmark]
        return HandDetection(
            keypoints2d=kp,
            keypoints3d=k3,
            side=self._side(cls.label),
            score=score,
            meta={"pass": pass_name, "mediapipe_label": cls.label, "relative_z": rel_z, **meta},
        )

    # -- pass 1 --------------------------------------------------------------------------------
    def _palm_pass(self, image: np.ndarray) -> list[HandDetection]:
        if self._hands is None:
            key = ("palm", self.max_hands, self.model_complexity, self.min_detection_confidence)
            self._hands = _shared_graph(
                key,
                lambda: self._hands_api.Hands(
                    static_image_mode=True,
                    max_num_hands=self.max_hands,
                    model_complexity=self.model_complexity,
                    min_detection_confidence=self.min_detection_confidence,
                ),
            )
        h, w = image.shape[:2]
        with _GRAPH_LOCK:
            res = self._hands.process(image)
        if not res.multi_hand_landmarks:
            return []
        worlds = res.multi_hand_world_landmarks or [None] * len(res.multi_hand_landmarks)
        return [
            self._make(lm, wl, hd, w, h, "palm")
            for lm, wl, hd in zip(
                res.multi_hand_landmarks, worlds, res.multi_handedness, strict=False
            )
        ]

    # -- pass 2 --------------------------------------------------------------------------------
    def _run_roi(self, image: np.ndarray, roi: tuple[float, ...]):
        rect_pb2 = mediapipe_module("mediapipe.framework.formats.rect_pb2")
        solution_base = mediapipe_module("mediapipe.python.solution_base")

        if self._roi is None:
            self._roi = _shared_graph(
                ("roi", self.model_complexity),
                lambda: solution_base.SolutionBase(
                    graph_config=_ROI_GRAPH,
                    side_inputs={"model_complexity": self.model_complexity},
                ),
            )
        x, y, rw, rh, rot = roi
        rect = rect_pb2.NormalizedRect(x_center=x, y_center=y, width=rw, height=rh, rotation=rot)
        with _GRAPH_LOCK:
            out = self._roi.process({"image": image, "roi": rect})
        if out.landmarks is None:
            return None
        return out

    def _roi_pass(self, image: np.ndarray) -> list[HandDetection]:
        h, w = image.shape[:2]
        m = float(max(h, w))
        hits = []
        for frac in _ROI_SIZES:
            side = frac * m
            nx = max(2, int(math.ceil(w / (0.5 * side))) - 1)
            ny = max(2, int(math.ceil(h / (0.5 * side))) - 1)
            for cy in np.linspace(side / 2, h - side / 2, ny) if h > side else [h / 2]:
                for cx in np.linspace(side / 2, w - side / 2, nx) if w > side else [w / 2]:
                    for rot in _ROI_ROTATIONS:
                        out = self._run_roi(image, (cx / w, cy / h, side / w, side / h, rot))
                        if out is not None:
                            hits.append(out)
        refined = []
        for out in hits:
            kp = landmark_pixels(out.landmarks, w, h)
            nxt = self._run_roi(image, roi_from_keypoints(kp, w, h))
            if nxt is not None:
                refined.append(nxt)
        logger.debug(
            "ROI search: %d window hits, %d kept after re-cropping", len(hits), len(refined)
        )
        refined = refined or hits
        if not refined:
            return []
        dets = [
            self._make(o.landmarks, o.world_landmarks, o.handedness, w, h, "roi_search")
            for o in refined
        ]
        # cluster by keypoint centre: same hand when centres are closer than half a hand size
        clusters: list[list[HandDetection]] = []
        for d in dets:
            c = d.keypoints2d.mean(0)
            size = float(np.ptp(d.keypoints2d, axis=0).max())
            for cl in clusters:
                if np.linalg.norm(cl[0].keypoints2d.mean(0) - c) < 0.5 * size:
                    cl.append(d)
                    break
            else:
                clusters.append([d])
        clusters.sort(key=lambda cl: (-len(cl), -max(d.score for d in cl)))
        out_dets = []
        for cl in clusters[: self.max_hands]:
            best = max(cl, key=lambda d: d.score)
            meta = dict(best.meta, votes=len(cl))
            out_dets.append(
                HandDetection(best.keypoints2d, best.keypoints3d, best.side, best.score, meta=meta)
            )
        return out_dets

    def keypoint_spread(self, image: np.ndarray, detection: HandDetection) -> np.ndarray | None:
        """(21,) spread of each keypoint of ``detection`` over the crops of
        :data:`CONFIDENCE_CROPS`, as a fraction of the hand's size (the larger side of the
        keypoints' box); None when the model finds the hand in fewer than
        :data:`MIN_CONFIDENCE_CROPS` of them. The detection's own keypoints are one member."""
        image = check_image(image)
        kp = np.asarray(detection.keypoints2d, dtype=np.float64).reshape(-1, 2)
        if kp.shape != (21, 2) or not np.isfinite(kp).all():
            return None
        size = float(np.ptp(kp, axis=0).max())
        if not size > 0:
            return None
        h, w = image.shape[:2]
        x, y, rw, rh, rot = roi_from_keypoints(kp, w, h)
        found = [kp]
        with silenced(2):
            for d_rot, scale, dx, dy in CONFIDENCE_CROPS:
                roi = (x + dx * rw, y + dy * rh, rw * scale, rh * scale, rot + d_rot)
                out = self._run_roi(image, roi)
                if out is not None:
                    found.append(landmark_pixels(out.landmarks, w, h))
        if len(found) - 1 < MIN_CONFIDENCE_CROPS:
            return None
        pts = np.stack(found)
        centre = np.median(pts, axis=0)
        return np.median(np.linalg.norm(pts - centre, axis=2), axis=0) / size

    def mirrored_look(
        self, image: np.ndarray, detection: HandDetection
    ) -> tuple[HandDetection, np.ndarray | None] | None:
        """The hand of ``detection`` as the detector finds it in the left-right mirrored photo,
        mapped back to the photo, with its keypoint confidence measured in the mirrored photo
        (where the model located it); None when the mirrored photo shows no hand whose keypoint
        centre lies within half the hand's size of the detection's.

        Mapped back: x -> W - x for the 2D keypoints (pixel centres at half-integers), x -> -x
        for the camera-aligned 3D keypoints, and the side swapped.
        """
        image = check_image(image)
        w = image.shape[1]
        kp = np.asarray(detection.keypoints2d, dtype=np.float64).reshape(-1, 2)
        if kp.shape != (21, 2) or not np.isfinite(kp).all():
            return None
        flipped = np.ascontiguousarray(image[:, ::-1])
        with silenced(2):
            found = self._palm_pass(flipped)
            if not found and self.roi_search:
                found = self._roi_pass(flipped)
        best = None
        for d in found:
            back = unmirror(d, w)
            dist = float(np.linalg.norm(back.keypoints2d.mean(axis=0) - kp.mean(axis=0)))
            if same_hand(back, detection) and (best is None or dist < best[0]):
                best = (dist, d, back)
        if best is None:
            return None
        _, d, back = best
        return back, self.keypoint_confidence(flipped, d)

    def keypoint_confidence(self, image: np.ndarray, detection: HandDetection) -> np.ndarray | None:
        """(21,) confidences in (0, 1] from :meth:`keypoint_spread` (see the module notes), or
        None when the spread cannot be measured."""
        spread = self.keypoint_spread(image, detection)
        if spread is None:
            return None
        return 1.0 / (1.0 + (spread / SPREAD_SCALE) ** 2)

    def detect(self, image: np.ndarray) -> list[HandDetection]:
        """All hands in an (H, W, 3) uint8 RGB image, most confident first.

        Returns:
            list of HandDetection: ``keypoints2d`` (21, 2) pixels, ``keypoints3d`` (21, 3) metres;
                empty when no hand.
        """
        image = check_image(image)
        with silenced(2):  # TFLite / absl info and warning lines
            dets = self._palm_pass(image)
            if not dets and self.roi_search:
                dets = self._roi_pass(image)
            if len(dets) < self.max_hands and self.mirror_pass:
                dets += self._mirrored_palm_pass(image, dets)
        dets.sort(key=lambda d: -d.score)
        return dets[: self.max_hands]

    def _mirrored_palm_pass(self, image: np.ndarray, found) -> list[HandDetection]:
        """The hands of the palm pipeline on the mirrored photo, mapped back, that are not one
        of ``found`` (or of each other)."""
        out: list[HandDetection] = []
        for d in self._palm_pass(np.ascontiguousarray(image[:, ::-1])):
            back = unmirror(d, image.shape[1])
            if not any(same_hand(back, f) for f in list(found) + out):
                out.append(back)
        return out
