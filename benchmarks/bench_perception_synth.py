"""Held-object perception on synthetic photos, against the scenes' own masks.

The development photos (``bench_perception.py``) are few, and every setting of the perception
was chosen on them; a synthetic photo (``easyhoi.synth.make_scene``: a rendered hand holding a
scanned-like object in front of a blurred background) comes with its exact hand and object
masks, and there are as many as there are seeds. Each photo goes through the same path as in
``bench_perception.py`` (MediaPipe, every hand segmented, the hand picked as the product picks
it), automatically, with one object point (the object mask's deepest pixel) and with an object
box (its bounding box grown by 5 %), and is scored the same way (``summary``).

The renders are not photos (one light, plain materials, painted bands and stripes on some
objects, a stylised hand that the landmark model finds less well than a real one), so the
rates are not those of real photos. What they are for: a change to the perception is checked
on scenes it was not chosen on, a rate that moves on fresh seeds and not on the development
photos (or the other way round) says the change is tuned to particular pixels.

Usage::

    python benchmarks/bench_perception_synth.py --seeds 0 40          # seeds 0..39
    python benchmarks/bench_perception_synth.py --seeds 100 140 --size 512 --no-point

Results: a line per scene on stderr, the summary on stdout and in
``benchmarks/results/bench_perception_synth.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
from bench_perception import RESULTS, run_photo, summary  # noqa: E402


def scene_reference(scene) -> dict:
    """The reference ``bench_perception.run_photo`` takes, from a synthetic scene's masks."""
    from tests.perception_refs import deepest_point

    obj = np.asarray(scene.object_mask, bool)
    return {
        "image": f"synthetic seed {scene.seed}",
        "hand": [np.asarray(scene.hand_mask, bool)],
        "holds": [True],
        "object": obj if obj.any() else None,
        "visibly_held": bool(obj.any()),
        "point": deepest_point(obj),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=(0, 20), metavar=("FIRST", "END"),
                    help="scene seeds FIRST..END-1 (default 0 20)")  # fmt: skip
    ap.add_argument("--size", type=int, default=384, help="photo side in pixels (default 384)")
    ap.add_argument("--no-point", action="store_true", help="skip the point and box runs")
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_perception_synth.json")
    args = ap.parse_args(argv)
    first, end = args.seeds
    if end <= first:
        ap.error(f"--seeds {first} {end}: END must be larger than FIRST")
    os.environ.setdefault("OMP_NUM_THREADS", "1")

    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.mediapipe_hand import MediaPipeHands
    from easyhoi.synth import make_scene

    detector, segmenter = MediaPipeHands(), ClassicalHOISegmenter()
    rows = []
    for seed in range(first, end):
        scene = make_scene(seed, image_size=args.size)
        row = run_photo(scene.image, scene_reference(scene), detector, segmenter,
                        not args.no_point)  # fmt: skip
        row.update(seed=seed, kind=scene.object.kind, grasp=scene.grasp.grasp_type)
        rows.append(row)
        pt, box = row.get("iou_point", float("nan")), row.get("iou_box", float("nan"))
        line = f"seed {seed:4d} {row['kind']:9s} {row['grasp']:9s} iou={row['iou']:.2f} "
        print(line + f"low={row['low']} pt={pt:.2f} box={box:.2f}", file=sys.stderr, flush=True)
    summ = summary(rows)
    print(json.dumps(summ, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"summary": summ, "rows": rows}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
