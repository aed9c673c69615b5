"""Run the offline perception chain on a folder of photos and draw a contact sheet.

Usage::

    python scripts/perception_contact_sheet.py --images DIR --out sheet.png [--table table.md]
    python scripts/perception_contact_sheet.py --images DIR --out sheet.png --chain [--table t.md]

Per photo (one row): input with keypoints, hand mask, object mask (kept components green,
rejected candidates red), inpainted image, amodal mask. The Markdown table lists the outcome of
each step and its time.

Default mode runs the steps directly on the first (most confident) hand. ``--chain`` calls the
library's chain (:func:`easyhoi.perception.chain.perceive`, which tries every hand, fits the hand
model and builds the object mesh) and records its per-step timings; a photo where no hand holds
an object is timed up to the NoObjectError and drawn with the first hand's masks.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from easyhoi.errors import NoHandError, NoObjectError
from easyhoi.io.image import load_image
from easyhoi.perception.amodal import ClassicalAmodalSegmenter, amodal_prompts
from easyhoi.perception.inpaint import OpenCVInpainter
from easyhoi.perception.masks import BONES, ClassicalHOISegmenter
from easyhoi.perception.mediapipe_hand import MediaPipeHands

EXTS = {".jpg", ".jpeg", ".png", ".webp", ".bmp", ".tif", ".tiff"}
TILE = 256


def run_chain(rgb: np.ndarray, detector, segmenter, inpainter, amodal, seed: int = 0) -> dict:
    """Detection -> masks -> inpainting -> amodal mask on one (H, W, 3) uint8 image."""
    out: dict = {"t": {}}
    t = time.perf_counter()
    hands = detector.detect(rgb)
    out["t"]["detect"] = time.perf_counter() - t
    out["hands"] = hands
    if not hands:
        return out
    hand = hands[0]
    t = time.perf_counter()
    seg = segmenter.segment(rgb, hand)
    out["t"]["masks"] = time.perf_counter() - t
    out["seg"] = seg
    if not seg.has_object:
        return out
    t = time.perf_counter()
    out["inpainted"] = inpainter.inpaint(rgb, seg.hand_mask)
    out["t"]["inpaint"] = time.perf_counter() - t
    t = time.perf_counter()
    points, box = amodal_prompts(seg.object_mask, n_per_part=3, seed=seed)
    out["amodal"] = amodal.segment(out["inpainted"], points, box, seg.object_mask)
    out["t"]["amodal"] = time.perf_counter() - t
    out["points"], out["box"] = points, box
    out["amodal_branch"] = amodal.last_meta.get("branch", "")
    return out


def _tile(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    s = TILE / max(h, w)
    r = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    canvas = np.full((TILE, TILE, 3), 255, np.uint8)
    canvas[: r.shape[0], : r.shape[1]] = r
    return canvas


def _overlay(rgb, mask, colour, alpha=0.55):
    out = rgb.astype(np.float64).copy()
    out[mask] = (1 - alpha) * out[mask] + alpha * np.asarray(colour, np.float64)
    return out.astype(np.uint8)


def draw_row(rgb: np.ndarray, res: dict) -> np.ndarray:
    r = max(2, int(max(rgb.shape[:2]) / 200))
    kp_img = rgb.copy()
    for hand in res.get("hands", []):
        kp = np.round(hand.keypoints2d).astype(int)
        for a, b in BONES:
            cv2.line(kp_img, tuple(map(int, kp[a])), tuple(map(int, kp[b])), (255, 255, 0), r)
        for p in kp:
            cv2.circle(kp_img, tuple(map(int, p)), r + 1, (255, 0, 0), -1)
    tiles = [kp_img]
    seg = res.get("seg")
    blank = np.full_like(rgb, 255)
    if seg is not None:
        tiles.append(_overlay(rgb, seg.hand_mask, (255, 0, 255)))
        o = rgb.copy()
        for c in seg.candidates:
            o = _overlay(o, c & ~seg.object_mask, (255, 0, 0), 0.4)
        tiles.append(_overlay(o, seg.object_mask, (0, 255, 0)))
    else:
        tiles += [blank, blank]
    tiles.append(res.get("inpainted", blank))
    if "amodal" in res:
        a = _overlay(res["inpainted"], res["amodal"], (0, 128, 255))
        for u, v in res["points"]:
            cv2.circle(a, (int(u), int(v)), r + 1, (255, 0, 0), -1)
        u0, v0, u1, v1 = (int(x) for x in res["box"])
        cv2.rectangle(a, (u0, v0), (u1, v1), (255, 255, 0), r)
        tiles.append(a)
    else:
        tiles.append(blank)
    return np.concatenate([_tile(t) for t in tiles], axis=1)


CHAIN_STEPS = (
    ("detect", "hand detection"),
    ("segment", "segmentation"),
    ("fit", "hand fit"),
    ("inpaint", "inpainting"),
    ("amodal", "amodal segmentation"),
    ("mesh", "object mesh"),
    ("watertight", "watertight"),
)


def run_perceive(rgb: np.ndarray, seed: int = 0) -> dict:
    """:func:`perceive` on one image: outcome, per-step seconds (summed per step) and total.

    Step times come from the chain's report; when it raises (no hand / no held object) they are
    taken from the progress callback's timestamps instead. ``cpu`` is the process CPU time of
    the whole call: on a busy machine it approximates the wall time the call takes when idle.
    """
    from easyhoi.perception.chain import perceive

    marks: list[tuple[str, float]] = []
    out: dict = {"error": None, "inp": None, "report": None}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        out["inp"], out["report"] = perceive(
            rgb, seed=seed, progress=lambda name: marks.append((name, time.perf_counter()))
        )
        timings = dict(out["report"].timings)
    except (NoHandError, NoObjectError) as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
        end = time.perf_counter()
        stamps = [t for _, t in marks] + [end]
        timings = {name: stamps[i + 1] - stamps[i] for i, (name, _) in enumerate(marks)}
    out["total"] = time.perf_counter() - t0
    out["cpu"] = time.process_time() - c0
    out["hands_tried"] = sum(name.startswith("segmentation") for name, _ in marks)
    out["t"] = {key: 0.0 for key, _ in CHAIN_STEPS}
    for name, sec in timings.items():
        for key, prefix in CHAIN_STEPS:
            if name.startswith(prefix):
                out["t"][key] += sec
    return out


def chain_row(rgb: np.ndarray, res: dict, parts: tuple) -> np.ndarray:
    """Contact-sheet row of a :func:`run_perceive` result (masks recomputed when it raised)."""
    inp = res["inp"]
    if inp is None:
        return draw_row(rgb, run_chain(rgb, *parts))
    from easyhoi.perception.base import HandDetection

    kp = np.asarray(inp.meta["keypoints2d"])
    drawn = {
        "hands": [HandDetection(kp, None, inp.meta["hand_side"], 1.0)],
        "seg": _ChainSeg(inp.hand_mask, inp.object_mask),
        "inpainted": inp.inpainted_image,
    }
    a = _overlay(inp.inpainted_image, inp.amodal_mask, (0, 128, 255))
    return np.concatenate([draw_row(rgb, drawn)[:, : 4 * TILE], _tile(a)], axis=1)


class _ChainSeg:
    def __init__(self, hand_mask, object_mask):
        self.hand_mask, self.object_mask, self.candidates = hand_mask, object_mask, ()


def chain_table(files, args, parts) -> tuple[list[np.ndarray], list[str]]:
    keys = [k for k, _ in CHAIN_STEPS]
    lines = [
        "| photo | hands | side | object | "
        + " | ".join(f"{k} s" for k in keys)
        + " | total s | cpu s |",
        "|" + "---|" * (len(keys) + 6),
    ]
    rows = []
    for f in files:
        rgb = load_image(f).rgb
        res = run_perceive(rgb, seed=args.seed)
        rep = res["report"]
        hands = rep.hands_found if rep else res["hands_tried"]
        obj = "yes" if res["inp"] is not None else "no"
        side = rep.side if rep else "-"
        lines.append(
            f"| {f.name} | {hands} | {side} | {obj} | "
            + " | ".join(f"{res['t'][k]:.2f}" for k in keys)
            + f" | {res['total']:.2f} | {res['cpu']:.2f} |"
        )
        print(lines[-1], flush=True)
        rows.append(chain_row(rgb, res, parts))
    return rows, lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--images", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--table", type=Path, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--chain", action="store_true", help="time the library chain (perceive)")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(int(os.environ.get("EASYHOI_TORCH_THREADS", "1")))
    files = sorted(f for f in args.images.iterdir() if f.suffix.lower() in EXTS)
    if not files:
        raise SystemExit(f"no images in {args.images}")
    det, seg = MediaPipeHands(), ClassicalHOISegmenter(seed=args.seed)
    inp, amo = OpenCVInpainter(), ClassicalAmodalSegmenter(seed=args.seed)
    if args.chain:
        rows, lines = chain_table(files, args, (det, seg, inp, amo))
        return _write(rows, lines, args)
    rows, lines = [], []
    lines.append(
        "| photo | size | hand | side | pass | object | hand px | object px | amodal px "
        "| amodal branch | detect s | masks s | inpaint s | amodal s | total s |"
    )
    lines.append("|" + "---|" * 15)
    for f in files:
        t0 = time.perf_counter()
        img = load_image(f)
        res = run_chain(img.rgb, det, seg, inp, amo, seed=args.seed)
        total = time.perf_counter() - t0
        rows.append(draw_row(img.rgb, res))
        hands, s, tt = res.get("hands", []), res.get("seg"), res["t"]
        h0 = hands[0] if hands else None
        lines.append(
            f"| {f.name} | {img.rgb.shape[1]}x{img.rgb.shape[0]} | {'yes' if h0 else 'no'} "
            f"| {h0.side if h0 else '-'} | {h0.meta.get('pass') if h0 else '-'} "
            f"| {'yes' if s is not None and s.has_object else 'no'} "
            f"| {int(s.hand_mask.sum()) if s is not None else 0} "
            f"| {int(s.object_mask.sum()) if s is not None else 0} "
            f"| {int(res['amodal'].sum()) if 'amodal' in res else 0} "
            f"| {res.get('amodal_branch', '-')} | "
            + " | ".join(f"{tt.get(k, 0.0):.2f}" for k in ("detect", "masks", "inpaint", "amodal"))
            + f" | {total:.2f} |"
        )
        print(lines[-1], flush=True)
    return _write(rows, lines, args)


def _write(rows, lines, args) -> int:
    sheet = np.concatenate(rows, axis=0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if args.table is not None:
        args.table.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
