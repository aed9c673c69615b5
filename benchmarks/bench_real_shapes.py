"""Real photos: the object's shape family on perception's outline and on the drawn one.

On synthetic photos ``bench_object.py`` measures the object step against scanned objects; real
photos have no 3D truth, but they have drawn outlines (``tests/data/perception_refs``). For every
development photo with a held object this script runs the perception chain with one object
point, the deepest pixel of the reference object (as ``bench_perception.py --click-only``), and
then the object step (:class:`~easyhoi.perception.objects.SilhouetteReconstructor`, with the
fitted hand's keypoints, as the chain calls it) twice on the same hand-free photo:

* on the amodal mask the chain made from its one-point mask (what the product does; the family
  must be the one the chain recorded, ``same`` in the rows);
* on the drawn reference outline, completed behind perception's hand mask as the amodal step
  completes a mask (:func:`~easyhoi.perception.amodal.occluder_completion`: its convex hull where
  it meets the hand grown by 2 px), with the reference as the visible mask.

Per photo: the one-point mask's IoU with the reference and the winning family on each outline;
the summary counts the families and the inflations (the fallback, a pillow of the outline) on
each. The difference between the two columns is what perception's outline costs the shape step.

Usage::

    python benchmarks/bench_real_shapes.py [--only NAME] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_perception import DATA, RESULTS, fit_to, iou, reference  # noqa: E402

#: Pixels the hand mask is grown by before the hull completes the drawn outline behind it (the
#: amodal step's own margin).
MARGIN_PX = 2.0


def completed_reference(ref_object: np.ndarray, hand_mask: np.ndarray) -> np.ndarray:
    """The drawn (visible) outline completed behind the hand as the amodal step completes a mask."""
    from easyhoi.perception.amodal import occluder_completion

    return occluder_completion(ref_object, hand_mask, MARGIN_PX)


def shape_family(mesh) -> str:
    """The winning family recorded on an object mesh of the silhouette reconstructor."""
    return str((mesh.metadata.get("easyhoi") or {}).get("method"))


def run_photo(path: Path, ref: dict, settings) -> dict:
    """One photo: the chain with one object point, then the object step on both outlines."""
    from types import SimpleNamespace

    from easyhoi.errors import EasyHOIError
    from easyhoi.io.image import load_image
    from easyhoi.perception.chain import perceive
    from easyhoi.perception.objects import SilhouetteReconstructor, hand_inputs
    from easyhoi.perception.prompts import Prompts

    rgb = load_image(path).rgb
    ref = fit_to(ref, rgb.shape[:2])
    row = {"photo": path.name}
    try:
        prompts = Prompts(object_points=(tuple(float(v) for v in ref["point"]),))
        inp, _ = perceive(rgb, settings, prompts=prompts)
    except EasyHOIError as exc:
        return {**row, "error": f"{type(exc).__name__}: {exc}"}
    row["mask_iou"] = iou(inp.object_mask, ref["object"])
    rec = SilhouetteReconstructor()
    hand = SimpleNamespace(params=inp.hand_params, camera=inp.hand_camera,
                           keypoints2d=inp.meta["keypoints2d"], keypoints3d=None)  # fmt: skip
    img = inp.inpainted_image if inp.inpainted_image is not None else inp.image

    def family(amodal, visible) -> str:
        kw = hand_inputs(rec, hand, settings.hand_model, inp.hand_mask, visible)
        return shape_family(rec.reconstruct(img, amodal, **kw))

    row["perception"] = family(inp.amodal_mask, inp.object_mask)
    row["same"] = row["perception"] == (inp.meta.get("object_shape") or {}).get("shape")
    drawn = ref["object"]
    row["drawn"] = family(completed_reference(drawn, inp.hand_mask), drawn)
    return row


def summary(rows: list[dict]) -> dict:
    """Family counts on each outline, the inflations among them, and the photos that differ."""
    ok = [r for r in rows if "error" not in r]
    out = {"photos": len(rows), "reconstructed": len(ok)}
    for side in ("perception", "drawn"):
        counts = Counter(r[side] for r in ok)
        out[f"{side}_families"] = dict(sorted(counts.items()))
        out[f"{side}_inflation"] = counts.get("inflation", 0)
    out["differ"] = sum(r["perception"] != r["drawn"] for r in ok)
    out["chain_family_reproduced"] = sum(bool(r["same"]) for r in ok)
    masks = [r["mask_iou"] for r in ok]
    out["mask_iou_ge_0.5"] = float(np.mean([m >= 0.5 for m in masks])) if masks else 0.0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="substring of the photo names to run")
    ap.add_argument("--json", type=Path, default=RESULTS / "bench_real_shapes.json")
    args = ap.parse_args(argv)
    from easyhoi.settings import resolve_run

    settings = resolve_run(None, seed=0)
    rows = []
    for f in sorted((ROOT / "tests" / "data" / "perception_refs").glob("*.json")):
        if args.only not in f.stem:
            continue
        ref = reference(f)
        if ref["object"] is None or ref["point"] is None:
            continue
        if not (DATA / ref["image"]).is_file():
            print(f"skipped (photo not found): {ref['image']}", file=sys.stderr)
            continue
        row = run_photo(DATA / ref["image"], ref, settings)
        rows.append(row)
        if "error" in row:
            print(f"{row['photo']:45s} {row['error']}", flush=True)
        else:
            fams = f"perception {row['perception']:12s} drawn {row['drawn']}"
            print(f"{row['photo']:45s} mask {row['mask_iou']:.2f}  {fams}", flush=True)
    out = {"summary": summary(rows), "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1))
    print(json.dumps(out["summary"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
