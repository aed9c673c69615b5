"""Benchmark of the three-stage optimizer: the "fast" preset against the "paper" preset (CPU).

Both presets run on the same synthetic hand-object scenes (``easyhoi.testing.optim_scenes``: an
OpenHand grasping a cylinder or a box, masks rendered from the ground truth, the hand estimate
perturbed) in the same process, one intra-op thread (the optimizer's small problems run several
times slower oversubscribed on a busy machine), each preset ``--repeat`` times (3) in turn: the
fastest run's seconds per stage and in total (the least disturbed by other jobs; the runs must
give the same hand, which checks determinism), and quality against the ground truth, every
metric measured the same way for both presets (at the scene's size): hand mask IoU, object
(amodal) mask IoU, penetration depth (cm), intersection volume (cm^3, solid), |signed contact
distance| (cm), mean hand-vertex error (cm, object frame scaled by the TRUE metric scale), the
metric-scale error (%) and the simulation displacement S.D. (cm;
:func:`easyhoi.metrics.simulation_displacement`, 35 steps, gravity down in the ground-truth
image, the same for every row). A ``gt`` row gives the ground-truth hand's values (its grasp has
a 1 mm gap and does not hold the object in the simulation: S.D. ~10 cm; an S.D. far below that
comes from a hand buried in the object, see the I.V. column).

Comparison ("fast no worse than paper by more than 5 %", the issue's target): an IoU is worse
when ``fast < 0.95 * paper``; a lower-is-better metric when ``fast > 1.05 * paper + tol`` with a
small absolute tolerance per metric (``METRICS``: 0.05 cm penetration / contact / hand error,
0.125 cm^3 = one voxel of the I.V. grid, 0.5 points of scale error, 0.5 cm S.D.), because 5 %
of a value near zero is below what the metric resolves (see :func:`_worse`). The summary lists,
per scene, the metrics on which fast is worse by that rule.

The paper preset is the paper's schedule (1000-iteration caps, 256 px renders, no early
stopping besides the stop losses): 13-18 s per scene on one idle CPU core (fast: 1.3-1.4 s).

These toy scenes are single-touch: the palm rests on the object 1 mm off, the fingers do not
close on it, so the ground-truth hand does not hold it (S.D. ~10 cm). Fast's depth scan assumes
a grasp (it puts the contact zones on the surface) and places such a hand too deep; the targets
concern hands holding objects and are measured on the held grasps of the synthetic benchmark
(``easyhoi bench --paper-scenes N``, docs/benchmark.md).
``--paper-cap N`` caps each of its stages at N iterations (registrations at 100/200 are kept
when they fit); the table says which cap ran.

Usage::

    python benchmarks/bench_optim.py                 # 2 scenes, full paper schedule, 3 runs
                                                     # per preset (fastest time kept; ~2 min)
    python benchmarks/bench_optim.py --quick         # 1 scene, paper capped at 250 iterations
    python benchmarks/bench_optim.py --repeat 1      # one run per preset
    python benchmarks/bench_optim.py --paper-cap 300

Results: a table on stdout and ``benchmarks/results/bench_optim.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NOISE = dict(rot_noise=0.05, trans_noise=0.02, depth_noise=0.05, pose_noise=0.03)
#: (key, column label, higher is better, absolute tolerance). See :func:`_worse`.
METRICS = (
    ("hand_iou", "hand IoU", True, 0.0),
    ("object_iou", "obj IoU", True, 0.0),
    ("pen_cm", "pen cm", False, 0.05),
    ("iv_cm3", "IV cm3", False, 0.125),
    ("contact_cm", "|cont| cm", False, 0.05),
    ("hand_err_cm", "hand err cm", False, 0.05),
    ("scale_err_pct", "scale err %", False, 0.5),
    ("sd_cm", "S.D. cm", False, 0.5),
)


def _capped(cfg, cap: int):
    if cap <= 0:
        return cfg
    return replace(
        cfg,
        camera=replace(cfg.camera, max_iters=min(cfg.camera.max_iters, cap)),
        contact=replace(cfg.contact, max_iters=min(cfg.contact.max_iters, cap)),
        refine=replace(cfg.refine, max_iters=min(cfg.refine.max_iters, cap)),
    )


def _quality(scene, model, params, metric_scale: float, camera, render_size: int) -> dict:
    """Quality of a hand (metric object frame) against the scene's ground truth."""
    import numpy as np
    import torch
    import trimesh

    from easyhoi.metrics import simulation_displacement
    from easyhoi.optim.run import plausibility
    from easyhoi.optim.state import Scene

    sc = Scene.from_input(scene.inp, model, torch.float64)
    params = params.detach().to(dtype=torch.float64)
    p = plausibility(sc, params, metric_scale, camera.detach().to(torch.float64), render_size)
    with torch.no_grad():
        gt = model(scene.gt_hand).vertices[0].numpy() / scene.gt_metric_scale
        v_m = model(params).vertices[0].numpy()
    v = v_m / metric_scale
    hand = trimesh.Trimesh(v_m, model.faces_for(params.side).numpy(), process=False)
    obj = sc.watertight.copy()
    obj.apply_scale(metric_scale)
    # image down of the GROUND-TRUTH camera, in the object frame: the same gravity for every
    # row (a result's own camera would tilt it by that result's rotation error)
    R = scene.gt_camera.R.detach().double().numpy()
    gravity = R.T @ np.array([0.0, 1.0, 0.0])
    sim = simulation_displacement(hand, obj, gravity_dir=tuple(gravity))
    return {
        "hand_iou": p["hand_mask_iou"],
        "object_iou": p["object_mask_iou"],
        "pen_cm": p["penetration_depth_cm"],
        "iv_cm3": p["intersection_volume_cm3"],
        "contact_cm": abs(p["contact_distance_cm"]),
        "in_contact": p["in_contact"],
        "hand_err_cm": float(np.linalg.norm(v - gt, axis=1).mean() * scene.gt_metric_scale * 100),
        "scale_err_pct": abs(metric_scale / scene.gt_metric_scale - 1.0) * 100,
        "sd_cm": float(sim.displacement),
    }


