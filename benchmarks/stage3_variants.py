"""Stage 3 settings compared on the same contact snapshots: the refinement's variants, paired.

A whole ``easyhoi bench`` run per setting repeats stages 1 and 2, which a refinement setting does
not change. This script runs the fast preset once per scene (the benchmark's scenes:
``--seed``, ``--scenes``, the default perturbation), whose own stage 3 is the preset's, then
re-runs stage 3 from that run's contact snapshot with each ``--variant``, and measures every
resulting hand against the truth as the benchmark does (untilted gravity only:
S.D. with the GT camera's down and with the contact snapshot's own, I.V. both ways, MPJPE, 2D
keypoints). The contact snapshot and the ground-truth hand are measured too.

    python benchmarks/stage3_variants.py --seed 185 --scenes 20 \\
        --variant free optim.refine.rigid_first=false \\
        --variant soft optim.refine.penetration_weight=500 optim.refine.contact_weight=2

Per variant: the mean of each metric and the ratio variant / preset with its paired-bootstrap
95 % interval (``easyhoi.synth.tables.ratio_interval``, as ``compare_synth.py`` reads two
whole runs). Every scene's row goes to ``--out`` (JSON lines, written as each scene ends).
A variant chosen here is then checked with whole runs on other fresh seeds
(``easyhoi bench --set``, ``compare_synth.py``): stage 3 alone does not show what a setting
costs when its stage starts from another snapshot.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_synth import METRICS  # noqa: E402  (key, label) read per hand
from preset_overrides import fast_overrides  # noqa: E402

#: The name of the preset's own stage 3 among the rows' hands.
PRESET = "preset"
#: The prefix of the settings a variant may change (stage 3's).
REFINE = "optim.refine."


def parse_variants(ap: argparse.ArgumentParser, groups: list[list[str]]) -> dict[str, dict]:
    """``[[NAME, KEY=VALUE, ...], ...]`` -> {NAME: overrides}; ``ap.error`` on a bad name,
    a repeated one, a variant without overrides, an override the fast preset refuses or one
    outside stage 3's settings."""
    out: dict[str, dict] = {}
    for group in groups:
        name, items = group[0], group[1:]
        if "=" in name or name in out or name in (PRESET, "contact", "gt"):
            ap.error(f"--variant needs a new NAME first, got {name!r}")
        if not items:
            ap.error(f"--variant {name} sets nothing: give KEY=VALUE after its name")
        out[name] = fast_overrides(ap, items)
        other = [k for k in out[name] if not k.startswith(REFINE)]
        if other:  # the snapshot comes from the preset's stages 1 and 2: they would not change
            ap.error(f"--variant {name}: only {REFINE}* settings act on stage 3, got {other}")
    return out


def variant_configs(variants: dict[str, dict]) -> dict:
    """{NAME: the fast preset's optimizer config with NAME's overrides}, built once."""
    from easyhoi.config import get_preset, with_overrides

    return {name: with_overrides(get_preset("fast"), ov).optim for name, ov in variants.items()}


