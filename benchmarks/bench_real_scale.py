"""Real photos of objects whose size is known: the reconstructed object's metric size.

The object's metric size comes from the hand (a hand model of known size fitted to the detected
keypoints gives the image scale at the hand, and the object touches the hand). On synthetic
scenes ``bench_object.py`` measures it against the truth; this script does the same on the
development photos whose held object is of a kind with a standard size (a beverage can, a
game controller, pens, phones, a sheet of paper). Each photo runs through the whole pipeline
(``easyhoi.pipeline.reconstruct_photo``, fast preset, seed 0) with one object point, the
deepest point of the photo's reference object mask (as ``bench_perception.py --click-only``),
so that a wrong automatic choice does not hide the size.

Per photo: the sides of the reconstructed object's oriented bounding box (metres, from
``HOIResult.object_mesh_metric``), its longest and second side against the range of its kind,
and the relative error of each side to that range (0 inside it, else the distance to the
nearer end over that end). The summary is the median over photos of the longest side's error,
with the means of that error and of the log of the longest side over the middle of its range
(below 0: the objects come out small).

The sizes are those of the kind, not of the very object (the models are not known), so a
range stands for the kinds whose sizes vary (pens, phones); a can's diameter and a sheet's
sides are standard.

Usage::

    python benchmarks/bench_real_scale.py [--only NAME] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_perception import DATA, RESULTS, reference  # noqa: E402

#: Kind -> (longest side range, second side range), millimetres.
KINDS = {
    # 330 ml (115 mm) and 355 ml (122 mm) cans share the 66 mm diameter
    "beverage can": ((115.0, 122.0), (66.0, 66.0)),
    # an Xbox-style controller, about 153 x 104 x 61 mm
    "game controller": ((148.0, 158.0), (100.0, 108.0)),
    # ballpoint pens and fine markers
    "pen": ((125.0, 150.0), (8.0, 14.0)),
    "marker": ((120.0, 145.0), (10.0, 20.0)),
    # from a small phone of 2010 to a large one of today
    "phone": ((110.0, 165.0), (58.0, 78.0)),
    # A4 (297 x 210) or US letter (279 x 216)
    "paper sheet": ((279.0, 297.0), (210.0, 216.0)),
}

#: Reference file stem -> kind of its held object (the reference's own label says what it is).
PHOTOS = {
    "images__hort-can": "beverage can",
    "images__easyhoi-game-controller": "game controller",
    "images__hort-phone": "phone",
    "photos-dev__ihoi-demo_01": "pen",
    "photos-dev__ihoi-demo_02": "pen",
    "photos-dev__ihoi-demo_07": "phone",
    "photos-dev__ihoi-demo_11": "pen",
    "photos-dev__mow-furniture_v_533h9YdqRm4_frame000212": "marker",
    "photos-dev__mow-packing_v_k_QXkSKWv-M_frame000006": "phone",
    "photos-dev__mow-packing_v_pX_bqy3wKoQ_frame000034": "paper sheet",
    "photos-dev__mow-study_v_nSqa1TLOsrc_frame000381": "pen",
}


def range_error(value: float, lo: float, hi: float) -> float:
    """Relative distance of ``value`` to the range [lo, hi]: 0 inside, else to the nearer end
    over that end (0.5: half as large again as the largest, or 0.5 below the smallest)."""
    if value < lo:
        return (lo - value) / lo
    if value > hi:
        return (value - hi) / hi
    return 0.0


def obb_sides_mm(mesh) -> np.ndarray:
    """Sides of the mesh's oriented bounding box in millimetres, longest first."""
    return np.sort(np.asarray(mesh.bounding_box_oriented.primitive.extents) * 1000.0)[::-1]


