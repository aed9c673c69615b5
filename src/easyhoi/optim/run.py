"""The three-stage prior-guided optimizer (docs/method.md section 2.2): public entry point.

:func:`optimize` turns an :class:`~easyhoi.hoi.HOIInput` into an :class:`~easyhoi.hoi.HOIResult`:

1. ``initial``: the starting camera (:func:`easyhoi.optim.camera.initial_camera`) and the
   estimator's hand placed in it (:func:`easyhoi.optim.contact.initial_hand`);
2. ``camera`` (stage 1), ``contact`` (stage 2), ``refine`` (stage 3), each when enabled
   (``config.run_camera`` / ``run_contact`` / ``run_refine``); a disabled stage keeps the state.
   With no stage enabled the result is the initial state (for ablations).

Conventions (see :mod:`easyhoi.optim.state` and :mod:`easyhoi.hoi`): the global frame is the
object's canonical frame in object units; ``metric_scale`` ``m`` is metres per object unit,
recovered from the hand's known (metric) size: the hand is placed at the depth where it meets
the object, so ``m`` is the ratio between the hand's metric depth and the object-unit depth
there. ``HOIResult.hand_params`` live in the metric object frame: ``model(params).vertices / m
== HOIResult.hand_vertices`` (object units). The camera maps object units to pixels.

Plausibility (``HOIResult.plausibility``, metres -> cm as :mod:`easyhoi.metrics`):
``penetration_depth_cm``, ``intersection_volume_cm3`` (the "solid" variant),
``in_contact`` (any vertex inside or within 5 mm), ``contact_distance_cm`` (signed SDF distance
of the closest hand vertex; negative = penetrating), ``hand_mask_iou`` (visible hand vs M_h)
and ``object_mask_iou`` (object vs M^_o), hard masks at ``render_size``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from easyhoi.config import EasyHOIConfig, OptimConfig, get_preset, to_dict
from easyhoi.errors import EasyHOIError, InvalidInputError, OptimizationError
from easyhoi.hoi import HOIInput, HOIResult, StageResult
from easyhoi.optim.camera import fit_camera, initial_camera
from easyhoi.optim.contact import ContactState, fit_contact, initial_hand
from easyhoi.optim.hand_change import hand_change
from easyhoi.optim.placement import camera_hand_to_object
from easyhoi.optim.refine import fit_refine
from easyhoi.optim.state import Scene, hard_iou
from easyhoi.optim.window import crop_input, interest_window, to_photo
from easyhoi.render.raster import depth_map

logger = logging.getLogger(__name__)

__all__ = ["optimize", "plausibility"]

Progress = Callable[[str, int, int, dict], None]


def _stage_error(name: str, exc: Exception) -> OptimizationError:
    return OptimizationError(f"stage {name!r} failed: {exc}")


#: Plausibility entries that compare the result with the masks it was fitted to: they say how
#: well the optimizer agreed with its own inputs, not whether those masks (and so the result)
#: are right. Every display labels them as self-consistency, apart from the physical metrics.
SELF_CONSISTENCY_KEYS = ("hand_mask_iou", "object_mask_iou")


def plausibility(
    scene: Scene, params, metric_scale: float, camera, render_size: int, sdf_resolution: int = 64
) -> dict:
    """JSON-ready plausibility report of a hand (metric object frame) against the object.

    ``contact_distance_cm`` is read from the object SDF grid at ``sdf_resolution``; the other
    values come from :mod:`easyhoi.metrics` (exact meshes) and hard renders at ``render_size``.
    """
    import trimesh

    from easyhoi import metrics

    model = scene.hand_model
    with torch.no_grad():
        verts_m = model(params).vertices[0].double()
    faces = model.faces_for(params.side).cpu().numpy()
    hand = trimesh.Trimesh(verts_m.cpu().numpy(), faces, process=False)
    obj = scene.watertight.copy()
    obj.apply_scale(metric_scale)
    out: dict = {}
    checks = {
        "penetration_depth_cm": lambda: metrics.penetration_depth(hand, obj),
        "intersection_volume_cm3": lambda: metrics.intersection_volume(hand, obj, method="solid"),
        "in_contact": lambda: metrics.in_contact(hand, obj),
    }
    for key, fn in checks.items():
        try:
            out[key] = fn()
        except EasyHOIError as exc:  # e.g. a hand mesh that is not closed
            logger.warning("plausibility metric %s unavailable: %s", key, exc)
            out[key] = None
    with torch.no_grad():
        v_obj = (verts_m / metric_scale).to(scene.dtype)
        d = scene.sdf(v_obj, sdf_resolution).min()
        out["contact_distance_cm"] = float(d) * scene.extent * metric_scale * 100.0
        h, w = scene.render_size(1.0, render_size)
        cam = camera.detach().to(scene.dtype).resized(w, h)
        zh = depth_map(v_obj, model.faces, cam)
        zo = scene.object_depth(cam)
        masks = scene.masks_at(h, w)
        vis = (torch.isfinite(zh) & (zh <= zo)).to(scene.dtype)
        out["hand_mask_iou"] = hard_iou(vis, masks["hand"])
        out["object_mask_iou"] = hard_iou(torch.isfinite(zo).to(scene.dtype), masks["amodal"])
    return out


def optimize(
    inp: HOIInput,
    config: OptimConfig | None = None,
    *,
    hand_model=None,
    progress: Progress | None = None,
    device=None,
) -> HOIResult:
    """Run the three-stage optimizer on one input.

    Args:
        inp (HOIInput): Photo, masks, object mesh (canonical frame, any scale), hand estimate and
            its camera.
        config (OptimConfig or None): Optimizer settings (default: the default preset's,
            ``get_preset().optim``); an :class:`~easyhoi.config.EasyHOIConfig` is accepted and its
            ``optim`` used.
        hand_model (HandModel or None): The run's hand model
            (:attr:`easyhoi.settings.RunSettings.hand_model`), the one ``inp.hand_params`` belong
            to. None only for the built-in open hand (:func:`easyhoi.hand.builtin_hand_model`); a
            MANO model must be passed in.
        progress (callable or None): ``progress(stage_name, iteration, max_iters, {loss terms})``,
            called every ``config.history_every`` iterations of every stage.
        device (str, torch.device or None): Where the optimisation runs ("cpu", "cuda", ...; None:
            the CPU). The run's resolved device is :attr:`easyhoi.settings.RunSettings.device`. The
            result is on the CPU.

    Returns:
        HOIResult: Hand in the metric object frame, camera, metric scale, stage snapshots ("initial"
            and one per stage that ran), timings (s), seed, config, plausibility.

    Raises:
        InvalidInputError: Bad input or configuration.
        OptimizationError: A stage diverged (NaN loss) or failed; the message names the stage.
    """
    if config is None:
        config = get_preset().optim
    if isinstance(config, EasyHOIConfig):
        config = config.optim
    if not isinstance(config, OptimConfig):
        raise InvalidInputError(f"config must be an OptimConfig, got {type(config).__name__}")
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"inp must be an HOIInput, got {type(inp).__name__}")
    dtype = config.torch_dtype
    if hand_model is None:
        from easyhoi.hand import builtin_hand_model

        hand_model = builtin_hand_model(inp.hand_model, dtype)
    device = torch.device("cpu" if device is None else device)
    hand_model = hand_model.on_device(device)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    photo_inp = inp
    win = interest_window(inp, config.render_size)
    inp = crop_input(inp, win)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        scene = Scene.from_input(inp, hand_model, dtype, device)
        timings["setup"] = time.perf_counter() - t0
        # the camera the whole photo would start from, seen through the window
        k = inp.hand_camera.K.detach().double().cpu()
        frame = {"principal": (float(k[0, 2]), float(k[1, 2])), "fov_height": photo_inp.size[0]}
        stages, camera, params, m = _run_stages(inp, scene, config, progress, timings, frame)
    t1 = time.perf_counter()
    report = plausibility(
        scene, params, m, camera, config.render_size, config.refine.sdf_resolution
    )
    moved = _object_moved_to_hand_cm(stages)
    if moved is not None:
        report["object_moved_to_hand_cm"] = moved
    timings["plausibility"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    with torch.no_grad():
        verts = hand_model(params).vertices[0].double().cpu().numpy() / m
    params, camera = params.to(device="cpu"), camera.to(device="cpu")
    stages = [_stage_on_cpu(s) for s in stages]
    change = hand_change(hand_model, inp, params, camera, m)
    result = HOIResult(
        hand_params=params,
        camera=camera,
        hand_vertices=verts,
        hand_faces=hand_model.faces_for(params.side).cpu().numpy(),
        object_mesh=inp.object_mesh,
        metric_scale=m,
        hand_model=inp.hand_model,
        stages=tuple(stages),
        timings=timings,
        seed=config.seed,
        config=to_dict(config),
        plausibility=report,
        meta=dict(photo_inp.meta),  # the photo's (the window's keypoints are shifted)
        hand_change=change,
    )
    return to_photo(result, win, photo_inp.size)


def _object_moved_to_hand_cm(stages) -> float | None:
    """How far the refinement moved the object onto a hand beside it (cm), None when it did
    not (:func:`easyhoi.optim.close_gap.meet`): the contact it makes is not the photo's."""
    for st in stages:
        meet = ((st.extra or {}).get("close_gap") or {}).get("meet") or {}
        if st.name == "refine" and meet.get("moved"):
            return float(meet["distance_cm"])
    return None


