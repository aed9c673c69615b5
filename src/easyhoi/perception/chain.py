"""The perception chain: photo -> :class:`~easyhoi.hoi.HOIInput` (paper section 2.1).

Steps (each a pluggable backend, chosen by name in :class:`~easyhoi.config.PerceptionConfig`):

1. hand detection (keypoints) and keypoint fitting of the hand model;
2. HOI segmentation: visible hand mask M_h, held-object mask M_o and their confidence. With
   several hands, each is segmented (the others passed to the segmenter when it takes them) and
   the hand whose object has the best confidence is used; a hand that holds no object is noted
   in the report. Prompts pick the hand (a hand point, or the hand nearest the object prompt,
   passing over a detection the landmark model does not find again: :func:`steady_nearest`)
   and steer the segmenter;
3. hand removal by inpainting (hand mask dilated);
4. amodal re-segmentation prompted by points in every part of M_o and a loose box -> M^_o
   (forced to contain M_o);
5. object mesh from the inpainted object crop, made watertight.
"""

from __future__ import annotations

import functools
import inspect
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from easyhoi.config import EasyHOIConfig
from easyhoi.errors import NO_OBJECT_HINT, InvalidInputError, NoHandError, NoObjectError
from easyhoi.hoi import HOIInput
from easyhoi.perception.base import HandDetection, Segmentation, create
from easyhoi.perception.confidence import keypoints_confidence
from easyhoi.perception.prompts import Prompts
from easyhoi.settings import RunSettings, resolve_run

logger = logging.getLogger(__name__)


@dataclass
class PerceptionReport:
    """What the chain found and how long each step took (seconds)."""

    hands_found: int = 0
    side: str | None = None
    has_object: bool = False
    timings: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    #: mask name ("hand", "object", "amodal") -> MaskConfidence (perception.confidence)
    confidence: dict = field(default_factory=dict)
    #: index, in detection order, of the hand the result uses (None before one is chosen)
    hand_index: int | None = None
    #: how that hand was chosen: "first holding an object", "hand point" or "object prompt"
    hand_choice: str | None = None
    #: object regions offered for ``--object-choice`` (None: not known)
    regions: int | None = None

    def to_dict(self) -> dict:
        return {
            "hands_found": self.hands_found,
            "side": self.side,
            "has_object": self.has_object,
            "timings": dict(self.timings),
            "notes": list(self.notes),
            "confidence": {k: v.to_dict() for k, v in self.confidence.items()},
            "hand_index": self.hand_index,
            "hand_choice": self.hand_choice,
            "regions": self.regions,
        }

    @property
    def low_confidence(self) -> list[str]:
        """Names of the masks whose confidence is low."""
        return [k for k, v in self.confidence.items() if v.low]


@dataclass(frozen=True)
class Provided:
    """Results of other tools that replace perception steps (all optional).

    Attributes:
        hand: (HandParams, Camera) of an imported hand (e.g. HaMeR), replacing detection + fit.
        hand_mask, object_mask, amodal_mask: (H, W) bool masks (e.g. LISA / SAM PNGs).
        object_mesh: a ``trimesh.Trimesh`` (e.g. InstantMesh / Tripo3D output).
    """

    hand: tuple | None = None
    hand_mask: np.ndarray | None = None
    object_mask: np.ndarray | None = None
    amodal_mask: np.ndarray | None = None
    object_mesh: object | None = None


