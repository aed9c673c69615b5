"""The object step's family selection, studied offline on ``bench_object.py --oracle`` results.

Every row of ``bench_object.py --oracle --json F`` holds each family's score as the step
computed it (``scores``: fit IoU, complexity, edge bonus, depth penalty) and each family's C.D.
when it is fitted alone (``oracle``). A selection rule that changes only the complexities
(:data:`easyhoi.perception.shapes.COMPLEXITY`) and the cuboid's edge weight
(:data:`~easyhoi.perception.shapes.EDGE_WEIGHT`) can then be scored exactly without refitting:
the winner is the family with the highest adjusted score, and its C.D. is the oracle's.

The script first checks that the stored constants reproduce every recorded winner, then scores
the stored constants and a grid of alternatives by the mean log C.D. over the scenes (each
scene's C.D. relative to the others', so one large miss does not decide), and prints the best
ones with the per-object count that beats the true-proportion box.

Usage::

    python benchmarks/bench_object.py --objects DIR --seeds 72 73 74 75 --oracle --json a.json
    python benchmarks/shape_selection.py a.json [b.json ...] [--top 10]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from easyhoi.perception import shapes

FAMILIES = shapes.FAMILIES
#: Values tried per constant (revolution stays at 0: only differences between families count).
GRID = {
    "superquadric": (0.0, 0.005, 0.01, 0.02, 0.04),
    "tube": (0.0, 0.015, 0.03, 0.05),
    "cuboid": (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1),
    "slab": (0.06, 0.08, 0.09, 0.11, 0.13),
    "inflation": (0.04, 0.06, 0.08, 0.1, 0.12),
    "handled": (0.015, 0.03, 0.05),
}
EDGE_WEIGHTS = (0.0, 0.05, 0.1, 0.15)


def arrays(rows: list[dict]) -> dict[str, np.ndarray]:
    """Per scene and family: the score without complexity and edge bonus (``base``), the edge
    evidence, the complexity used, the oracle C.D.; and the grip's flat verdict per scene."""
    n, k = len(rows), len(FAMILIES)
    out = {
        "base": np.full((n, k), -np.inf),
        "edge": np.zeros((n, k)),
        "used": np.zeros((n, k)),
        "cd": np.full((n, k), np.inf),
        "flat": np.array([bool(r.get("flat_by_grip", False)) for r in rows]),
    }
    for i, r in enumerate(rows):
        for j, name in enumerate(FAMILIES):
            s = r["scores"].get(name)
            if s is None:
                continue
            bonus = float(s.get("edge_bonus", 0.0))
            out["base"][i, j] = s["score"] + s["complexity"] - bonus
            out["edge"][i, j] = bonus / shapes.EDGE_WEIGHT
            out["used"][i, j] = s["complexity"]
            out["cd"][i, j] = r["oracle"][name]
    return out


def choose(
    a: dict[str, np.ndarray], complexity: dict[str, float], edge_weight: float
) -> np.ndarray:
    """Index of each scene's winner, as :func:`~easyhoi.perception.shapes.fit_shape` picks it
    (scores rounded to 1e-6, ties to the family listed first); the slab keeps the complexity it
    had when the grip called the object flat."""
    pen = np.tile([complexity[f] for f in FAMILIES], (len(a["base"]), 1))
    slab = FAMILIES.index("slab")
    pen[a["flat"], slab] = a["used"][a["flat"], slab]
    score = np.round(a["base"] - pen + edge_weight * a["edge"], 6)
    return np.argmax(score, axis=1)


def evaluate(rows: list[dict], a: dict[str, np.ndarray], idx: np.ndarray) -> dict:
    """Mean log C.D., median C.D. and the objects (mean over their scenes) that beat the box."""
    cd = a["cd"][np.arange(len(rows)), idx]
    per: dict[str, list] = {}
    for r, c in zip(rows, cd, strict=True):
        per.setdefault(r["object"], []).append((c, r["box_cd"]))
    beats = sum(np.mean([c for c, _ in v]) < np.mean([b for _, b in v]) for v in per.values())
    return {"log_cd": float(np.mean(np.log(cd))), "cd_median": float(np.median(cd)),
            "beats_box": int(beats), "objects": len(per)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="bench_object.py --oracle --json files")
    ap.add_argument("--top", type=int, default=10)
    args = ap.parse_args(argv)
    rows = [r for f in args.results for r in json.loads(f.read_text())["rows"]]
    if not rows or any("oracle" not in r or "scores" not in r for r in rows):
        print("every row needs 'oracle' and 'scores': run bench_object.py with --oracle --json")
        return 2
    a = arrays(rows)
    stored = choose(a, shapes.COMPLEXITY, shapes.EDGE_WEIGHT)
    winners = [FAMILIES[i] for i in stored]
    off = sum(w != r["shape"] for w, r in zip(winners, rows, strict=True))
    print(f"{len(rows)} scenes; the stored constants reproduce {len(rows) - off} recorded winners")
    best_cd = a["cd"].min(axis=1)
    print(f"perfect choice: mean log C.D. {float(np.mean(np.log(best_cd))):.4f}")
    print("stored:", evaluate(rows, a, stored))
    tried = []
    for values in itertools.product(*GRID.values()):
        comp = {"revolution": 0.0, **dict(zip(GRID, values, strict=True))}
        for ew in EDGE_WEIGHTS:
            tried.append((evaluate(rows, a, choose(a, comp, ew)), comp, ew))
    tried.sort(key=lambda t: t[0]["log_cd"])
    for res, comp, ew in tried[: args.top]:
        print(json.dumps({"complexity": comp, "edge_weight": ew, **res}))
    return 1 if off else 0


if __name__ == "__main__":
    sys.exit(main())