def _stage_on_cpu(stage: StageResult) -> StageResult:
    """A stage snapshot with its tensors on the CPU (results are written from there)."""
    return replace(
        stage,
        hand_params=None if stage.hand_params is None else stage.hand_params.to(device="cpu"),
        camera=None if stage.camera is None else stage.camera.to(device="cpu"),
    )


def _place_hand(inp: HOIInput, scene: Scene, config: OptimConfig, cam):
    """The estimator's hand in the object camera ``cam`` (:func:`initial_hand`): its camera-frame
    parameters, metric scale, note, and its parameters in the metric object frame."""
    p_cam, m, note = initial_hand(scene, inp, cam, config.render_size, config.contact)
    return p_cam, m, note, camera_hand_to_object(p_cam, cam, m, scene.hand_model)


def _run_stages(
    inp: HOIInput, scene: Scene, config: OptimConfig, progress, timings: dict, frame: dict
):
    stages: list[StageResult] = []
    t = time.perf_counter()
    cam, note = initial_camera(scene, config.camera, inp.amodal_mask, config.render_size, **frame)
    p_cam, m, hand_note, params = _place_hand(inp, scene, config, cam)
    stages.append(
        StageResult(
            name="initial",
            hand_params=params,
            camera=cam,
            seconds=time.perf_counter() - t,
            metric_scale=m,
            stop_reason="initial",
            extra={"camera": note, "hand": hand_note},
        )
    )
    timings["initial"] = time.perf_counter() - t

    if config.run_camera:
        try:
            cam, res = fit_camera(scene, cam, config.camera, config, progress)
        except InvalidInputError as exc:  # e.g. NaN vertices reaching the renderer
            raise _stage_error("camera", exc) from exc
        # the hand placement follows the new camera (same pixels, new focal)
        p_cam, m, hand_note, params = _place_hand(inp, scene, config, cam)
        stages.append(replace(res, hand_params=params, metric_scale=m,
                              extra={**res.extra, "hand": hand_note}))  # fmt: skip
        timings["camera"] = res.seconds

    if config.run_contact:
        try:
            state = ContactState(scene, p_cam, cam, m)
            res = fit_contact(scene, state, config.contact, config, progress)
        except InvalidInputError as exc:  # e.g. NaN vertices reaching the renderer
            raise _stage_error("contact", exc) from exc
        params, m = res.hand_params, float(res.metric_scale)
        stages.append(res)
        timings["contact"] = res.seconds

    if config.run_refine:
        theta0 = inp.hand_params.pose  # the estimator's articulation (same side convention)
        try:
            params, res = fit_refine(scene, params, m, cam, config.refine, config,
                                     theta0=theta0.to(scene.device, scene.dtype),
                                     progress=progress)  # fmt: skip
        except InvalidInputError as exc:  # e.g. NaN vertices reaching the renderer
            raise _stage_error("refine", exc) from exc
        m = float(res.metric_scale)  # the push-out may move the hand's depth as a scale
        cam = res.camera  # moved with the hand when the object is met (optim.close_gap.meet)
        stages.append(res)
        timings["refine"] = res.seconds
    if not np.isfinite(m) or m <= 0:
        raise OptimizationError(f"the recovered metric scale is invalid ({m})")
    return stages, cam, params, m