def run_scene(spec, configs: dict, settings) -> dict:
    """One scene: the fast run, then stage 3 from its contact snapshot per variant config. The
    preset's own stage 3 is the run's (``refine_from_contact`` with the preset's config
    reproduces it exactly, ``tests/test_benchmark.py``), read with the contact snapshot's camera
    as the variants are."""
    from easyhoi.config import get_preset
    from easyhoi.hand import load_hand_model
    from easyhoi.optim.run import optimize
    from easyhoi.optim.state import Scene as OptScene
    from easyhoi.synth.evaluate import _truth, evaluate_hand, gt_hand_state, refine_from_contact
    from easyhoi.synth.perturb import get_perturbation
    from easyhoi.synth.scene import make_scene

    seed, kind, grasp = spec
    t0 = time.perf_counter()
    fast = get_preset("fast").optim
    scene = make_scene(seed, kind, grasp, image_size=settings.image_size, hold=settings.hold)
    inp = scene.to_hoi_input(get_perturbation(settings.perturbation), seed=seed)
    truth = _truth(scene, inp, fast)
    res = optimize(inp, fast)
    opt_scene = OptScene.from_input(inp, load_hand_model(inp.hand_model), fast.torch_dtype)
    contact = next(s for s in res.stages if s.name == "contact")

    def measured(params, m, camera) -> dict:
        ev = evaluate_hand(truth, params, m, camera, settings.sd_steps, cone=False)
        return {k: float(ev[k]) for k, _ in METRICS}

    row = {"seed": seed, "kind": kind, "grasp": grasp}
    row["contact"] = measured(contact.hand_params, contact.metric_scale, contact.camera)
    row["gt"] = measured(*gt_hand_state(scene, inp))
    row[PRESET] = measured(res.hand_params, res.metric_scale, contact.camera)
    for name, cfg in configs.items():
        params, m = refine_from_contact(inp, res, cfg, opt_scene)
        row[name] = measured(params, m, contact.camera)
    row["seconds"] = time.perf_counter() - t0
    return row


def summary(rows: list[dict], names: list[str]) -> list[dict]:
    """Per hand (contact snapshot, preset, each variant, GT) and metric: the mean, and for the
    variants the ratio to the preset with its paired 95 % interval."""
    from easyhoi.synth.tables import ratio_interval

    out = []
    for name in ["contact", PRESET, *names, "gt"]:
        for key, label in METRICS:
            v = np.array([r[name][key] for r in rows], dtype=np.float64)
            rec = {"hand": name, "metric": label, "mean": float(v.mean())}
            if name in names:
                base = np.array([r[PRESET][key] for r in rows], dtype=np.float64)
                rec["ratio"], rec["low"], rec["high"] = ratio_interval(v, base)
            out.append(rec)
    return out


def table(recs: list[dict]) -> str:
    out = ["| hand | metric | mean | / preset (95 % CI) |", "|---|---|---|---|"]
    for r in recs:
        ci = f"{r['ratio']:.2f} ({r['low']:.2f}-{r['high']:.2f})" if "ratio" in r else ""
        out.append(f"| {r['hand']} | {r['metric']} | {r['mean']:.3f} | {ci} |")
    return "\n".join(out)


def main(argv=None) -> int:
    from easyhoi.synth.benchmark import BenchmarkSettings, scene_specs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True, help="scene seed (as easyhoi bench)")
    ap.add_argument("--scenes", type=int, default=20, help="number of scenes (default 20)")
    ap.add_argument(
        "--variant",
        nargs="+",
        action="append",
        default=[],
        metavar="NAME KEY=VALUE",
        help="a named stage-3 setting (repeatable)",
    )
    ap.add_argument("--out", type=Path, default=None, help="JSON lines, one per scene")
    args = ap.parse_args(argv)
    if args.scenes < 1:
        ap.error("--scenes must be at least 1")
    variants = parse_variants(ap, args.variant)
    configs = variant_configs(variants)
    settings = BenchmarkSettings(scenes=args.scenes, seed=args.seed)
    rows = []
    sink = args.out.open("w") if args.out else None
    try:
        for spec in scene_specs(args.scenes, args.seed):
            rows.append(run_scene(spec, configs, settings))
            if sink:
                sink.write(json.dumps(rows[-1]) + "\n")
                sink.flush()
            r = rows[-1]
            moved = {n: round(r[n]["sd_own_cm"], 2) for n in ["contact", PRESET, *variants]}
            print(f"scene {r['seed']} ({r['kind']}, {r['grasp']}): S.D. own camera {moved}",
                  flush=True)  # fmt: skip
    finally:
        if sink:
            sink.close()
    print(f"\n{len(rows)} scenes\n\n{table(summary(rows, list(variants)))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