def perceive(
    image: np.ndarray,
    settings: RunSettings | EasyHOIConfig | None = None,
    progress: Callable[[str], None] | None = None,
    seed: int | None = None,
    provided: Provided | None = None,
    prompts: Prompts | None = None,
) -> tuple[HOIInput, PerceptionReport]:
    """Run the perception chain on an (H, W, 3) uint8 RGB photo.

    Steps whose results are in ``provided`` are skipped (their inputs are not needed). The hand
    is fitted with ``settings.hand_model``; the run's seed seeds the amodal prompts and every
    backend that takes a seed (:func:`backend_seed`).

    Args:
        image: The photo.
        settings: The run's :class:`~easyhoi.settings.RunSettings`, or a configuration to
            resolve them from (None: the default preset).
        progress: Called with each step's name as it starts.
        seed: Replaces the run's seed when given.
        provided: Results of other tools that replace steps.
        prompts: Pixels of ``image`` that steer the segmentation: a hand point picks the hand
            nearest to it; object points and box reach the segmenter when its ``segment``
            takes a ``prompts`` argument (:class:`InvalidInputError` when it does not, and
            when ``provided`` holds the object mask that they would steer).

    Raises:
        NoHandError: no hand in the photo.
        NoObjectError: hands were found but none holds an object.
    """
    from easyhoi.geometry.watertight import make_watertight
    from easyhoi.perception.amodal import amodal_mask, amodal_prompts
    from easyhoi.perception.hand_fit import fit_detection

    if isinstance(settings, RunSettings):
        run = settings if seed is None else settings.with_seed(seed)
    else:
        run = resolve_run(settings, seed=seed)
    cfg, seed = run.config, run.seed
    pc = cfg.perception
    report = PerceptionReport()
    say = progress or (lambda _msg: None)
    H, W = image.shape[:2]

    def timed(name, fn, *a, **kw):
        say(name)
        t0 = time.perf_counter()
        out = fn(*a, **kw)
        report.timings[name] = round(time.perf_counter() - t0, 4)
        return out

    pv = provided or Provided()
    prompts = None if prompts is None or prompts.empty else prompts.check(W, H)
    if pv.object_mask is not None and prompts is not None and prompts.steers_object:
        raise InvalidInputError(
            "--object-mask replaces the object segmentation: --object-point, --object-box, "
            "--background-point and --object-choice would steer nothing (only --hand-point "
            "still applies)"
        )
    for name in ("hand_mask", "object_mask", "amodal_mask"):
        m = getattr(pv, name)
        if m is not None and np.shape(m) != (H, W):
            h, w = np.shape(m)[:2]
            raise InvalidInputError(f"{name} is {h}x{w} but the image is {H}x{W} (height x width)")
    masks_given = pv.hand_mask is not None and pv.object_mask is not None
    # the segmenter first: a missing model folder is reported before any work
    segmenter = None if masks_given else _backend(pc, "segmenter", pc.segmenter, seed, run.device)
    if pv.hand is not None and masks_given:  # nothing left for the detector to do
        say("hand detection (provided)")
        side = pv.hand[0].side
        hands = [HandDetection(np.zeros((0, 2)), None, side, 1.0, meta={"source": "provided"})]
        detector = None
    else:
        detector = _backend(pc, "hand", pc.hand, seed, run.device)
        hands = timed("hand detection", detector.detect, image)
    report.hands_found = len(hands)
    if not hands:
        raise NoHandError("no hand found in the photo")
    known_confidence: dict[int, np.ndarray] = {}
    if pv.hand is None and not masks_given:
        hands, known_confidence, dropped = steady_nearest(detector, image, hands, prompts, timed)
        if dropped is not None:
            report.hands_found = len(hands)
            report.notes.append(dropped)
    if masks_given:
        order, report.hand_choice = prompted_hand_order(hands, None)
        seg = Segmentation(pv.hand_mask, pv.object_mask, bool(pv.object_mask.any()))
        if not seg.has_object:
            raise NoObjectError(f"found {len(hands)} hand(s) but no held object")
        idx = order[0]
    else:
        idx, seg, notes, report.hand_choice = segment_hands(
            image, hands, segmenter, prompts, timed, name=pc.segmenter
        )
        report.notes.extend(notes)
        if seg is None:
            if report.hand_choice is not None:
                i = prompted_hand_order(hands, prompts)[0][0]
                if prompts.has_object_prompt:  # the user says the object is there
                    raise NoObjectError(
                        f"no object could be segmented at the object prompt (for hand {i}, "
                        f"{hands[i].side}): click inside the object or draw the box round all "
                        "of it"
                    )
                raise NoObjectError(
                    f"the hand nearest the {report.hand_choice} (hand {i}, {hands[i].side}) "
                    "holds no object"
                )
            raise NoObjectError(f"found {len(hands)} hand(s) but no held object{NO_OBJECT_HINT}")
        if pv.hand_mask is not None or pv.object_mask is not None:
            hm = seg.hand_mask if pv.hand_mask is None else pv.hand_mask
            om = seg.object_mask if pv.object_mask is None else pv.object_mask
            conf = {k: v for k, v in seg.confidence.items()
                    if getattr(pv, f"{k}_mask", None) is None}  # fmt: skip
            choices = seg.candidates if pv.object_mask is None else ()  # none to pick from
            seg = Segmentation(hm, om, bool(om.any()), choices, seg.meta, conf)
        report.confidence.update(seg.confidence)
        report.regions = len(seg.candidates)
    chosen = hands[idx]
    # how sure the detector is of each keypoint, where it can say (the optimizer's keypoint
    # terms weigh the joints by it); when it is unsure, a second look at the mirrored photo.
    # A steadier skeleton from that look replaces the keypoints the hand is fitted to and the
    # optimizer follows; the masks stay those of the first look (a skeleton whose fingers run
    # behind the held object seeds the hand mask over the object)
    kp_confidence = None
    if pv.hand is None and hasattr(detector, "keypoint_confidence"):
        if id(chosen) in known_confidence:  # measured when the hand was chosen (None too)
            kp_confidence = known_confidence[id(chosen)]
        else:
            kp_confidence = timed(
                "keypoint confidence", detector.keypoint_confidence, image, chosen
            )
        look = second_look(detector, image, chosen, kp_confidence, timed)
        if look is not None:
            before = keypoints_confidence(kp_confidence).score
            chosen, kp_confidence = look
            report.notes.append(
                "hand keypoints from the mirrored photo: the detector is surer of them there "
                f"(median keypoint confidence {before:.2f} in the photo, "
                f"{keypoints_confidence(kp_confidence).score:.2f} mirrored)"
            )
        report.confidence["keypoints"] = keypoints_confidence(kp_confidence)
    report.hand_index = idx
    report.side, report.has_object = chosen.side, True

    model = run.hand_model
    if pv.hand is not None:
        params, camera = pv.hand
        chosen = replace(chosen, side=params.side, params=params, camera=camera)
        report.side = params.side
        report.notes.append("hand provided (imported), not fitted")
    else:
        chosen = timed("hand fit", fit_detection, chosen, model, W, H)

    inpainter = _backend(pc, "inpainter", pc.inpainter, seed, run.device)
    inpainted = timed("inpainting", inpainter.inpaint, image, seg.hand_mask)
    points, box = amodal_prompts(seg.object_mask, seed=seed)
    if pv.amodal_mask is not None:
        amodal = pv.amodal_mask
    else:
        amodal = timed(
            "amodal segmentation",
            amodal_mask,
            _backend(pc, "amodal", pc.amodal, seed, run.device),
            inpainted,
            points,
            box,
            seg.object_mask,
            seg.hand_mask,
        )
    amodal = np.asarray(amodal, bool) | seg.object_mask
    if pv.object_mesh is not None:
        mesh = pv.object_mesh.copy()
        report.notes.append("object mesh provided (imported)")
    else:
        from easyhoi.perception.objects import hand_inputs

        reconstructor = _backend(pc, "object", pc.object, seed, run.device)
        hand_kw = hand_inputs(reconstructor, chosen, model, seg.hand_mask, seg.object_mask)
        mesh = timed("object mesh", reconstructor.reconstruct, inpainted, amodal, **hand_kw)
    if not mesh.is_watertight:
        mesh, wt = timed("watertight", make_watertight, mesh)
        report.notes.append(f"object mesh repaired ({wt.method})")
    inp = HOIInput(
        image=image,
        hand_mask=seg.hand_mask,
        object_mask=seg.object_mask,
        amodal_mask=amodal,
        object_mesh=mesh,
        hand_params=chosen.params,
        hand_camera=chosen.camera,
        hand_model=cfg.hand_model,
        inpainted_image=inpainted,
        meta={
            "keypoints2d": np.asarray(chosen.keypoints2d).tolist(),
            **(
                {}
                if kp_confidence is None
                else {"keypoints2d_confidence": np.round(kp_confidence, 4).tolist()}
            ),
            "hand_side": chosen.side,
            "detection": {k: v for k, v in chosen.meta.items() if _jsonable(v)},
            "perception": report.to_dict(),
            "object_shape": (getattr(mesh, "metadata", None) or {}).get("easyhoi", {}).get("shape"),
            **_choices_meta(seg),
        },
    )
    return inp, report