def run_one(scene, preset: str, cap: int, size: int, repeat: int = 1) -> dict:
    """Optimize ``repeat`` times; seconds are the fastest run's (the least disturbed by other
    jobs on the machine), quality the first run's (every run must give the same hand)."""
    import torch

    from easyhoi.config import get_preset
    from easyhoi.optim.run import optimize

    cfg = get_preset(preset).optim
    if preset == "paper":
        cfg = _capped(cfg, cap)
    best, res = None, None
    for _ in range(max(1, repeat)):
        start = time.perf_counter()
        r = optimize(scene.inp, cfg)
        total = time.perf_counter() - start
        if res is None:
            res = r
        elif not all(
            torch.equal(getattr(r.hand_params, k), getattr(res.hand_params, k))
            for k in ("global_orient", "transl", "pose")
        ):
            raise RuntimeError(f"{preset}: two runs on the same input gave different hands")
        if best is None or total < best[0]:
            best = (total, r.timings)
    total, timings = best
    return {
        "preset": preset,
        "paper_cap": cap if preset == "paper" else None,
        "repeat": max(1, repeat),
        "seconds": {
            **{k: round(float(timings.get(k, 0.0)), 3) for k in ("camera", "contact", "refine")},
            "total": round(total, 3),
        },
        "iterations": {s.name: s.iterations for s in res.stages},
        "stop": {s.name: s.stop_reason for s in res.stages},
        # measured at the scene's size (not the preset's render size), the same for both
        **_quality(scene, scene.model, res.hand_params, res.metric_scale, res.camera, size),
    }


def ground_truth_row(scene, size: int) -> dict:
    """The metrics of the ground-truth hand (reference: what a perfect result scores)."""
    q = _quality(scene, scene.model, scene.gt_hand, scene.gt_metric_scale, scene.gt_camera, size)
    return {"preset": "gt", "paper_cap": None, "seconds": {}, **q}


