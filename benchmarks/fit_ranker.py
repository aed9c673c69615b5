"""Refit the held-object ranker's weights on the tuning half of the development photos.

The automatic path ranks region proposals by the hand-set held-object score plus a weighted sum
of their cues (:data:`easyhoi.perception.ranker.RANKER_WEIGHTS`). This script rebuilds the
training data and fits those weights again:

1. ``collect``: every development photo with a reference (``tests/data/perception_refs``), the
   hands MediaPipe finds, every automatic hypothesis of every hand, and its IoU with the
   reference held object (cached in ``benchmarks/results/ranker_cache.pkl``; the cues are
   recomputed from the cache on every run, so a changed cue needs no new segmentation).
2. ``fit``: a listwise ranking loss on the *tuning* half only (per hand, the softmax share of
   the hypotheses with IoU >= 0.5 among the ``RANK_TOP`` ranked ones is maximised), L2
   regularised (``--l2``), plain projected gradient descent in numpy: the hand-set score keeps
   weight 1 and every fitted weight keeps the sign of its cue's reason (:data:`SIGNS`). The
   photos are split in two halves by a checksum of their name as in ``bench_perception.py``.
3. Report, per half, the share of photos whose top-ranked hypothesis (of the hand with the
   highest top score) has IoU >= 0.5 before refinement, for the weights in the code and for
   the refitted ones, and the ceiling (a hypothesis among those ranked reaches 0.5);
   ``--print`` prints the refitted weights as the Python literal of ``ranker.RANKER_WEIGHTS``.
4. ``--folds``: the same fit judged on photos it did not see: each half fitted and scored on
   the other, and leave-one-photo-out over all photos with a held object (every photo scored
   by weights fitted on the other 37), the estimate of what fitting on every photo would give.

Usage::

    python benchmarks/fit_ranker.py            # collect (cached) + fit + report
    python benchmarks/fit_ranker.py --recollect --print
"""

from __future__ import annotations

import argparse
import pickle
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_perception import DATA, RESULTS, fit_to, reference  # noqa: E402

CACHE = RESULTS / "ranker_cache.pkl"
#: Sign every fitted weight must keep: +1 for evidence of a held object, -1 against, 0 free.
SIGNS = {
    "fingers": 1, "thumb": 1, "grasp": 1, "contact": 1, "skin": -1, "border": -1, "size": -1,
    "far": -1, "contrast": 1, "solidity": 1, "sides": -1, "back": -1, "cross": 1, "pinch": 1,
    "wrap": -1, "spread": -1, "flanks": -1, "amodal": 1, "log_area": 0,
}  # fmt: skip
#: Features whose weights are fitted (the hand-set score keeps weight 1).
FREE = (
    "fingers", "thumb", "grasp", "contact", "skin", "border", "size", "far", "contrast", "solidity",
    "sides", "back", "pinch", "wrap", "spread", "flanks", "amodal", "log_area",
)  # fmt: skip


def half_of(stem: str) -> str:
    return "tune" if zlib.crc32(stem.encode()) % 2 == 0 else "check"


def collect(refs: Path, data: Path) -> list[dict]:
    """Per photo and hand: the working crop's scene and proposals, and the reference object
    in crop pixels (the expensive part, cached)."""
    from easyhoi.io.image import load_image
    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.mediapipe_hand import MediaPipeHands

    detector, seg = MediaPipeHands(), ClassicalHOISegmenter()
    out = []
    for f in sorted(refs.glob("*.json")):
        ref = reference(f)
        rgb = load_image(data / ref["image"]).rgb
        ref = fit_to(ref, rgb.shape[:2])
        hands = detector.detect(rgb)
        entry = {"name": Path(ref["image"]).name, "half": half_of(f.stem), "hands": []}
        entry["present"] = ref["object"] is not None
        for i, hand in enumerate(hands):
            others = [h for j, h in enumerate(hands) if j != i]
            w = seg._setup(rgb, hand, None, others)
            props = seg._auto_proposals(w)
            x0, y0, x1, y1 = w.crop
            ch, cw = w.img.shape[:2]
            target = None
            if ref["object"] is not None:
                crop = ref["object"][y0:y1, x0:x1].astype(np.float32)
                target = cv2.resize(crop, (cw, ch), interpolation=cv2.INTER_AREA) > 0.5
            entry["hands"].append(
                {"img": w.img, "scene": w.scene, "excl": w.excl, "props": props, "target": target}
            )
        out.append(entry)
        print(f"collected {entry['name']} ({len(hands)} hands)", file=sys.stderr, flush=True)
    return out


def features(data: list[dict], top: int) -> list[dict]:
    """Cue vectors (all cues, for the ``top`` hypotheses of the cheap ranking) and IoUs."""
    from easyhoi.perception import ranker as rk
    from easyhoi.perception.proposals import membership, segment_sums

    rows = []
    for e in data:
        for k, h in enumerate(e["hands"]):
            props, scene = h["props"], h["scene"]
            if not props.regions:
                continue
            idx, cues = rk.candidate_cues(props, scene, top)
            cues = cues[idx]
            iou = np.zeros(len(idx))
            if h["target"] is not None:
                t = h["target"]
                member = membership(props)[idx]
                inter = member @ segment_sums(props.labels, t, props.n_base)
                area = member @ props.sizes
                iou = inter / np.maximum(area + t.sum() - inter, 1.0)
            rows.append(
                {
                    "name": e["name"],
                    "half": e["half"],
                    "hand": k,
                    "idx": idx,
                    "cues": cues,
                    "iou": iou,
                    "present": e["present"],
                }  # fmt: skip
            )
    return rows