def nearest_hand(hands: list[HandDetection], point) -> int:
    """Index of the hand whose keypoints come nearest to the pixel ``point`` (x, y)."""
    p = np.asarray(point, float).reshape(1, 2)
    dists = []
    for hand in hands:
        k = np.asarray(hand.keypoints2d, float).reshape(-1, 2)
        dists.append(np.linalg.norm(k - p, axis=1).min() if len(k) else np.inf)
    return int(np.argmin(dists))


def steady_nearest(
    detector, image: np.ndarray, hands: list[HandDetection], prompts: Prompts | None, timed
) -> tuple[list[HandDetection], dict[int, np.ndarray], str | None]:
    """The hands an object prompt chooses among, the keypoint confidences measured on the way
    (by ``id`` of the detection, None where it cannot be measured) and a note when a detection
    was passed over.

    An object prompt picks the hand nearest to it (:func:`prompted_hand_order`), which is blind
    to what the detection is. A skeleton the landmark model does not find again in slightly
    moved crops of its own region (:meth:`keypoint_confidence` is None: a hand in fewer than
    half of them) is not a steady reading of a hand: a real hand is found again when the crop
    moves by a few per cent, while a skeleton fitted to a pattern beside the hand (a printed
    box, a sleeve's fold) comes and goes. When the nearest detection is such a skeleton and the
    next nearest is found again, the prompt's hand is chosen among the others. Only with an
    object prompt and no hand point, and with at least two hands; an only hand is kept
    whatever its confidence. The chain needs the chosen hand's confidence anyway, so every
    confidence measured here is returned and none is measured twice.
    """
    if (
        prompts is None
        or prompts.hand_point is not None
        or not prompts.has_object_prompt
        or len(hands) < 2
        or not hasattr(detector, "keypoint_confidence")
    ):
        return hands, {}, None
    order, _ = prompted_hand_order(hands, prompts)
    i = order[0]
    conf = timed("keypoint confidence", detector.keypoint_confidence, image, hands[i])
    if conf is not None:
        return hands, {id(hands[i]): conf}, None
    rest = [h for j, h in enumerate(hands) if j != i]
    j = prompted_hand_order(rest, prompts)[0][0]
    other = timed("keypoint confidence", detector.keypoint_confidence, image, rest[j])
    measured = {id(hands[i]): conf, id(rest[j]): other}
    if other is None:
        return hands, measured, None
    note = (
        f"a {hands[i].side} hand skeleton nearest to the object prompt was set aside: the "
        "detector does not find it again in slightly moved crops (not a steady hand)"
    )
    return rest, measured, note