def run_photo(ref_path: Path, kind: str) -> dict:
    from easyhoi.config import get_preset
    from easyhoi.errors import EasyHOIError
    from easyhoi.io.image import load_image
    from easyhoi.perception.prompts import Prompts
    from easyhoi.pipeline import reconstruct_photo

    ref = reference(ref_path)
    photo = DATA / ref["image"]
    # the prompt is in pixels of the photo as stored; the reference may be of another size
    w, h = load_image(photo).original_size
    h0, w0 = ref["hand"][0].shape if ref["hand"] else (h, w)
    x, y = ref["point"]
    prompts = Prompts(object_points=((float(x) * w / w0, float(y) * h / h0),))
    row = {"photo": photo.name, "kind": kind}
    try:
        rec = reconstruct_photo(photo, None, get_preset("fast"), seed=0, prompts=prompts)
    except EasyHOIError as exc:
        row["error"] = f"{type(exc).__name__}: {exc}"
        return row
    sides = obb_sides_mm(rec.result.object_mesh_metric())
    (l_lo, l_hi), (s_lo, s_hi) = KINDS[kind]
    row.update(
        shape=rec.inp.meta.get("object_shape", {}).get("shape"),
        sides_mm=[round(float(v), 1) for v in sides],
        longest_err=round(range_error(float(sides[0]), l_lo, l_hi), 3),
        second_err=round(range_error(float(sides[1]), s_lo, s_hi), 3),
        longest_ratio=round(float(sides[0]) / (0.5 * (l_lo + l_hi)), 3),
    )
    return row


def table(rows: list[dict]) -> str:
    out = [
        "| photo | kind | shape | sides mm | longest: known | error | second: known | error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        (l_lo, l_hi), (s_lo, s_hi) = KINDS[r["kind"]]
        known_l = f"{l_lo:.0f}" if l_lo == l_hi else f"{l_lo:.0f}-{l_hi:.0f}"
        known_s = f"{s_lo:.0f}" if s_lo == s_hi else f"{s_lo:.0f}-{s_hi:.0f}"
        if "error" in r:
            out.append(f"| {r['photo']} | {r['kind']} | failed: {r['error']} | | | | | |")
            continue
        sides = " x ".join(f"{v:.0f}" for v in r["sides_mm"])
        out.append(
            f"| {r['photo']} | {r['kind']} | {r['shape']} | {sides} | {known_l} | "
            f"{r['longest_err']:.0%} | {known_s} | {r['second_err']:.0%} |"
        )
    return "\n".join(out)


def summary(rows: list[dict]) -> dict:
    ok = [r for r in rows if "error" not in r]
    return {
        "photos": len(rows),
        "reconstructed": len(ok),
        "longest_err_median": float(np.median([r["longest_err"] for r in ok])) if ok else None,
        "second_err_median": float(np.median([r["second_err"] for r in ok])) if ok else None,
        "longest_in_range": sum(r["longest_err"] == 0 for r in ok),
        "longest_ratio_median": float(np.median([r["longest_ratio"] for r in ok])) if ok else None,
        # means as well: a median over a dozen photos is whichever photo lies in the middle
        "longest_err_mean": float(np.mean([r["longest_err"] for r in ok])) if ok else None,
        "log_ratio_mean": float(np.mean([np.log(r["longest_ratio"]) for r in ok])) if ok else None,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--refs", type=Path, default=ROOT / "tests" / "data" / "perception_refs")
    ap.add_argument("--only", default="", help="substring of the reference names to run")
    ap.add_argument("--json", type=Path, default=RESULTS / "bench_real_scale.json")
    args = ap.parse_args(argv)
    rows = []
    for stem, kind in sorted(PHOTOS.items()):
        path = args.refs / f"{stem}.json"
        if args.only not in stem:
            continue
        if not path.is_file():
            print(f"skipped (no reference): {stem}", file=sys.stderr)
            continue
        ref = reference(path)
        if not (DATA / ref["image"]).is_file():
            print(f"skipped (photo not found): {ref['image']}", file=sys.stderr)
            continue
        row = run_photo(path, kind)
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    if not rows:
        print("no photo found", file=sys.stderr)
        return 1
    print(table(rows))
    summ = summary(rows)
    print()
    print(json.dumps(summ, indent=1))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"photos": rows, "summary": summ}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