def top1(rows: list[dict], weights: np.ndarray, names: set[str]) -> dict[str, float]:
    """Per photo: IoU of the top-ranked hypothesis, taking the hand whose best score is
    highest (the product picks the hand of the most confident object)."""
    from easyhoi.perception import ranker as rk

    best: dict[str, tuple[float, float]] = {}
    for r in rows:
        if r["name"] not in names:
            continue
        s = rk.ranker_score(r["cues"], weights)
        i = int(np.argmax(s))
        cur = best.get(r["name"])
        if cur is None or s[i] > cur[0]:
            best[r["name"]] = (float(s[i]), float(r["iou"][i]))
    return {k: v[1] for k, v in best.items()}


def fit_listwise(
    rows: list[dict], l2: float, free: tuple[str, ...], steps: int = 3000, lr: float = 0.1
) -> np.ndarray:
    """Listwise softmax ranking on the given rows: per hand, maximise the share of
    exp(score) that falls on hypotheses with IoU >= 0.5 (each such hand weighted equally).
    The hand-set score keeps weight 1; only the features named in ``free`` get a weight."""
    from easyhoi.perception import ranker as rk

    cols = [rk.FEATURES.index(k) for k in free]
    xs, bs, ps = [], [], []
    for r in rows:
        pos = r["iou"] >= 0.5
        if pos.any() and not pos.all():
            f = rk.ranker_features(r["cues"])
            xs.append(f[:, cols])
            bs.append(f[:, 0])
            ps.append(pos)
    allx = np.concatenate(xs)
    sd = np.maximum(allx.std(0), 1e-6)
    xs = [x / sd for x in xs]
    w = np.zeros(len(cols))
    sign = np.array([SIGNS.get(k, 0) for k in free])
    lo = np.where(sign > 0, 0.0, -np.inf)
    hi = np.where(sign < 0, 0.0, np.inf)
    for _ in range(steps):
        g = l2 * w
        for x, b, pos in zip(xs, bs, ps, strict=True):
            s = b + x @ w
            p = np.exp(s - s.max())
            p_all = p / p.sum()
            p_pos = p * pos / (p * pos).sum()
            g += (p_all - p_pos) @ x / len(xs)
        w -= lr * g
        # each cue's weight keeps the sign its reason gives (see docs/perception.md)
        w = np.clip(w, lo, hi)
    out = np.zeros(len(rk.FEATURES))
    out[0] = 1.0
    out[cols] = w / sd
    return out


def hit_rate(ious: dict[str, float]) -> float:
    """Share of photos whose chosen hypothesis has IoU >= 0.5."""
    return float(np.mean([v >= 0.5 for v in ious.values()]))


def held_out(
    rows: list[dict],
    halves: dict[str, set[str]],
    l2: float,
    free: tuple[str, ...],
    fitted_on_tune: np.ndarray,
) -> str:
    """Top-1 rates of fits scored on photos they were not fitted on: each half on the other
    (``fitted_on_tune``: the weights already fitted on the tuning half), and leave one photo
    out over all photos with a held object."""
    present = [r for r in rows if r["present"]]
    fitted_on_check = fit_listwise([r for r in present if r["half"] == "check"], l2, free)
    line = [
        f"check (fitted on tune) {hit_rate(top1(rows, fitted_on_tune, halves['check'])):.2f}",
        f"tune (fitted on check) {hit_rate(top1(rows, fitted_on_check, halves['tune'])):.2f}",
    ]
    loo: dict[str, float] = {}
    for name in sorted(halves["tune"] | halves["check"]):
        w = fit_listwise([r for r in present if r["name"] != name], l2, free)
        loo.update(top1(rows, w, {name}))
    line.append(f"leave-one-out {hit_rate(loo):.2f} (n {len(loo)})")
    return "held out: " + "  ".join(line)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--refs", type=Path, default=ROOT / "tests" / "data" / "perception_refs")
    ap.add_argument("--recollect", action="store_true", help="rebuild the cached proposals")
    ap.add_argument("--l2", type=float, default=0.1)
    ap.add_argument("--top", type=int, default=None, help="hypotheses ranked (default RANK_TOP)")
    ap.add_argument("--free", default=",".join(FREE), help="features given a weight")
    ap.add_argument("--print", action="store_true", help="print the refitted weights")
    ap.add_argument(
        "--folds", action="store_true", help="also score fits on photos they did not see"
    )
    args = ap.parse_args(argv)
    from easyhoi.perception import ranker as rk

    if CACHE.exists() and not args.recollect:
        data = pickle.loads(CACHE.read_bytes())
    else:
        data = collect(args.refs, args.data)
        CACHE.parent.mkdir(parents=True, exist_ok=True)
        CACHE.write_bytes(pickle.dumps(data))
    rows = features(data, args.top or rk.RANK_TOP)
    held = {r["name"]: r["half"] for r in rows if r["present"]}
    halves = {h: {n for n, v in held.items() if v == h} for h in ("tune", "check")}
    train = [r for r in rows if r["half"] == "tune" and r["present"]]
    w_fit = fit_listwise(train, args.l2, tuple(args.free.split(",")))
    for label, w in (("code", rk.RANKER_WEIGHTS), ("refit", w_fit)):
        line = []
        for h in ("tune", "check"):
            t = top1(rows, w, halves[h])
            ceil = {r["name"] for r in rows if r["name"] in halves[h] and r["iou"].max() >= 0.5}
            line.append(
                f"{h} {hit_rate(t):.2f} (n {len(t)}, ceiling {len(ceil) / max(1, len(t)):.2f})"
            )
        print(f"{label:6s} " + "  ".join(line))
    if args.folds:
        print(held_out(rows, halves, args.l2, tuple(args.free.split(",")), w_fit))
    if args.print:
        print(repr(dict(zip(rk.FEATURES, np.round(w_fit, 3).tolist(), strict=True))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