def prompted_hand_order(
    hands: list[HandDetection], prompts: Prompts | None
) -> tuple[list[int], str | None]:
    """The hands to segment, in order, and why: (indices, "hand point" / "object prompt" / None).

    A hand point picks the hand nearest to it; object prompts alone pick the hand nearest to
    the object (its first point, else the box centre): a held object lies at the hand that
    holds it. The first point, not the mean of all: further points mark parts the object
    lacks, and a point on a far part of an object that two hands hold must not hand the
    object to the other hand. Without prompts every hand is tried in detection order (reason
    None).
    """
    if prompts is not None and prompts.hand_point is not None:
        return [nearest_hand(hands, prompts.hand_point)], "hand point"
    if prompts is not None and prompts.has_object_prompt:
        if prompts.object_points:
            centre = np.asarray(prompts.object_points[0], float)
        else:
            x0, y0, x1, y1 = prompts.object_box
            centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        return [nearest_hand(hands, centre)], "object prompt"
    return list(range(len(hands))), None


def segment_hands(
    image: np.ndarray,
    hands: list[HandDetection],
    segmenter,
    prompts: Prompts | None = None,
    timed: Callable | None = None,
    name: str = "segmenter",
) -> tuple[int | None, Segmentation | None, list[str], str | None]:
    """Segment the hand(s) and pick the one whose held object is most certain.

    The hands come from :func:`prompted_hand_order` (one hand when a prompt picks it). Each is
    segmented, with the other hands passed as ``others`` when the segmenter takes them (they are
    never part of the object), and the hand holding an object of the highest object confidence
    wins (the first on ties). Every hand that holds no object is named in the notes.

    Returns:
        (hand index, segmentation, notes, why the hand was chosen), or (None, None, notes,
        reason) when no hand holds an object.
    """
    run = timed or (lambda _name, fn, *a, **kw: fn(*a, **kw))
    picked = prompts.object_choice if prompts is not None else None
    if picked is not None:  # the hand is chosen as without the choice, then its region K taken
        segment_picked = _prompted(segmenter, name, prompts)
        prompts = replace(prompts, object_choice=None)
    segment = _prompted(segmenter, name, prompts)
    order, choice = prompted_hand_order(hands, prompts)
    if picked is not None and len(order) == 1:  # a prompt picked the hand: region K at once
        segment = segment_picked
    takes_others = "others" in inspect.signature(segmenter.segment).parameters

    def others(i):
        return {"others": [h for j, h in enumerate(hands) if j != i]} if takes_others else {}

    notes, results = [], []
    for i in order:
        s = run(f"segmentation (hand {i})", segment, image, hands[i], **others(i))
        if s.has_object or picked is not None:
            conf = s.confidence.get("object")
            score = conf.score if (conf is not None and s.has_object) else -1.0
            results.append((score, -i, i, s))
        else:
            notes.append(f"hand {i} ({hands[i].side}) holds no object")
    if not results:
        return None, None, notes, choice
    _, _, i, s = max(results, key=lambda r: (r[0], r[1]))
    if choice is None:
        choice = "first holding an object" if len(results) == 1 else "most confident object"
    if picked is not None and len(order) > 1:
        s = run(f"segmentation (hand {i}, object choice {picked})", segment_picked, image,
                hands[i], **others(i))  # fmt: skip
    return i, s, notes, choice


