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
  optimization (its stage snapshots give the hand errors per stage with the true object);
* **object quality**: C.D. / F@5mm / F@10mm (MOHO convention) of the input object at the
  result's metric scale against the GT object;
* **runtime**: seconds per stage of ``fast`` on every scene and of ``paper`` on the first
  ``paper_scenes`` scenes (with their quality, side by side).

Units and frames of every number (:func:`evaluate_hand`): hands are compared in the GT world
frame (metres, the object's metric frame) after mapping the result's object frame with the GT
similarity (``canonical_from_world``): a metric-scale error therefore shows up as a hand error.
S.D. (cm) uses gravity along +y of the GT camera mapped to the object frame (scenes are built
with ``hold=True``: the camera rolled so that the GT grasp holds under it); I.V. (cm^3) and
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
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch

from easyhoi.config import OptimConfig, get_preset, with_overrides
from easyhoi.errors import InvalidInputError
from easyhoi.synth.evaluate import (
    _estimator_hand,
    _object_quality,
    _stage_metrics,
    _truth,
    evaluate_hand,
    gt_hand_state,
    refine_from_contact,
)
from easyhoi.synth.grasp import GRASP_TYPES
from easyhoi.synth.objects import OBJECT_KINDS
from easyhoi.synth.perturb import get_perturbation

logger = logging.getLogger(__name__)

__all__ = ["LOSS_ABLATIONS", "BenchmarkSettings", "run_benchmark", "scene_specs", "strip_timings"]

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
    hold: bool = True
    """Turn each camera about its axis so that the GT grasp holds the object under image-down
    gravity (``make_scene(hold=True)``): S.D. then separates grasps that hold from ones that do
    not (with random rolls the GT grasp itself fell in about half of the scenes)."""
    sd_steps: int = 35
    """Simulation steps of S.D. (35: ObMan's code)."""
    gallery: int = 4
    """Scenes rendered in the gallery (the first ones)."""
    chamfer_samples: int = 30000
    """Surface samples per mesh of C.D. / F-scores."""
    sd_cone: bool = True
    """Also simulate the gravity cone of each hand (``sd_cone_cm``, 7 simulations instead of 1)."""
    loss_ablation: bool = True
    """Re-run stage 3 without each loss term (the loss ablation table; 4 refinements and their
    simulations per scene)."""
    fast_overrides: dict = field(default_factory=dict)
    """Overrides of the fast preset, ``{"optim.refine.prior_weight": 5.0, ...}`` as
    :func:`easyhoi.config.with_overrides` takes them: a variant, run on the same scenes as the
    preset itself (``benchmarks/compare_synth.py`` compares the two reports)."""

    def __post_init__(self):
        if self.scenes < 1 or self.paper_scenes < 0 or self.paper_cap < 0 or self.sd_steps < 1:
            raise InvalidInputError(f"invalid benchmark settings: {self}")
        get_perturbation(self.perturbation)
        self.fast_config()  # an unknown path or a wrong value fails here, before any scene

    def fast_config(self):
        """The fast preset with :attr:`fast_overrides` applied (``EasyHOIConfig``)."""
        return with_overrides(get_preset("fast"), dict(self.fast_overrides))


def scene_specs(n: int, seed: int = 0) -> list[tuple[int, str, str]]:
    """``(scene_seed, object_kind, grasp_type)`` of the ``n`` scenes: kinds cycle, grasps shift.

    Every kind appears before any repeats; over 15 scenes every (kind, grasp) pair appears once.
    """
    k, g = len(OBJECT_KINDS), len(GRASP_TYPES)
    return [
        (1000 * seed + i, OBJECT_KINDS[i % k], GRASP_TYPES[(i % k + i // k) % g]) for i in range(n)
    ]


# ----------------------------------------------------------------------------------------------
# one scene
# ----------------------------------------------------------------------------------------------


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
    from easyhoi.optim.state import Scene as OptScene
    from easyhoi.synth.scene import make_scene

    seed, kind, grasp = spec
    t0 = time.perf_counter()
    scene = make_scene(seed, kind, grasp, image_size=settings.image_size, hold=settings.hold)
    level = get_perturbation(settings.perturbation)
    inp = scene.to_hoi_input(level, seed=seed)
    t_scene = time.perf_counter() - t0
    truth = _truth(scene, inp, fast)
    res = optimize(inp, fast)
    steps = settings.sd_steps
    row: dict = {"seed": seed, "kind": kind, "grasp": grasp, "gravity_sd_cm": scene.gravity_sd_cm}
    cone = settings.sd_cone
    row["stages"] = _stage_metrics(truth, res, steps, cone=cone)
    row["ground_truth"] = evaluate_hand(truth, *gt_hand_state(scene, inp), steps, cone=cone)
    # loss ablation: stage 3 from the contact snapshot
    opt_scene = OptScene.from_input(inp, load_hand_model(inp.hand_model), fast.torch_dtype)
    contact = next(s for s in res.stages if s.name == "contact")
    abl = {"full": row["stages"]["refine"]}
    for name, key in LOSS_ABLATIONS.items():
        if key is None or not settings.loss_ablation:
            continue
        cfg = with_overrides(fast, {f"refine.{key}": 0.0})
        params, m_abl = refine_from_contact(inp, res, cfg, opt_scene)
        abl[name] = evaluate_hand(truth, params, m_abl, contact.camera, steps, cone=cone)
    row["loss_ablation"] = abl
    # the same scene with the GT object shape (same canonical frame, no deformation)
    gt_level = replace(level, object=replace(level.object, shape="oracle", amplitude=0.0))
    inp_gt = scene.to_hoi_input(gt_level, seed=seed)
    truth_gt = _truth(scene, inp_gt, fast)
    res_gt = optimize(inp_gt, fast)
    gt_stages = _stage_metrics(truth_gt, res_gt, steps, simulate=False)
    gt_stages["refine"] = evaluate_hand(
        truth_gt, res_gt.hand_params, res_gt.metric_scale, res_gt.camera, steps, cone=cone
    )
    row["object_input"] = {
        "estimator": _estimator_hand(truth, inp),
        "reconstructed": row["stages"]["refine"],
        "gt": gt_stages["refine"],
        "gt_stages": gt_stages,
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
            truth, res_p.hand_params, res_p.metric_scale, res_p.camera, steps, cone=cone
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
    fast = settings.fast_config().optim
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
