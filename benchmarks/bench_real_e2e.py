"""Real photos end to end: is the reconstruction usable, and does it say so when it is not?

``bench_perception.py`` scores the masks perception hands to the optimizer; this script scores
what a user gets. Every development photo with a reference (``tests/data/perception_refs``)
runs through the whole pipeline (``easyhoi.pipeline.reconstruct_photo``, fast preset, seed 0)
twice: automatically, and with one object point at the reference object mask's deepest pixel
(as ``bench_perception.py`` clicks it). The final hand and object are rendered into the photo
(``viz.masks.rendered_masks``: the parts of each that the camera sees) and compared with the
reference masks, which the pipeline never sees:

* ``hand_iou``: the rendered visible hand against the reference hand it overlaps most;
* ``object_iou``: the rendered visible object against the reference held object;
* ``in_contact``: the result's own contact test (the held objects of the references all touch
  the hand that holds them);
* ``usable``: hand IoU and object IoU >= 0.5 and in contact: hand, object and contact all
  roughly right;
* ``warned``: the run printed a low-confidence warning (a mask, the keypoints, or an object
  moved onto the hand; ``perception.feedback``), or stopped with a named error;
* ``input_object_iou``: perception's visible object mask against the reference, so that a
  usable mask that the optimizer loses (``mask_lost``: input IoU >= 0.5, result < 0.5) shows.
* ``object_hidden``: the share of perception's visible object mask that the rendered hand lies
  over (the photo shows those pixels as object, so nothing should be in front of them).

The summary, per mode, over the photos with a held object: the share usable, the share of the
unusable ones that were warned about, the mean IoUs, and the masks lost by the optimizer.

With ``--resample F`` and/or ``--jpeg Q`` every photo is first resampled by ``F`` and saved
(as a JPEG of quality ``Q``, else losslessly) into a temporary folder, as ``bench_perception.py``
does in memory, and the runs read those copies: the same scenes through pixels no setting was
chosen on. The object point and the references are scaled to the copy's size.

Usage::

    python benchmarks/bench_real_e2e.py [--only NAME] [--workers 2] [--mode auto|point|both]
                                        [--set KEY=VALUE ...] [--out FILE]
    python benchmarks/bench_real_e2e.py --resample 0.85 --jpeg 90   # fresh copies
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_perception import DATA, RESULTS, encoded, fit_to, iou, reference, resample  # noqa: E402
from preset_overrides import add_set_option, fast_overrides  # noqa: E402

#: IoU from which a rendered hand or object counts as roughly right.
USABLE_IOU = 0.5


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def run_one(ref_file: str, mode: str, data: str, overrides: dict | None = None) -> dict:
    """One photo in one mode: the row described in the module docs (``overrides``: configuration
    overrides of the fast preset, as ``--set``)."""
    from easyhoi.config import get_preset, with_overrides
    from easyhoi.errors import EasyHOIError
    from easyhoi.perception.feedback import contact_line, low_confidence_lines
    from easyhoi.perception.prompts import Prompts
    from easyhoi.pipeline import reconstruct_photo
    from easyhoi.viz.masks import rendered_masks

    ref = reference(Path(ref_file))
    path = Path(data) / ref["image"]
    row = {"photo": Path(ref["image"]).name, "mode": mode, "present": ref["object"] is not None}
    prompts = None
    if mode == "point":
        if ref["point"] is None:
            row["status"] = "no reference point"
            return row
        # a reference is drawn on the photo as stored, the pixels prompts are given in (a
        # resampled copy: the point scaled to it)
        from PIL import Image

        with Image.open(path) as im:
            point = fit_to(ref, im.size[::-1])["point"]
        prompts = Prompts(object_points=(tuple(float(v) for v in point),))
    t0 = time.process_time()
    try:
        cfg = with_overrides(get_preset("fast"), overrides or {})
        rec = reconstruct_photo(path, None, cfg, seed=0, prompts=prompts)
    except EasyHOIError as exc:
        row.update(status=type(exc).__name__, warned=True, usable=False,
                   cpu_seconds=time.process_time() - t0)  # fmt: skip
        return row
    row["cpu_seconds"] = time.process_time() - t0
    # the masks on the photo as the pipeline loaded it (a large one is downscaled)
    h, w = rec.inp.size
    ref = fit_to(ref, (h, w))
    rendered = rendered_masks(rec.result, h, w)
    plaus = rec.result.plausibility
    lines = low_confidence_lines(rec.perception, prompted=prompts is not None)
    gap = contact_line(plaus, prompted=prompts is not None)
    row.update(
        status="ok",
        hand_iou=max((iou(rendered["hand_visible"], m) for m in ref["hand"]), default=0.0),
        object_iou=iou(rendered["object_visible"], ref["object"]),
        input_hand_iou=max((iou(rec.inp.hand_mask, m) for m in ref["hand"]), default=0.0),
        input_object_iou=iou(rec.inp.object_mask, ref["object"]),
        object_hidden=_hidden_share(rendered["hand_visible"], rec.inp.object_mask),
        in_contact=bool(plaus.get("in_contact")),
        contact_cm=plaus.get("contact_distance_cm"),
        intersection_cm3=plaus.get("intersection_volume_cm3"),
        warned=bool(lines or gap),
        warnings=[*lines, *([gap] if gap else [])],
        camera_stage={k: v for st in rec.result.stages if st.name == "camera"
                      for k, v in st.extra.items() if k != "hand"},
        stage_seconds={st.name: round(st.seconds, 3) for st in rec.result.stages},
    )  # fmt: skip
    row["usable"] = bool(
        row["hand_iou"] >= USABLE_IOU and row["object_iou"] >= USABLE_IOU and row["in_contact"]
    )
    return row


def write_copies(files, src: Path, dst: Path, factor: float, jpeg: int | None) -> None:
    """Copies of the references' photos under ``dst`` (same relative paths and names; the
    decoder reads the content, not the extension): resampled by ``factor``, saved as JPEG of
    quality ``jpeg`` (OpenCV's encoder, as ``bench_perception.py --jpeg``) or, without it,
    losslessly as PNG."""
    from easyhoi.io.image import load_image

    for f in files:
        rel = reference(Path(f))["image"]
        out = dst / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(encoded(resample(load_image(src / rel).rgb, factor), jpeg))


def _hidden_share(hand_visible: np.ndarray, object_mask: np.ndarray) -> float:
    """Share of the input visible object mask that the result's hand covers in the render: the
    photo shows those pixels as object, so nothing should lie in front of them."""
    m = np.asarray(object_mask, bool)
    return round(float((np.asarray(hand_visible, bool) & m).sum() / max(int(m.sum()), 1)), 3)


def summary(rows: list[dict]) -> dict:
    """Rates over the rows of photos with a held object (module docs)."""
    held = [r for r in rows if r["present"] and r.get("status") != "no reference point"]
    done = [r for r in held if r.get("status") == "ok"]
    bad = [r for r in held if not r.get("usable")]
    secs = [r["cpu_seconds"] for r in held if "cpu_seconds" in r]

    def mean(key, rs):
        vals = [r[key] for r in rs if r.get(key) is not None]
        return round(float(np.mean(vals)), 3) if vals else None

    def share(n, d):
        return round(n / len(d), 3) if d else None

    return {
        "photos": len(held),
        "finished": share(len(done), held),
        "usable": share(sum(bool(r.get("usable")) for r in held), held),
        "unusable_warned": share(sum(bool(r.get("warned")) for r in bad), bad),
        "usable_warned": share(sum(bool(r.get("warned")) for r in held if r.get("usable")),
                               [r for r in held if r.get("usable")]),  # fmt: skip
        "hand_iou_ge_0.5": share(sum(r.get("hand_iou", 0) >= USABLE_IOU for r in held), held),
        "object_iou_ge_0.5": share(sum(r.get("object_iou", 0) >= USABLE_IOU for r in held), held),
        "in_contact": share(sum(bool(r.get("in_contact")) for r in held), held),
        "mean_hand_iou": mean("hand_iou", done),
        "mean_object_iou": mean("object_iou", done),
        "mean_input_object_iou": mean("input_object_iou", done),
        "mean_object_hidden": mean("object_hidden", done),
        "mask_lost": sum(
            r.get("input_object_iou", 0) >= USABLE_IOU and r.get("object_iou", 0) < USABLE_IOU
            for r in done
        ),
        "median_cpu_seconds": round(float(np.median(secs)), 2) if secs else None,
    }  # fmt: skip


def _line(r: dict) -> str:
    if r.get("status") != "ok":
        return f"{r['photo'][:44]:44s} {r['mode']:5s} {r.get('status')}"
    return (
        f"{r['photo'][:44]:44s} {r['mode']:5s} usable={int(r['usable'])} "
        f"hand={r['hand_iou']:.2f} obj={r['object_iou']:.2f} (mask {r['input_object_iou']:.2f}) "
        f"hidden={r['object_hidden']:.2f} contact={int(r['in_contact'])} "
        f"warned={int(r['warned'])} {r['cpu_seconds']:.1f}s"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help="folder the references' photos are in")
    ap.add_argument(
        "--refs",
        type=Path,
        default=ROOT / "tests" / "data" / "perception_refs",
        help="folder of reference files (tests/perception_refs.py format)",
    )
    ap.add_argument("--only", default="", help="substring of the photo names to run")
    ap.add_argument(
        "--mode",
        choices=("auto", "point", "both"),
        default="both",
        help="automatic, one object point at the reference's deepest pixel, or both",
    )
    ap.add_argument("--workers", type=int, default=2, help="processes (one torch thread each)")
    ap.add_argument(
        "--out", type=Path, default=RESULTS / "bench_real_e2e.json", help="JSON of every row"
    )
    ap.add_argument("--resample", type=float, default=1.0,
                    help="run on copies of the photos resampled by this factor")  # fmt: skip
    ap.add_argument("--jpeg", type=int, default=None, metavar="Q",
                    help="run on copies saved as JPEG of quality Q (after --resample)")  # fmt: skip
    add_set_option(ap)
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers must be >= 1, got {args.workers}")
    if not args.resample > 0:
        ap.error(f"--resample must be > 0, got {args.resample}")
    if args.jpeg is not None and not 1 <= args.jpeg <= 100:
        ap.error(f"--jpeg takes a quality from 1 to 100, got {args.jpeg}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    overrides = fast_overrides(ap, args.set)
    files = [f for f in sorted(args.refs.glob("*.json")) if args.only in f.stem]
    if not files:
        print(f"no reference files in {args.refs} matching {args.only!r}", file=sys.stderr)
        return 1
    modes = ("auto", "point") if args.mode == "both" else (args.mode,)
    data = args.data
    if args.resample != 1.0 or args.jpeg is not None:
        data = Path(tempfile.mkdtemp(prefix="easyhoi-copies-"))
        write_copies(files, args.data, data, args.resample, args.jpeg)
    jobs = [(str(f), m, str(data), overrides) for f in files for m in modes]
    rows = []
    with ProcessPoolExecutor(args.workers, initializer=_init_worker) as pool:
        for row, (f, *_) in zip(pool.map(run_one, *zip(*jobs, strict=True)), jobs, strict=True):
            row["half"] = "tune" if zlib.crc32(Path(f).stem.encode()) % 2 == 0 else "check"
            rows.append(row)
            print(_line(row), flush=True)
    summ = {m: summary([r for r in rows if r["mode"] == m]) for m in modes}
    print(json.dumps(summ, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"summary": summ, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