def _choices_meta(seg: Segmentation) -> dict:
    """``object_choices`` for ``result.json``: the outlines of the object regions that
    ``--object-choice K`` picks from (the K-th is region K), and ``object_choice``, the one
    used; nothing when the segmenter offered none (a prompted object, another segmenter)."""
    if not seg.candidates:
        return {}
    from easyhoi.perception.outlines import mask_outlines

    used = seg.meta.get("object_choice") or 1
    return {
        "object_choices": [mask_outlines(m) for m in seg.candidates],
        "object_choice": int(used),
    }


def second_look(detector, image: np.ndarray, hand: HandDetection, confidence, timed=None):
    """A steadier skeleton of ``hand`` from the detector's look at the mirrored photo, when the
    detector is unsure of ``hand``'s keypoints (their ``confidence`` is low) and has such a
    look (``detector.mirrored_look``): (detection, its keypoint confidences), or None when the
    look is not steadier (a higher median confidence) or not taken.

    Why: the landmark model is not mirror-symmetric, so the mirrored photo is a second look at
    the same hand; of two skeletons of one hand, the one that stays put when the crop moves is
    the one located from evidence (the confidence's own reason, ``mediapipe_hand``).
    """
    if not keypoints_confidence(confidence).low or not hasattr(detector, "mirrored_look"):
        return None
    run = timed or (lambda _name, fn, *a, **kw: fn(*a, **kw))
    look = run("second look (mirrored photo)", detector.mirrored_look, image, hand)
    if look is None or look[1] is None:
        return None
    if confidence is not None and np.median(look[1]) <= np.median(confidence):
        return None
    return look


