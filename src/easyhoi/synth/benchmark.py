"""Synthetic benchmark with exact ground truth: the paper's tables on :mod:`easyhoi.synth` scenes.

:func:`run_benchmark` builds ``n`` scenes (object kinds and grasp types cycled, the "hamer"
perturbation by default), optimizes each with the ``fast`` preset and measures, against the
ground truth:

* **stage ablation**: the per-stage snapshots of ONE full run (``initial`` = no optimization,
  ``camera``, ``contact``, ``refine``), nothing re-run;
* **loss ablation**: stage 3 re-run from the run's contact snapshot with one loss weight set to 0
  (hand mask, penetration, regularization, contact); "full" is the run's own refine snapshot;
* **object input**: a second full run on the same scene whose object is the GT shape (same
  canonical rotation and scale, no deformation), next to the estimator's hand before any
  optimization;
* **object quality**: C.D. / F@5mm / F@10mm (MOHO convention) of the input object at the
  result's metric scale against the GT object;
* **runtime**: seconds per stage of ``fast`` on every scene and of ``paper`` on the first
  ``paper_scenes`` scenes (with their quality, side by side).

Units and frames of every number (:func:`evaluate_hand`): hands are compared in the GT world
frame (metres, the object's metric frame) after mapping the result's object frame with the GT
similarity (``canonical_from_world``): a metric-scale error therefore shows up as a hand error.
S.D. (cm) uses gravity along +y of the GT camera mapped to the object frame; I.V. (cm^3) and
penetration (cm) are measured between the hand and the input object at the result's metric
scale; mask IoUs compare hard renders at the preset's ``render_size`` with the GT masks.
Tables: :mod:`easyhoi.synth.tables`.
"""

from __future__ import annotations

import logging
import os
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
import trimesh

from easyhoi import metrics
from easyhoi.config import OptimConfig, get_preset, with_overrides
from easyhoi.errors import InvalidInputError
from easyhoi.structures import HandParams
from easyhoi.synth.grasp import GRASP_TYPES
from easyhoi.synth.objects import OBJECT_KINDS
from easyhoi.synth.perturb import get_perturbation

logger = logging.getLogger(__name__)

__all__ = [
    "LOSS_ABLATIONS",
    "BenchmarkSettings",
    "evaluate_hand",
    "refine_from_contact",
    "run_benchmark",
    "scene_specs",
    "strip_timings",
]

#: Loss ablation variants: name -> the refine weight set to 0 (None: the full loss).
LOSS_ABLATIONS: dict[str, str | None] = {
    "full": None,
    "w/o hand mask": "hand_mask_weight",
    "w/o penetration": "penetration_weight",
    "w/o regularization": "reg_weight",
    "w/o contact": "contact_weight",
}


@dataclass(frozen=True)
class BenchmarkSettings:
    """What :func:`run_benchmark` runs."""

    scenes: int = 20
    """Number of synthetic scenes."""
    seed: int = 0
    """Scene ``i`` has seed ``1000 * seed + i`` (its perturbations too)."""
    paper_scenes: int = 3
    """The paper preset runs on the first this many scenes (it is ~20x slower)."""
    paper_cap: int = 0
    """Cap on each paper stage's iterations (0 = the paper's full schedule)."""
    perturbation: str = "hamer"
    """Level of :data:`easyhoi.synth.perturb.PERTURBATION_LEVELS`."""
    image_size: int = 128
    """Photo side in pixels."""
    sd_steps: int = 35
    """Simulation steps of S.D. (35: ObMan's code)."""
    gallery: int = 4
    """Scenes rendered in the gallery (the first ones)."""
    chamfer_samples: int = 30000
    """Surface samples per mesh of C.D. / F-scores."""

    def __post_init__(self):
        if self.scenes < 1 or self.paper_scenes < 0 or self.paper_cap < 0 or self.sd_steps < 1:
            raise InvalidInputError(f"invalid benchmark settings: {self}")
        get_perturbation(self.perturbation)


