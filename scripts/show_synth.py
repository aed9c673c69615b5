"""Gallery of synthetic scenes: photo, ground-truth masks, keypoints and depth.

Usage::

    python scripts/show_synth.py --out outputs/synth_gallery.png --n 4 [--seed 0] [--size 256]
        [--object random|cylinder|box|sphere|mug|tool|PATH] [--grasp random|power|...]
        [--perturbation none|low|hamer|high]

One row per scene: the photo; visible masks (hand red, object blue) with the amodal object
outline (white); the 21 GT keypoints and skeleton over the photo; the depth map; and, with
``--perturbation``, the perturbed masks of the resulting HOIInput.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image

from easyhoi.synth import make_scene

#: OpenPose skeleton (21 keypoints).
BONES = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (0, 9), (9, 10),
         (10, 11), (11, 12), (0, 13), (13, 14), (14, 15), (15, 16), (0, 17), (17, 18),
         (18, 19), (19, 20)]  # fmt: skip
DIGIT_COLOURS = [(255, 80, 80), (255, 200, 0), (60, 220, 60), (0, 190, 255), (200, 90, 255)]


def mask_panel(hand, obj, amodal, image=None) -> np.ndarray:
    h, w = hand.shape
    base = np.full((h, w, 3), 30, np.uint8) if image is None else (image * 0.35).astype(np.uint8)
    base[hand] = (220, 60, 60)
    base[obj] = (60, 90, 230)
    contours, _ = cv2.findContours(amodal.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)  # fmt: skip
    cv2.drawContours(base, contours, -1, (255, 255, 255), 1)
    return base


def keypoint_panel(image, kp2) -> np.ndarray:
    out = image.copy()
    for b, (i, j) in enumerate(BONES):
        c = DIGIT_COLOURS[b // 4]
        p, q = (tuple(int(round(x)) for x in kp2[k]) for k in (i, j))
        cv2.line(out, p, q, c, 1, cv2.LINE_AA)
    for k, (u, v) in enumerate(kp2):
        c = (255, 255, 255) if k == 0 else DIGIT_COLOURS[(k - 1) // 4]
        cv2.circle(out, (int(round(u)), int(round(v))), 2, c, -1, cv2.LINE_AA)
    return out


def depth_panel(depth) -> np.ndarray:
    finite = np.isfinite(depth)
    out = np.zeros(depth.shape, np.uint8)
    if finite.any():
        lo, hi = depth[finite].min(), depth[finite].max()
        out[finite] = (255 * (1 - (depth[finite] - lo) / max(hi - lo, 1e-9)) * 0.8 + 40).astype(
            np.uint8
        )
    return cv2.applyColorMap(out, cv2.COLORMAP_VIRIDIS)[..., ::-1] * finite[..., None]


def label(panel, text) -> np.ndarray:
    out = panel.copy()
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1,
                cv2.LINE_AA)  # fmt: skip
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="outputs/synth_gallery.png", help="PNG to write")
    ap.add_argument("--n", type=int, default=4, help="number of scenes (rows)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first scene")
    ap.add_argument("--size", type=int, default=256, help="image size in pixels")
    ap.add_argument("--object", default="random", help="object kind or mesh path")
    ap.add_argument("--grasp", default="random", help="grasp type")
    ap.add_argument("--perturbation", default=None, help="also show a perturbed HOIInput")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)  # tiny tensors: threads only add contention
    rows = []
    for k in range(args.n):
        t = time.perf_counter()
        s = make_scene(args.seed + k, args.object, args.grasp, image_size=args.size)
        g = s.grasp
        print(
            f"scene {s.seed}: {s.object.name} ({s.object.kind}), {g.grasp_type} grasp, "
            f"penetration {10 * g.penetration_cm:.1f} mm, {g.contact_count} contact vertices "
            f"({', '.join(g.contact_digits)}), {time.perf_counter() - t:.2f} s "
            f"[{', '.join(f'{n} {v:.2f}' for n, v in s.timings.items())}]"
        )
        panels = [
            label(s.image, f"#{s.seed} {s.object.name} / {g.grasp_type}"),
            label(mask_panel(s.hand_mask, s.object_mask, s.object_amodal), "GT masks"),
            label(keypoint_panel(s.image, s.keypoints_2d), "GT keypoints"),
            label(depth_panel(s.depth), f"depth, pen {10 * g.penetration_cm:.1f} mm"),
        ]
        if args.perturbation:
            inp = s.to_hoi_input(args.perturbation)
            panels.append(
                label(
                    mask_panel(inp.hand_mask, inp.object_mask, inp.amodal_mask),
                    f"masks: {args.perturbation}",
                )  # fmt: skip
            )
        rows.append(np.concatenate(panels, axis=1))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