def _prompted(segmenter, name: str, prompts: Prompts | None):
    """``segment(image, hand)`` of ``segmenter``, handing it the object and background
    prompts."""
    if prompts is None or not prompts.steers_object:
        return segmenter.segment
    if "prompts" not in inspect.signature(segmenter.segment).parameters:
        raise InvalidInputError(
            f"the segmenter {name!r} takes no object prompts; choose one that does "
            "(see `easyhoi doctor`) or leave out --object-point/--object-box/--background-point"
        )
    if prompts.object_choice is not None and not getattr(segmenter, "offers_choices", False):
        raise InvalidInputError(
            f"the segmenter {name!r} offers no numbered object regions; leave out "
            "--object-choice or use --object-point"
        )
    return functools.partial(segmenter.segment, prompts=prompts)


#: Backends that load large models from local folders, and the config fields naming them.
_MODEL_DIR_FIELDS = {"sam": ("sam_dir",), "depth": ("depth_dir",),
                     "diffusion": ("diffusion_dir",),
                     "shap-e": ("shape_dir",),
                     "grounded-sam": ("detector_dir", "sam_dir")}  # fmt: skip


def backend_seed(seed: int) -> int:
    """The seed handed to perception backends: the run's seed modulo 2**31.

    OpenCV's random generator (GrabCut's initial clustering) takes a C int, so the run's seed
    (up to 2**32 - 1) is folded into [0, 2**31).
    """
    return int(seed) % 2**31


def _backend(pc, role: str, name: str, seed: int = 0, device: str = "cpu"):
    """Create a backend: one that takes a ``seed`` gets :func:`backend_seed`, one that takes a
    ``device`` gets the run's (adapters of large models: the model and its inputs go there),
    adapters of large models get their local model folders from config (one folder as
    ``model_dir``, several each under its field's name)."""
    from easyhoi.perception.base import factory

    kwargs = {}
    try:
        params = inspect.signature(factory(role, name)).parameters
    except (TypeError, ValueError):  # pragma: no cover - a factory without a signature
        params = {}
    if "seed" in params:
        kwargs["seed"] = backend_seed(seed)
    if "device" in params:
        kwargs["device"] = device
    if role == "object" and pc.object_shape != "auto":
        if "families" not in params:
            raise InvalidInputError(
                f"--object-shape {pc.object_shape} (perception.object_shape) chooses a shape "
                f"family of the 'silhouette' object backend; the {name!r} backend has none"
            )
        kwargs["families"] = (pc.object_shape,)
    fields = _MODEL_DIR_FIELDS.get(name)
    if fields is None:
        return create(role, name, **kwargs)
    dirs = {}
    for field_name in fields:
        dirs[field_name] = getattr(pc, field_name)
        if not dirs[field_name]:
            flag = "--" + field_name.replace("_", "-")
            raise InvalidInputError(
                f"the {role} backend {name!r} needs a local model folder: pass {flag} DIR "
                f"(perception.{field_name}); nothing is downloaded"
            )
    if len(fields) == 1:
        return create(role, name, model_dir=dirs[fields[0]], **kwargs)
    return create(role, name, **dirs, **kwargs)


def _jsonable(v) -> bool:
    return isinstance(v, str | int | float | bool | type(None))