def scene_specs(n: int, seed: int = 0) -> list[tuple[int, str, str]]:
    """``(scene_seed, object_kind, grasp_type)`` of the ``n`` scenes: kinds cycle, grasps shift.

    Every kind appears before any repeats; over 15 scenes every (kind, grasp) pair appears once.
    """
    k, g = len(OBJECT_KINDS), len(GRASP_TYPES)
    return [
        (1000 * seed + i, OBJECT_KINDS[i % k], GRASP_TYPES[(i % k + i // k) % g]) for i in range(n)
    ]


# ----------------------------------------------------------------------------------------------
# ground truth and per-hand evaluation
# ----------------------------------------------------------------------------------------------


@dataclass
class _Truth:
    """Ground truth of one input: frames, the GT hand, the scene for GT-mask IoUs."""

    model: object
    world_from_canonical: np.ndarray  # (4, 4): x_world = A @ x_can + b (metres)
    metres_per_unit: float
    gravity_obj: np.ndarray  # (3,) unit, object (canonical) frame
    joints: np.ndarray  # (21, 3) world, metres
    verts: np.ndarray  # (V, 3) world, metres
    joints_cam: np.ndarray  # (21, 3) GT camera frame, metres
    verts_cam: np.ndarray  # (V, 3) GT camera frame, metres
    opt_scene: object  # easyhoi.optim.scene.Scene with the GT masks
    render_size: int
    sdf_resolution: int


def _truth(scene, inp, cfg: OptimConfig) -> _Truth:
    from easyhoi.optim.scene import Scene as OptScene

    gt = inp.meta["gt"]
    M = np.asarray(gt["canonical_from_world"], float)
    s = float(np.linalg.norm(M[:3, 0]))
    Rc = M[:3, :3] / s
    R_cam = scene.camera.R.numpy()
    model = scene.hand_model
    with torch.no_grad():
        gt_cam = HandParams.from_dict(gt["hand_params_camera"]).to(torch.float64)
        out = model(gt_cam)
    gt_inp = replace(
        inp,
        hand_mask=scene.hand_mask,
        object_mask=scene.object_mask,
        amodal_mask=scene.object_amodal,
    )
    return _Truth(
        model=model,
        world_from_canonical=np.linalg.inv(M),
        metres_per_unit=float(gt["metres_per_unit"]),
        gravity_obj=Rc @ R_cam.T @ np.array([0.0, 1.0, 0.0]),
        joints=np.asarray(scene.keypoints_3d),
        verts=np.asarray(scene.grasp.vertices),
        joints_cam=out.keypoints[0].numpy(),
        verts_cam=out.vertices[0].numpy(),
        opt_scene=OptScene.from_input(gt_inp, model, cfg.torch_dtype),
        render_size=cfg.render_size,
        sdf_resolution=cfg.refine.sdf_resolution,
    )


def _hand_out(model, params: HandParams):
    with torch.no_grad():
        out = model(params.detach().to(torch.float64))
    return out.vertices[0].numpy(), out.keypoints[0].numpy()


def _mask_ious(truth: _Truth, v_obj: torch.Tensor, camera) -> tuple[float, float]:
    """Hard-render IoUs (visible hand vs GT M_h, object vs GT amodal) at ``render_size``."""
    from easyhoi.optim.scene import hard_iou
    from easyhoi.render.raster import depth_map

    sc = truth.opt_scene
    with torch.no_grad():
        h, w = sc.render_size(1.0, truth.render_size)
        cam = camera.detach().to(sc.dtype).resized(w, h)
        zh = depth_map(v_obj.to(sc.dtype), truth.model.faces, cam)
        zo = sc.object_depth(cam)
        masks = sc.masks_at(h, w)
        vis = (torch.isfinite(zh) & (zh <= zo)).to(sc.dtype)
        return hard_iou(vis, masks["hand"]), hard_iou(
            torch.isfinite(zo).to(sc.dtype), masks["amodal"]
        )


def evaluate_hand(truth: _Truth, params: HandParams, m: float, camera, sd_steps: int) -> dict:
    """Metrics of one hand (metric object frame, ``m`` metres per object unit) vs the truth.

    Returns a dict (lengths in cm, volumes in cm^3):

    * ``mpjpe_ra_cm`` / ``mpvpe_ra_cm``: global rotation and root removed (EasyHOI's
      convention: articulation and shape only);
    * ``mpjpe_root_cm``: metric camera frame, root-aligned (the hand through ``camera`` vs the
      GT hand in the GT camera, wrist translation removed: adds the global orientation);
    * ``mpjpe_cam_cm`` / ``mpvpe_cam_cm``: metric camera frame, no alignment (adds the depth,
      which the focal length / distance ambiguity of the fitted camera dominates);
    * ``mpjpe_world_cm`` / ``mpvpe_world_cm``: world (object) frame after the GT similarity,
      no alignment (adds the object pose and metric-scale errors, including the rotation
      ambiguity of symmetric objects);
    * ``sd_cm`` (S.D.), ``iv_cm3`` (solid, 5 mm grid) and ``iv_obman_cm3`` (ObMan voxels),
      ``pen_cm`` (deepest hand vertex inside), ``contact_cm`` (signed distance of the closest
      hand vertex to the surface, < 0 inside), ``in_contact`` (a vertex inside or within 5 mm);
    * ``hand_iou`` / ``object_iou``: visible hand vs the GT M_h, object vs the GT amodal mask;
    * ``scale_err_pct``: |m / true m - 1| in %.
    """
    from easyhoi.metrics.interaction import _signed_depths

    model = truth.model
    V, K = _hand_out(model, params)
    A, b = truth.world_from_canonical[:3, :3], truth.world_from_canonical[:3, 3]
    Vw, Kw = (V / m) @ A.T + b, (K / m) @ A.T + b
    hand = trimesh.Trimesh(V, model.faces_for(params.side).numpy(), process=False)
    obj = truth.opt_scene.watertight.copy()
    obj.apply_scale(m)
    dist, inside = _signed_depths(V, obj)  # one closest-point query for pen / contact
    signed = np.where(inside, -dist, dist)
    hand_iou, object_iou = _mask_ious(truth, torch.as_tensor(V / m), camera)
    sd = metrics.simulation_displacement(hand, obj, steps=sd_steps, gravity_dir=truth.gravity_obj)
    R = camera.R.detach().double().numpy()
    t = camera.t.detach().double().numpy() * m
    Vc, Kc = V @ R.T + t, K @ R.T + t
    return {
        "mpjpe_ra_cm": metrics.mpjpe(K, truth.joints, align="rotation"),
        "mpvpe_ra_cm": metrics.mpvpe(
            V, truth.verts, align="rotation", pred_root=K[0], gt_root=truth.joints[0]
        ),
        "mpjpe_root_cm": metrics.mpjpe(Kc, truth.joints_cam, align="root"),
        "mpjpe_cam_cm": metrics.mpjpe(Kc, truth.joints_cam),
        "mpvpe_cam_cm": metrics.mpvpe(Vc, truth.verts_cam),
        "mpjpe_world_cm": metrics.mpjpe(Kw, truth.joints),
        "mpvpe_world_cm": metrics.mpvpe(Vw, truth.verts),
        "sd_cm": sd.displacement,
        "iv_cm3": metrics.intersection_volume(hand, obj, method="solid"),
        "iv_obman_cm3": metrics.intersection_volume(hand, obj, method="obman"),
        "pen_cm": float(dist[inside].max() * 100.0) if inside.any() else 0.0,
        "contact_cm": float(signed.min() * 100.0),
        "in_contact": bool(inside.any() or (dist <= 0.005).any()),
        "hand_iou": hand_iou,
        "object_iou": object_iou,
        "scale_err_pct": abs(m / truth.metres_per_unit - 1.0) * 100.0,
    }


def _estimator_hand(truth: _Truth, inp) -> dict:
    """The estimator's hand (camera frame) vs the GT hand in that camera: the "HaMeR" row."""
    V, K = _hand_out(truth.model, inp.hand_params)
    return {
        "mpjpe_ra_cm": metrics.mpjpe(K, truth.joints_cam, align="rotation"),
        "mpvpe_ra_cm": metrics.mpvpe(
            V, truth.verts_cam, align="rotation", pred_root=K[0], gt_root=truth.joints_cam[0]
        ),
        "mpjpe_root_cm": metrics.mpjpe(K, truth.joints_cam, align="root"),
        "mpjpe_cam_cm": metrics.mpjpe(K, truth.joints_cam),
        "mpvpe_cam_cm": metrics.mpvpe(V, truth.verts_cam),
    }


def gt_hand_state(scene, inp):
    """The GT hand as a result would hold it: ``(params, m, camera)`` in the input's frames.

    ``params`` in the metric object frame, ``m`` the true metres per object unit, ``camera``
    the GT camera acting on object units (used for the "ground truth" reference row and tests).
    """
    from easyhoi.structures import Camera
    from easyhoi.synth.perturb import transform_hand

    M = np.asarray(inp.meta["gt"]["canonical_from_world"], float)
    s = float(np.linalg.norm(M[:3, 0]))
    Rc, c = M[:3, :3] / s, M[:3, 3]  # x_can = s Rc x + c
    gt = scene.hand_params.to(torch.float64)
    params = transform_hand(gt, Rc, c / s, scene.hand_model)  # x_metric = x_can / s = Rc x + c / s
    cam = scene.camera
    R = cam.R.double().numpy() @ Rc.T
    t = s * (cam.t.double().numpy() - R @ (c / s))
    camera = Camera(cam.K.clone(), torch.as_tensor(R), torch.as_tensor(t), cam.width, cam.height)
    return params, 1.0 / s, camera


def refine_from_contact(inp, result, cfg: OptimConfig, opt_scene=None):
    """Re-run stage 3 from ``result``'s contact snapshot with ``cfg`` (seeded like optimize).

    Returns the refined :class:`HandParams` (metric object frame; metric scale unchanged).
    """
    from easyhoi.optim.refine import fit_refine
    from easyhoi.optim.scene import Scene as OptScene

    contact = next(s for s in result.stages if s.name == "contact")
    if opt_scene is None:
        from easyhoi.hand import load_hand_model

        opt_scene = OptScene.from_input(inp, load_hand_model(inp.hand_model), cfg.torch_dtype)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        theta0 = inp.hand_params.pose.to(opt_scene.dtype)
        params, _ = fit_refine(
            opt_scene,
            contact.hand_params,
            float(contact.metric_scale),
            contact.camera,
            cfg.refine,
            cfg,
            theta0=theta0,
        )
    return params


# ----------------------------------------------------------------------------------------------
# one scene
# ----------------------------------------------------------------------------------------------


def _object_quality(inp, m: float, truth: _Truth, gt_mesh, n: int) -> dict:
    """C.D. / F-scores of the input object at metric scale ``m`` vs the GT object (world)."""
    A = truth.world_from_canonical[:3, :3]
    R = A / np.linalg.norm(A[:, 0])
    v = np.asarray(inp.object_mesh.vertices) * m @ R.T + truth.world_from_canonical[:3, 3]
    pred = trimesh.Trimesh(v, np.asarray(inp.object_mesh.faces), process=False)
    out = {}
    for align in ("translation_scale", "none"):
        r = metrics.chamfer_fscore(pred, gt_mesh, n_samples=n, align=align)
        out[align] = {"cd": r.chamfer, "f5": r.fscore[5.0], "f10": r.fscore[10.0]}
    return out


def _stage_metrics(truth, result, steps: int) -> dict:
    out = {}
    for st in result.stages:
        cam = st.camera if st.camera is not None else result.camera
        out[st.name] = evaluate_hand(truth, st.hand_params, float(st.metric_scale), cam, steps)
    return out


def _gallery_images(result, image) -> dict:
    from easyhoi.viz import render_overlay, render_views

    views = render_views(result, size=image.shape[0])
    return {
        "photo": np.asarray(image),
        "overlay": render_overlay(result, image).image,
        "side": views["side"],
    }


def evaluate_scene(
    spec,
    settings: BenchmarkSettings,
    fast: OptimConfig,
    paper: OptimConfig | None,
    gallery: bool = False,
) -> dict:
    """Every measurement of one scene (see the module docstring); ``timings`` holds seconds."""
    from easyhoi.hand import load_hand_model
    from easyhoi.optim.run import optimize
    from easyhoi.optim.scene import Scene as OptScene
    from easyhoi.synth.scene import make_scene

    seed, kind, grasp = spec
    t0 = time.perf_counter()
    scene = make_scene(seed, kind, grasp, image_size=settings.image_size)
    level = get_perturbation(settings.perturbation)
    inp = scene.to_hoi_input(level, seed=seed)
    t_scene = time.perf_counter() - t0
    truth = _truth(scene, inp, fast)
    res = optimize(inp, fast)
    steps = settings.sd_steps
    row: dict = {"seed": seed, "kind": kind, "grasp": grasp}
    row["stages"] = _stage_metrics(truth, res, steps)
    row["ground_truth"] = evaluate_hand(truth, *gt_hand_state(scene, inp), steps)
    # loss ablation: stage 3 from the contact snapshot
    opt_scene = OptScene.from_input(inp, load_hand_model(inp.hand_model), fast.torch_dtype)
    contact = next(s for s in res.stages if s.name == "contact")
    abl = {"full": row["stages"]["refine"]}
    for name, key in LOSS_ABLATIONS.items():
        if key is None:
            continue
        cfg = with_overrides(fast, {f"refine.{key}": 0.0})
        params = refine_from_contact(inp, res, cfg, opt_scene)
        abl[name] = evaluate_hand(truth, params, float(contact.metric_scale), contact.camera, steps)
    row["loss_ablation"] = abl
    # the same scene with the GT object shape (same canonical frame, no deformation)
    gt_level = replace(level, object=replace(level.object, shape="oracle", amplitude=0.0))
    inp_gt = scene.to_hoi_input(gt_level, seed=seed)
    truth_gt = _truth(scene, inp_gt, fast)
    res_gt = optimize(inp_gt, fast)
    row["object_input"] = {
        "estimator": _estimator_hand(truth, inp),
        "reconstructed": row["stages"]["refine"],
        "gt": evaluate_hand(
            truth_gt, res_gt.hand_params, res_gt.metric_scale, res_gt.camera, steps
        ),
    }
    row["object_quality"] = {
        "reconstructed": _object_quality(
            inp, res.metric_scale, truth, scene.object_mesh, settings.chamfer_samples
        ),
        "gt": _object_quality(
            inp_gt, res_gt.metric_scale, truth_gt, scene.object_mesh, settings.chamfer_samples
        ),
    }
    timings = {"scene": t_scene, "fast": dict(res.timings)}
    row["stops"] = {s.name: [s.iterations, s.stop_reason] for s in res.stages}
    if paper is not None:
        res_p = optimize(inp, paper)
        row["paper"] = evaluate_hand(
            truth, res_p.hand_params, res_p.metric_scale, res_p.camera, steps
        )
        row["paper_stops"] = {s.name: [s.iterations, s.stop_reason] for s in res_p.stages}
        timings["paper"] = dict(res_p.timings)
    timings["total"] = time.perf_counter() - t0
    row["timings"] = timings
    if gallery:
        row["_gallery"] = _gallery_images(res, inp.image)
    return row


# ----------------------------------------------------------------------------------------------
# the whole benchmark
# ----------------------------------------------------------------------------------------------


def _capped(cfg: OptimConfig, cap: int) -> OptimConfig:
    if cap <= 0:
        return cfg
    return with_overrides(
        cfg,
        {
            "camera.max_iters": min(cfg.camera.max_iters, cap),
            "contact.max_iters": min(cfg.contact.max_iters, cap),
            "refine.max_iters": min(cfg.refine.max_iters, cap),
        },
    )


def _warm_up(fast: OptimConfig) -> None:
    """One tiny run so that lazy initialisation is not charged to the first timed scene."""
    from easyhoi.optim.run import optimize
    from easyhoi.synth.scene import make_scene

    tiny = {"camera.max_iters": 2, "contact.max_iters": 2, "refine.max_iters": 2}
    scene = make_scene(999_999, "box", "power", image_size=64, photo=False)
    optimize(scene.to_hoi_input("none"), with_overrides(fast, tiny))


def run_benchmark(
    settings: BenchmarkSettings | None = None, progress: Callable[[str], None] | None = None
) -> dict:
    """Run the benchmark; returns a JSON-ready dict (plus ``gallery`` images, arrays).

    Keys: ``settings``, ``machine`` (versions, load average before / after), ``scenes`` (one
    dict per scene, see :func:`evaluate_scene`), ``wall_seconds``, ``gallery`` (list of dicts of
    (H, W, 3) uint8 images; not JSON). The numbers are deterministic except those under
    ``timings``, ``wall_seconds`` and ``machine`` (see :func:`strip_timings`).
    """
    settings = settings or BenchmarkSettings()
    fast = get_preset("fast").optim
    paper = _capped(get_preset("paper").optim, settings.paper_cap)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    _warm_up(fast)
    rows, gallery = [], []
    for i, spec in enumerate(scene_specs(settings.scenes, settings.seed)):
        use_paper = paper if i < settings.paper_scenes else None
        row = evaluate_scene(spec, settings, fast, use_paper, gallery=i < settings.gallery)
        if "_gallery" in row:
            gallery.append(
                {"title": f"{spec[1]} / {spec[2]} (seed {spec[0]})", **row.pop("_gallery")}
            )
        rows.append(row)
        if progress is not None:
            progress(
                f"scene {i + 1}/{settings.scenes} ({spec[1]}, {spec[2]}): "
                f"{row['timings']['total']:.1f} s"
            )
    return {
        "settings": asdict(settings),
        "machine": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            "torch": torch.__version__,
            "torch_threads": torch.get_num_threads(),
            "cpus": os.cpu_count(),
            "load_before": [round(x, 2) for x in load0],
            "load_after": [round(x, 2) for x in os.getloadavg()],
        },
        "scenes": rows,
        "wall_seconds": time.perf_counter() - t0,
        "gallery": gallery,
    }


def strip_timings(report: dict) -> dict:
    """The report without its non-deterministic parts (timings, wall time, machine, gallery)."""
    skip = {"timings", "wall_seconds", "machine", "gallery"}

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items() if k not in skip}
        if isinstance(x, list):
            return [clean(v) for v in x]
        return x

    return clean(report)
