"""Run the offline perception chain on a folder of photos and draw a contact sheet.

Usage::

    python scripts/perception_contact_sheet.py --images DIR --out sheet.png [--table table.md]

Per photo (one row): input with keypoints, hand mask, object mask (kept components green,
rejected candidates red), inpainted image, amodal mask. The Markdown table lists the outcome of
each step and its time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--images", required=True, type=Path)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--table", type=Path, default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    files = sorted(f for f in args.images.iterdir() if f.suffix.lower() in EXTS)
    if not files:
        raise SystemExit(f"no images in {args.images}")
    det, seg = MediaPipeHands(), ClassicalHOISegmenter(seed=args.seed)
    inp, amo = OpenCVInpainter(), ClassicalAmodalSegmenter(seed=args.seed)
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
    sheet = np.concatenate(rows, axis=0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if args.table is not None:
        args.table.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
