"""Two synthetic-benchmark runs of the same scenes, compared scene by scene.

A change to the optimizer is judged on scenes it was not tuned on: run ``easyhoi bench`` on
fresh seeds as the code is and with the change (``--set KEY=VALUE`` for a setting, or another
checkout), then::

    python benchmarks/compare_synth.py BASE/results.json VARIANT/results.json [MORE ...]

Several files per side pool their scenes (``--base A.json B.json --variant C.json D.json``
pairs them in order). Per stage and metric: the mean of each run and the ratio variant / base
with its paired-bootstrap 95 % interval (the scenes resampled together, as the benchmark's own
goal table does, ``easyhoi.synth.tables.ratio_interval``), so that a change is read against
the scenes' spread; then the scenes whose S.D. after the refinement moved the most. S.D. is
chaotic (docs/benchmark.md): a ratio whose interval contains 1 is no change.

Runs must hold the same scenes (seed, object kind, grasp in order); otherwise the script stops
with exit 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

#: (key in a stage's metrics, label) compared per stage.
METRICS = (
    ("sd_cm", "S.D. cm"),
    ("sd_own_cm", "S.D. own camera cm"),
    ("iv_cm3", "I.V. cm3 solid"),
    ("iv_obman_cm3", "I.V. cm3 ObMan"),
    ("mpjpe_ra_cm", "MPJPE cm"),
    ("kp2d_px", "2D kp px"),
)
STAGES = ("initial", "camera", "contact", "refine")


class CompareError(ValueError):
    """The runs cannot be compared (other scenes, a missing stage)."""


def load_scenes(paths: list[Path]) -> list[dict]:
    scenes: list[dict] = []
    for p in paths:
        scenes += json.loads(Path(p).read_text())["scenes"]
    return scenes


def _ids(scenes: list[dict]) -> list[tuple]:
    return [(s["seed"], s["kind"], s["grasp"]) for s in scenes]


def _values(scenes: list[dict], stage: str, key: str) -> np.ndarray:
    try:
        return np.array([float(s["stages"][stage][key]) for s in scenes])
    except (KeyError, TypeError) as exc:
        raise CompareError(f"a scene has no {key!r} at stage {stage!r}") from exc


def _measured(scenes: list[dict], stage: str, key: str) -> bool:
    return all(s["stages"][stage].get(key) is not None for s in scenes)


def compare(base: list[dict], variant: list[dict]) -> list[dict]:
    """One row per (stage, metric): means, ratio variant / base and its interval."""
    from easyhoi.synth.tables import ratio_interval

    if _ids(base) != _ids(variant):
        raise CompareError("the runs hold different scenes (seed, kind, grasp): run both "
                           "with the same --seed and --scenes")  # fmt: skip
    rows = []
    for stage in STAGES:
        for key, label in METRICS:
            if key == "sd_own_cm" and not _measured(base + variant, stage, key):
                continue  # runs from before the benchmark read S.D. in each stage's own camera
            a, b = _values(base, stage, key), _values(variant, stage, key)
            ratio, lo, hi = ratio_interval(b, a)
            rows.append({"stage": stage, "metric": label, "base": float(a.mean()),
                         "variant": float(b.mean()), "ratio": ratio, "low": lo,
                         "high": hi})  # fmt: skip
    return rows


def largest_moves(base: list[dict], variant: list[dict], k: int = 5) -> list[tuple]:
    """The ``k`` scenes whose S.D. after the refinement moved the most: (id, base, variant)."""
    a, b = _values(base, "refine", "sd_cm"), _values(variant, "refine", "sd_cm")
    order = np.argsort(-np.abs(b - a), kind="stable")[:k]
    ids = _ids(base)
    return [(ids[i], float(a[i]), float(b[i])) for i in order]


def table(rows: list[dict]) -> str:
    out = ["| stage | metric | base | variant | variant / base (95 % CI) |", "|" + "---|" * 5]
    for r in rows:
        ci = f"{r['ratio']:.2f} ({r['low']:.2f}-{r['high']:.2f})"
        cells = (r["stage"], r["metric"], f"{r['base']:.3f}", f"{r['variant']:.3f}", ci)
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, help="BASE VARIANT (one results.json each)")
    ap.add_argument("--base", nargs="+", type=Path, default=[], help="results.json of the base")
    ap.add_argument("--variant", nargs="+", type=Path, default=[], help="... of the variant")
    args = ap.parse_args(argv)
    base, variant = list(args.base), list(args.variant)
    if args.files:
        if len(args.files) != 2 or base or variant:
            ap.error("give BASE VARIANT, or --base ... --variant ...")
        base, variant = [args.files[0]], [args.files[1]]
    if not base or not variant:
        ap.error("give BASE VARIANT, or --base ... --variant ...")
    try:
        a, b = load_scenes(base), load_scenes(variant)
        rows = compare(a, b)
    except (OSError, json.JSONDecodeError, KeyError, CompareError) as exc:
        print(f"error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    print(f"{len(a)} scenes\n\n{table(rows)}\n\nlargest moves of S.D. after the refinement:")
    for (seed, kind, grasp), x, y in largest_moves(a, b):
        print(f"  scene {seed} ({kind}, {grasp}): {x:.2f} -> {y:.2f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