def _worse(fast: float, paper: float, higher_better: bool, abs_tol: float, tol: float = 0.05):
    """Fast is worse than paper by more than ``tol`` (5 %).

    Higher-is-better metrics (IoUs, in [0, 1]): relative only, ``fast < (1 - tol) * paper``.
    Lower-is-better metrics: worse by more than 5 % relative AND by more than ``abs_tol``,
    i.e. ``fast > (1 + tol) * paper + abs_tol``: 5 % of a value near zero (a penetration of
    0.01 cm) is far below what the metric resolves, so a small absolute tolerance per metric
    (METRICS) is added: 0.5 mm for penetration, contact distance and hand error (the paper's
    own tolerance, -5e-3 normalised units, is ~0.5 mm for these ~10 cm objects), one 5 mm voxel
    (0.125 cm^3) of the solid intersection-volume grid, 0.5 percentage points of scale error and
    0.5 cm of simulation displacement (PyBullet's contact margin and a few steps of drift).
    """
    if higher_better:
        return fast < paper * (1 - tol) - abs_tol - 1e-9
    return fast > paper * (1 + tol) + abs_tol


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 scene, paper capped at 250")
    ap.add_argument("--paper-cap", type=int, default=None, help="iterations cap (0 = none)")
    ap.add_argument("--size", type=int, default=128, help="image size of the scenes (px)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3, help="runs per preset; fastest time kept")
    args = ap.parse_args(argv)
    import torch

    from easyhoi.testing.optim_scenes import make_scene

    torch.set_num_threads(args.threads)
    kinds = ["box"] if args.quick else ["cylinder", "box"]
    cap = args.paper_cap if args.paper_cap is not None else (250 if args.quick else 0)
    rows = []
    # warm-up (lazy initialisation: hand regions, kernels) so the first timed run is not charged
    from easyhoi.config import get_preset, with_overrides
    from easyhoi.optim.run import optimize

    tiny = {"camera.max_iters": 2, "contact.max_iters": 2, "refine.max_iters": 2}
    optimize(make_scene("box", size=64).inp, with_overrides(get_preset("fast").optim, tiny))
    for kind in kinds:
        scene = make_scene(kind, size=args.size, **NOISE)
        rows.append({**ground_truth_row(scene, args.size), "scene": kind})
        for preset in ("fast", "paper"):
            r = run_one(scene, preset, cap, args.size, args.repeat)
            r["scene"] = kind
            rows.append(r)
            print(f"{kind:9s} {preset:6s} {r['seconds']['total']:7.1f} s", flush=True)

    print()
    head = (
        f"{'scene':9s} {'preset':11s} {'camera':>7s} {'contact':>8s} {'refine':>7s} {'total':>7s}"
    )
    head += "".join(f" {label:>11s}" for _, label, _, _ in METRICS)
    print(head)
    for r in rows:
        s = r["seconds"]
        name = r["preset"] + (f"@{cap}" if r["preset"] == "paper" and cap > 0 else "")
        line = f"{r['scene']:9s} {name:11s} "
        if s:
            line += f"{s['camera']:7.1f} {s['contact']:8.1f} {s['refine']:7.1f} {s['total']:7.1f}"
        else:
            line += f"{'-':>7s} {'-':>8s} {'-':>7s} {'-':>7s}"
        line += "".join(f" {r[k]:11.3f}" for k, _, _, _ in METRICS)
        print(line)
    summary = {}
    for kind in kinds:
        f = next(r for r in rows if r["scene"] == kind and r["preset"] == "fast")
        p = next(r for r in rows if r["scene"] == kind and r["preset"] == "paper")
        worse = [k for k, _, hb, tol in METRICS if _worse(f[k], p[k], hb, tol)]
        ratio = p["seconds"]["total"] / max(f["seconds"]["total"], 1e-9)
        summary[kind] = {"speedup": round(ratio, 2), "fast_worse_by_over_5pct": worse}
        print(f"{kind}: paper/fast time ratio {ratio:.1f}x; fast worse (>5%) on: {worse or 'none'}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "machine": {
            "python": sys.version.split()[0],
            "platform": platform.platform(),
            "torch": torch.__version__,
            "threads": args.threads,
        },  # fmt: skip
        "size": args.size,
        "paper_cap": cap,
        "rows": rows,
        "summary": summary,
    }
    path = RESULTS / "bench_optim.json"
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
