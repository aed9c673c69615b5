"""Held-object perception on the development photos, against hand-drawn reference masks.

Per photo: hand detection (MediaPipe) and segmentation of every hand with the chosen hand picked
as :func:`easyhoi.perception.chain.segment_hands` does in the product. Reported per photo:

* ``hand``: a hand was found; ``hand IoU``: the chosen hand mask against the reference hand it
  matches best;
* ``IoU``: the chosen object mask against the reference held object(s) (0 when none is output);
* ``wrong``: an object is output, one is present, and IoU < 0.5;
* ``missed``: an object is visibly held and none is output;
* ``low``: the object confidence is low (< 0.5; the product warns);
* ``s``: seconds for detection + segmentation (the summary also gives the median CPU seconds
  of the process, which a busy shared machine does not inflate);
* ``best hyp``: the best IoU any automatic hypothesis of any hand reaches (the ceiling of the
  ranking: what a perfect choice among the region proposals would give, before refinement);
* ``best_choice`` (``--choices``; ``best_choice_iou_ge_0.5`` in the summary): the best IoU of
  the object regions the automatic path offers, each picked in turn with ``--object-choice K``
  (what a user who picks the right one from ``masks.png`` gets);
* ``IoU 1pt``: the same with one object point, the reference mask's deepest interior point
  (maximum of its distance transform, ``tests/perception_refs.object_point``), as a user's
  single click; ``on`` (in the ``--click-only`` lines; ``point_clicked_object_iou_ge_0.5`` in
  the summary) scores the same mask against the held object the point lies on alone, which
  differs from ``IoU 1pt`` where each hand holds an object of its own (the product reconstructs
  the clicked one);
* ``IoU box``: the same with an object box (``--object-box``), the reference mask's bounding box
  grown by 5 % of its width and height on every side, as a user's box drawn round the object.

With ``--click-only`` the summary also gives the share of the one-point masks with IoU < 0.5
(``point_wrong_flagged_low``) and with IoU >= 0.5 (``point_right_flagged_low``) whose object
confidence is low, so that the product warns. Each photo also gets a second object point where a
user would add one
(``point2``): the deepest pixel of the part of the reference object the one-point mask misses,
when the mask misses more than it takes in beyond the object (a further object point cannot
take a leak away; then the one-point IoU is kept). ``point2_worse_by_0.05`` counts the photos
whose mask the second point makes worse. ``fix`` is the second gesture of either kind: a
background point (``--background-point``) at the deepest pixel of what the one-point mask takes
in beyond the object, when that is a region one sees (``tests/perception_refs.background_point``),
else the second object point above. ``cands`` (``point_candidates_ge_0.5`` in the summary) is
the best IoU any candidate of the one-click path reaches for the hand the click picks, each
finished as the click finishes the one it keeps (``ClassicalHOISegmenter.click_candidates``):
what a perfect choice among the click's candidates would give (at least the one-point IoU).

The reference object is every object a hand holds (``held_by``), visibly or not.

The photos are split in two fixed halves by a checksum of their name (CRC-32 even: ``tune``,
odd: ``check``); the summary is given for each half and for all. Reference masks: the JSON
polygons in ``tests/data/perception_refs`` (``--refs`` to read another folder); photos without
a reference file are skipped.

Usage::

    python benchmarks/bench_perception.py                       # all photos with references
    python benchmarks/bench_perception.py --split check --no-point
    python benchmarks/bench_perception.py --only mow-           # photos whose name has mow-
    python benchmarks/bench_perception.py --click-only          # only the one-point runs
    python benchmarks/bench_perception.py --no-point --choices  # and each offered region
    python benchmarks/bench_perception.py --click-only --choices  # each of the point's regions
    python benchmarks/bench_perception.py --resample 0.9        # the photos at 0.9 x their size
    python benchmarks/bench_perception.py --mirror              # the photos mirrored
    python benchmarks/bench_perception.py --resample 0.85 --jpeg 90  # and saved as JPEG

``--resample F`` resamples every photo by ``F`` before anything else (area averaging below 1,
bicubic above, capped at the photo loader's 1600 px longer side), with the reference masks and
the object point resampled alike: the same scenes at another pixel size. Working sizes are in
palm lengths, so the rates should not depend on it; how much they move is how much of a rate
is the particular pixels of these photos rather than what they show. ``--jpeg Q`` saves every
photo (after any resampling) as a JPEG of quality ``Q`` and reads it back: compression noise no
one sees, which moves a rate as much as resampling does. ``--mirror`` flips every
photo and its reference left to right (after any resampling): the same pixel values, a left
hand for a right one.

Results: a Markdown table on stdout and ``benchmarks/results/bench_perception.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import zlib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: How much larger than the object's bounding box a user's box is, per side (of its size)
BOX_GROW = 0.05
RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "data"


def reference(path: Path) -> dict:
    """Reference of one photo (``tests/perception_refs.py`` format): image path, one mask per
    hand, the held-object mask (None: nothing held), whether it is visibly held, the
    one-click point (the held-object mask's deepest interior pixel) and the name of the first
    held object (``kind``; None: nothing held)."""
    sys.path.insert(0, str(ROOT))
    from tests import perception_refs as pr

    ref = pr.load_ref(path)
    obj = pr.held_object_mask(ref)
    return {
        "image": ref.image,
        "hand": [pr.rasterize(h.polygons, ref.height, ref.width) for h in ref.hands],
        "holds": [bool(h.holds_object) for h in ref.hands],
        "object": obj if obj.any() else None,
        # each held object alone: a photo whose hands hold one object each has two
        "objects": [
            pr.rasterize(o.polygons, ref.height, ref.width) for o in ref.objects if o.held_by
        ],
        "visibly_held": any(o.held_by and o.visibly_held for o in ref.objects),
        "point": pr.object_point(ref),
        "kind": next((o.name for o in ref.objects if o.held_by), None),
    }


def map_masks(ref: dict, f, point) -> dict:
    """The reference with ``f`` applied to every mask (each hand, the held-object mask, each
    held object; ``f`` keeps None as None) and its object point replaced by ``point``: what
    every photo transform does to the reference."""
    return {
        **ref,
        "hand": [f(h) for h in ref["hand"]],
        "object": f(ref["object"]),
        "objects": [f(m) for m in ref.get("objects", [])],
        "point": point,
    }


def fit_to(ref: dict, shape: tuple[int, int]) -> dict:
    """The reference with its masks resampled to ``shape`` (the photo loader may downscale
    very large photos)."""

    def fit(m):
        if m is None or m.shape == tuple(shape):
            return m
        return cv2.resize(m.astype(np.uint8), shape[::-1], interpolation=cv2.INTER_NEAREST) > 0

    h0, w0 = ref["hand"][0].shape if ref["hand"] else shape
    pt = ref["point"]
    if pt is not None:
        pt = (pt[0] * shape[1] / w0, pt[1] * shape[0] / h0)
    return map_masks(ref, fit, pt)


def resample(rgb: np.ndarray, factor: float, max_side: int = 1600) -> np.ndarray:
    """``rgb`` resampled by ``factor`` (area averaging below 1, bicubic above), its longer side
    at most ``max_side`` as the photo loader keeps it."""
    h, w = rgb.shape[:2]
    f = min(float(factor), max_side / max(h, w)) if factor > 1 else float(factor)
    if f == 1.0:
        return rgb
    size = (max(8, round(w * f)), max(8, round(h * f)))
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_CUBIC)


def encoded(rgb: np.ndarray, quality: int | None) -> bytes:
    """``rgb`` as the bytes of a JPEG of ``quality`` (OpenCV's encoder), or of a PNG without
    one."""
    bgr = np.ascontiguousarray(rgb[..., ::-1])
    fmt = (".png", []) if quality is None else (".jpg", [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    ok, buf = cv2.imencode(fmt[0], bgr, fmt[1])
    if not ok:
        raise RuntimeError(f"{fmt[0]} encoding failed")
    return buf.tobytes()


def reencode(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` saved as a JPEG of ``quality`` and read back: the same scene through other pixels
    (compression noise no one sees), as photos reach users after another save."""
    buf = np.frombuffer(encoded(rgb, quality), np.uint8)
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])


def mirror(rgb: np.ndarray, ref: dict) -> tuple[np.ndarray, dict]:
    """The photo and its reference mirrored left to right (the object point as well)."""

    def flip(m):
        return None if m is None else m[:, ::-1].copy()

    pt = ref["point"]
    if pt is not None:
        pt = (rgb.shape[1] - 1 - pt[0], pt[1])
    return rgb[:, ::-1].copy(), map_masks(ref, flip, pt)


def rotate(rgb: np.ndarray, ref: dict, quarter_turns: int) -> tuple[np.ndarray, dict]:
    """The photo and its reference turned by ``quarter_turns`` x 90 degrees counter-clockwise
    (the object point as well)."""
    k = int(quarter_turns) % 4

    def turn(m):
        return None if m is None else np.ascontiguousarray(np.rot90(m, k))

    pt = ref["point"]
    if pt is not None:
        x, y = pt
        h, w = rgb.shape[:2]
        for _ in range(k):  # (x, y) in an (h, w) image -> (y, w - 1 - x) in the (w, h) one
            x, y, h, w = y, w - 1 - x, w, h
        pt = (x, y)
    return turn(rgb), map_masks(ref, turn, pt)


def crop_around(rgb: np.ndarray, ref: dict, grow: float) -> tuple[np.ndarray, dict]:
    """The photo cut to the box around the reference's holding hands and held object, its
    sides grown ``grow`` times about its centre (within the photo), as hand-object datasets
    crop their frames; the reference follows (the object point shifted). Photos without a held
    object are cut around their hands."""
    holding = [h for h, holds in zip(ref["hand"], ref["holds"], strict=True) if holds]
    parts = holding or list(ref["hand"])
    if ref["object"] is not None:
        parts.append(ref["object"])
    ys, xs = np.nonzero(np.logical_or.reduce(parts))
    h, w = rgb.shape[:2]
    cx, cy = (xs.min() + xs.max() + 1) / 2, (ys.min() + ys.max() + 1) / 2
    hw = grow * (xs.max() + 1 - xs.min()) / 2
    hh = grow * (ys.max() + 1 - ys.min()) / 2
    x0, x1 = max(0, int(round(cx - hw))), min(w, int(round(cx + hw)))
    y0, y1 = max(0, int(round(cy - hh))), min(h, int(round(cy + hh)))

    def cut(m):
        return None if m is None else np.ascontiguousarray(m[y0:y1, x0:x1])

    pt = ref["point"]
    if pt is not None:
        pt = (pt[0] - x0, pt[1] - y0)
    return cut(rgb), map_masks(ref, cut, pt)


def clicked_object(ref: dict) -> np.ndarray | None:
    """The held object the reference's point lies on: the whole held-object mask when the
    hands hold one object, the clicked one alone when they hold one each (a one-object
    reconstruction of the clicked hand's object cannot reach the union of both)."""
    objs = ref.get("objects") or []
    if len(objs) < 2 or ref["point"] is None:
        return ref["object"]
    x, y = (int(round(v)) for v in ref["point"])
    on = [m for m in objs if 0 <= y < m.shape[0] and 0 <= x < m.shape[1] and m[y, x]]
    return on[0] if on else ref["object"]


def iou(a: np.ndarray | None, b: np.ndarray | None) -> float:
    """Mask IoU, 0 when either mask is missing (None) or both are empty."""
    from easyhoi.geometry.masks import mask_iou

    return 0.0 if a is None or b is None else mask_iou(a, b, empty=0.0)


def holding_hands_found(hands, ref) -> tuple[int, int]:
    """(reference hands holding the object, how many of them a detection lands on): most of a
    detection's keypoints inside the reference hand's outline grown by 7 px."""
    k = np.ones((15, 15), np.uint8)
    total = found = 0
    for mask, holds in zip(ref["hand"], ref["holds"], strict=True):
        if not holds:
            continue
        total += 1
        grown = cv2.dilate(mask.astype(np.uint8), k) > 0
        h, w = grown.shape
        for d in hands:
            kp = np.asarray(d.keypoints2d, dtype=np.float64).reshape(-1, 2)
            xs = np.clip(kp[:, 0].astype(int), 0, w - 1)
            ys = np.clip(kp[:, 1].astype(int), 0, h - 1)
            if grown[ys, xs].mean() > 0.5:
                found += 1
                break
    return total, found


def best_hypothesis_iou(rgb, hands, segmenter, ref_obj) -> float:
    """The best IoU with ``ref_obj`` that any automatic hypothesis of any hand reaches."""
    from easyhoi.perception.proposals import membership, segment_sums

    best = 0.0
    if ref_obj is None or not hasattr(segmenter, "automatic_hypotheses"):
        return best
    for i, hand in enumerate(hands):
        others = [h for j, h in enumerate(hands) if j != i]
        (x0, y0, x1, y1), props = segmenter.automatic_hypotheses(rgb, hand, others)
        if not props.regions:
            continue
        ch, cw = props.labels.shape
        crop = ref_obj[y0:y1, x0:x1].astype(np.float32)
        inside = cv2.resize(crop, (cw, ch), interpolation=cv2.INTER_AREA) > 0.5
        total = float(ref_obj.sum()) * cw * ch / ((x1 - x0) * (y1 - y0))  # in crop pixels
        member = membership(props)
        inter = member @ segment_sums(props.labels, inside, props.n_base)
        area = member @ props.sizes
        best = max(best, float((inter / np.maximum(area + total - inter, 1.0)).max()))
    return best


def object_low(seg) -> bool:
    """Whether a segmentation's object mask would be warned about: its confidence is low, or
    there is no segmentation (no object) at all."""
    conf = seg.confidence.get("object") if seg is not None else None
    return bool(conf is None or conf.low)


def run_photo(rgb, ref, detector, segmenter, with_point: bool, choices: bool = False) -> dict:
    from easyhoi.perception.chain import segment_hands
    from easyhoi.perception.prompts import Prompts

    t0, c0 = time.perf_counter(), time.process_time()
    hands = detector.detect(rgb)
    idx, seg, notes, _ = segment_hands(rgb, hands, segmenter) if hands else (None, None, [], None)
    secs = time.perf_counter() - t0
    cpu = time.process_time() - c0
    present = ref["object"] is not None
    out_obj = seg.object_mask if seg is not None else None
    conf = seg.confidence.get("object") if seg is not None else None
    n_holding, n_found = holding_hands_found(hands, ref)
    row = {
        "hand": bool(hands),
        "holding_hands": n_holding,
        "holding_hands_found": n_found,
        # against the reference hand it matches best (the photo may show several)
        "hand_iou": max((iou(seg.hand_mask, h) for h in ref["hand"]), default=0.0)
        if seg is not None
        else 0.0,
        "present": present,
        "output": seg is not None,
        "iou": iou(out_obj, ref["object"]),
        "confidence": None if conf is None else round(conf.score, 3),
        "low": bool(conf is None or conf.low),
        "reasons": [] if conf is None else list(conf.reasons),
        "seconds": secs,
        "cpu_seconds": cpu,
        "notes": notes,
        "score": None if seg is None else seg.meta.get("score"),
        "evidence": None if seg is None else seg.meta.get("evidence"),
        "margin": None if seg is None else seg.meta.get("margin"),
    }
    row["best_hyp"] = best_hypothesis_iou(rgb, hands, segmenter, ref["object"])
    if choices and seg is not None and present:
        # each offered region picked in turn (--object-choice K), as a user looking at
        # masks.png would pick the right one
        row["best_choice"] = max(
            iou(segment_hands(rgb, hands, segmenter, prompts=Prompts(object_choice=k))[1]
                .object_mask, ref["object"])
            for k in range(1, len(seg.candidates) + 1)
        )  # fmt: skip
    row["wrong"] = bool(seg is not None and present and row["iou"] < 0.5)
    row["missed"] = bool(present and ref["visibly_held"] and seg is None)
    row["false_object"] = bool(seg is not None and not present)
    if with_point and present and hands:
        p = Prompts(object_points=(tuple(float(v) for v in ref["point"]),))
        t1 = time.perf_counter()
        _, sp, _, _ = segment_hands(rgb, prompt_hands(detector, rgb, hands, p), segmenter,
                                    prompts=p)  # fmt: skip
        row["seconds_point"] = time.perf_counter() - t1
        m1 = sp.object_mask if sp is not None else None
        row["iou_point"] = iou(m1, ref["object"])
        row["iou_point_clicked"] = iou(m1, clicked_object(ref))
        row["low_point"] = object_low(sp)
        row["iou_box"], row["low_box"] = box_run(rgb, hands, detector, segmenter, ref["object"])
    return row


def prompt_hands(detector, rgb, hands, prompts) -> list:
    """The detections the product chooses the prompt's hand among
    (:func:`easyhoi.perception.chain.steady_nearest`: a skeleton the detector does not find
    again is passed over)."""
    from easyhoi.perception.chain import steady_nearest

    return steady_nearest(detector, rgb, hands, prompts, lambda _n, fn, *a, **kw: fn(*a, **kw))[0]


def box_run(rgb, hands, detector, segmenter, ref_obj) -> tuple[float, bool]:
    """(object IoU with the reference, object confidence low) when the object is prompted by
    the box a user draws round it (``tests/perception_refs.object_box``)."""
    from easyhoi.perception.chain import segment_hands
    from easyhoi.perception.prompts import Prompts

    sys.path.insert(0, str(ROOT))
    from tests.perception_refs import object_box

    pb = Prompts(object_box=object_box(ref_obj, BOX_GROW))
    _, sb, _, _ = segment_hands(rgb, prompt_hands(detector, rgb, hands, pb), segmenter, prompts=pb)
    return iou(sb.object_mask if sb is not None else None, ref_obj), object_low(sb)


def click_ceiling(rgb, hands, segmenter, prompts, ref_obj) -> float | None:
    """The best IoU with ``ref_obj`` that any finished candidate of the one-click path reaches,
    for the hand the click picks; None for a segmenter without ``click_candidates``."""
    from easyhoi.perception.chain import nearest_hand

    if ref_obj is None or not hasattr(segmenter, "click_candidates"):
        return None
    point = prompts.object_points[0]
    i = nearest_hand(hands, point)
    others = [h for j, h in enumerate(hands) if j != i]
    (x0, y0, x1, y1), cands = segmenter.click_candidates(rgb, hands[i], point, others)
    best = 0.0
    for m, _ in cands:
        full = np.zeros(ref_obj.shape, bool)
        full[y0:y1, x0:x1] = cv2.resize(m.astype(np.uint8), (x1 - x0, y1 - y0),
                                        interpolation=cv2.INTER_NEAREST) > 0  # fmt: skip
        best = max(best, iou(full, ref_obj))
    return best


def run_click(rgb, ref, detector, segmenter, choices: bool = False) -> dict:
    """The one-point run alone (``--click-only``): object IoU and seconds of the click; with
    ``choices``, also the IoU of each of the point's regions picked in turn (``--object-choice
    K`` with the point, as a user looking at ``masks.png`` would pick)."""
    from easyhoi.perception.chain import segment_hands
    from easyhoi.perception.prompts import Prompts

    all_hands = detector.detect(rgb)
    row = {"hand": bool(all_hands), "present": ref["object"] is not None}
    if row["present"] and all_hands:
        p = Prompts(object_points=(tuple(float(v) for v in ref["point"]),))
        t0, c0 = time.perf_counter(), time.process_time()
        hands = prompt_hands(detector, rgb, all_hands, p)  # what every point run chooses among
        _, sp, _, _ = segment_hands(rgb, hands, segmenter, prompts=p)
        row["seconds_point"] = time.perf_counter() - t0
        row["cpu_seconds_point"] = time.process_time() - c0
        m1 = sp.object_mask if sp is not None else None
        row["iou_point"] = iou(m1, ref["object"])
        row["iou_point_clicked"] = iou(m1, clicked_object(ref))
        row["low_point"] = object_low(sp)
        row["ceiling_point"] = click_ceiling(rgb, hands, segmenter, p, ref["object"])
        if choices and sp is not None:
            row["iou_point_choices"] = [row["iou_point"]] + [
                iou(segment_hands(rgb, hands, segmenter, prompts=replace(p, object_choice=k))[1]
                    .object_mask, ref["object"])
                for k in range(2, len(sp.candidates) + 1)
            ]  # fmt: skip
        row["iou_box"], row["low_box"] = box_run(rgb, all_hands, detector, segmenter,
                                                 ref["object"])  # fmt: skip
        sys.path.insert(0, str(ROOT))
        from tests.perception_refs import background_point, second_point

        second = second_point(m1, ref["object"])
        row["iou_point2"] = row["iou_point"]
        if second is not None:
            p2 = Prompts(object_points=(p.object_points[0], second))
            _, s2, _, _ = segment_hands(rgb, hands, segmenter, prompts=p2)
            row["iou_point2"] = iou(s2.object_mask if s2 is not None else None, ref["object"])
        row["iou_fix"], row["fix"] = row["iou_point2"], "object" if second is not None else ""
        bg = background_point(m1, ref["object"])
        if bg is not None:
            pb = Prompts(object_points=p.object_points, background_points=(bg,))
            _, sb, _, _ = segment_hands(rgb, hands, segmenter, prompts=pb)
            row["iou_fix"] = iou(sb.object_mask if sb is not None else None, ref["object"])
            row["fix"] = "background"
    return row


def _share_low(rows: list[dict], keep, key: str = "low_point") -> float:
    """Share of the ``rows`` selected by ``keep`` (that ran the prompt of ``key``) flagged low."""
    sel = [r[key] for r in rows if key in r and keep(r)]
    return float(np.mean(sel)) if sel else 0.0


def click_summary(rows: list[dict]) -> dict:
    pts = [r for r in rows if r["present"]]
    secs = [r["seconds_point"] for r in pts if "seconds_point" in r]
    cpu = [r["cpu_seconds_point"] for r in pts if "cpu_seconds_point" in r]
    return {
        "with_object": len(pts),
        "point_iou_ge_0.5": float(np.mean([r.get("iou_point", 0.0) >= 0.5 for r in pts]))
        if pts
        else 0.0,
        "point_mean_iou": float(np.mean([r.get("iou_point", 0.0) for r in pts])) if pts else 0.0,
        # against the held object the point lies on (differs where each hand holds its own)
        "point_clicked_object_iou_ge_0.5": float(
            np.mean([r.get("iou_point_clicked", 0.0) >= 0.5 for r in pts])
        )
        if pts
        else 0.0,
        # the one-point masks with IoU < 0.5 / >= 0.5 whose object confidence is low (warned)
        "point_wrong_flagged_low": _share_low(pts, lambda r: r.get("iou_point", 0.0) < 0.5),
        "point_right_flagged_low": _share_low(pts, lambda r: r.get("iou_point", 0.0) >= 0.5),
        # some candidate of the click reaches 0.5 (what a perfect choice among them would give)
        "point_candidates_ge_0.5": float(
            np.mean([(r.get("ceiling_point") or 0.0) >= 0.5 for r in pts])
        )
        if pts
        else 0.0,
        # the best of the point's first K regions (--choices): a user picking from masks.png
        **{
            f"point_best_of_{k}_ge_0.5": float(
                np.mean([max(r.get("iou_point_choices", [0.0])[:k]) >= 0.5 for r in pts])
            )
            for k in range(2, 5)
            if pts and any("iou_point_choices" in r for r in pts)
        },
        "point2_iou_ge_0.5": float(np.mean([r.get("iou_point2", 0.0) >= 0.5 for r in pts]))
        if pts
        else 0.0,
        "point2_worse_by_0.05": sum(
            r.get("iou_point2", 0.0) < r.get("iou_point", 0.0) - 0.05 for r in pts
        ),
        "fix_iou_ge_0.5": float(np.mean([r.get("iou_fix", 0.0) >= 0.5 for r in pts]))
        if pts
        else 0.0,
        "background_fixes": sum(r.get("fix") == "background" for r in pts),
        "background_fix_worse_by_0.05": sum(
            r.get("fix") == "background" and r.get("iou_fix", 0.0) < r.get("iou_point", 0.0) - 0.05
            for r in pts
        ),
        "box_iou_ge_0.5": float(np.mean([r.get("iou_box", 0.0) >= 0.5 for r in pts]))
        if pts
        else 0.0,
        "box_wrong_flagged_low": _share_low(pts, lambda r: r.get("iou_box", 0.0) < 0.5, "low_box"),
        "box_right_flagged_low": _share_low(pts, lambda r: r.get("iou_box", 0.0) >= 0.5, "low_box"),
        "median_seconds_point": float(np.median(secs)) if secs else 0.0,
        # CPU time of the one process: wall time on a machine shared with other work
        "median_cpu_seconds_point": float(np.median(cpu)) if cpu else 0.0,
    }


def summary(rows: list[dict]) -> dict:
    held = [r for r in rows if r["present"]]
    wrong = [r for r in held if r["wrong"]]
    right = [r for r in held if r["output"] and not r["wrong"]]
    pts = [r for r in held if "iou_point" in r]
    found = sum(r["holding_hands_found"] for r in rows)
    return {
        "photos": len(rows),
        "with_object": len(held),
        "hand_found": float(np.mean([r["hand"] for r in rows])) if rows else 0.0,
        # hands that hold the object (reference) with no detection on them
        "holding_hands_missed": f"{sum(r['holding_hands'] for r in rows) - found} of "
        f"{sum(r['holding_hands'] for r in rows)}",
        "mean_hand_iou": float(np.mean([r["hand_iou"] for r in rows])) if rows else 0.0,
        "hand_iou_ge_0.7": float(np.mean([r["hand_iou"] >= 0.7 for r in rows])) if rows else 0.0,
        "iou_ge_0.5": float(np.mean([r["iou"] >= 0.5 for r in held])) if held else 0.0,
        "mean_iou": float(np.mean([r["iou"] for r in held])) if held else 0.0,
        "best_hyp_iou_ge_0.5": float(np.mean([r["best_hyp"] >= 0.5 for r in held]))
        if held
        else 0.0,
        "missed": float(np.mean([r["missed"] for r in held])) if held else 0.0,
        **(
            {
                "best_choice_iou_ge_0.5": float(
                    np.mean([r.get("best_choice", r["iou"]) >= 0.5 for r in held])
                )
            }  # fmt: skip
            if held and any("best_choice" in r for r in held)
            else {}
        ),
        "wrong": len(wrong),
        "wrong_flagged_low": float(np.mean([r["low"] for r in wrong])) if wrong else 1.0,
        "right_flagged_low": float(np.mean([r["low"] for r in right])) if right else 0.0,
        "point_iou_ge_0.5": float(np.mean([r["iou_point"] >= 0.5 for r in pts])) if pts else 0.0,
        "point_mean_iou": float(np.mean([r["iou_point"] for r in pts])) if pts else 0.0,
        "point_clicked_object_iou_ge_0.5": float(
            np.mean([r["iou_point_clicked"] >= 0.5 for r in pts])
        )
        if pts
        else 0.0,
        # the one-point masks with IoU < 0.5 / >= 0.5 whose object confidence is low (warned)
        "point_wrong_flagged_low": _share_low(pts, lambda r: r["iou_point"] < 0.5),
        "point_right_flagged_low": _share_low(pts, lambda r: r["iou_point"] >= 0.5),
        "box_iou_ge_0.5": float(np.mean([r["iou_box"] >= 0.5 for r in pts])) if pts else 0.0,
        "box_mean_iou": float(np.mean([r["iou_box"] for r in pts])) if pts else 0.0,
        # the box masks with IoU < 0.5 / >= 0.5 whose object confidence is low (warned)
        "box_wrong_flagged_low": _share_low(pts, lambda r: r["iou_box"] < 0.5, "low_box"),
        "box_right_flagged_low": _share_low(pts, lambda r: r["iou_box"] >= 0.5, "low_box"),
        "median_seconds": float(np.median([r["seconds"] for r in rows])) if rows else 0.0,
        # CPU time of the one process: wall time on a machine shared with other work
        "median_cpu_seconds": float(np.median([r["cpu_seconds"] for r in rows])) if rows else 0.0,
    }


def table(rows: list[dict], names: list[str]) -> str:
    head = (
        "| photo | half | hand | hand IoU | IoU | best hyp | wrong | missed | conf | low | s "
        "| IoU 1pt | IoU box |"
    )
    lines = [head, "|" + "---|" * 13]
    for n, r in zip(names, rows, strict=True):
        lines.append(
            f"| {n} | {r['half']} | {'y' if r['hand'] else 'n'} | {r['hand_iou']:.2f} | "
            f"{r['iou']:.2f} | {r['best_hyp']:.2f} | {'y' if r['wrong'] else ''} | "
            f"{'y' if r['missed'] else ''} | "
            f"{'-' if r['confidence'] is None else format(r['confidence'], '.2f')} | "
            f"{'y' if r['low'] else ''} | {r['seconds']:.2f} | "
            f"{format(r['iou_point'], '.2f') if 'iou_point' in r else '-'} | "
            f"{format(r['iou_box'], '.2f') if 'iou_box' in r else '-'} |"
        )
    return "\n".join(lines)


def summary_table(summ: dict) -> str:
    keys = list(next(iter(summ.values())))
    lines = ["| | " + " | ".join(summ) + " |", "|---|" + "---|" * len(summ)]
    for k in keys:
        cells = []
        for s in summ.values():
            v = s[k]
            cells.append(f"{v:.2f}" if isinstance(v, float) else str(v))
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--refs", type=Path, default=ROOT / "tests" / "data" / "perception_refs")
    ap.add_argument("--split", choices=("all", "tune", "check"), default="all")
    ap.add_argument("--only", default="", help="substring of the photo names to run")
    ap.add_argument("--no-point", action="store_true", help="skip the one-point runs")
    ap.add_argument(
        "--click-only", action="store_true", help="only the one-point runs (no automatic choice)"
    )
    ap.add_argument(
        "--resample",
        type=float,
        default=1.0,
        help="resample every photo by this factor first (the same scenes at another size)",
    )
    ap.add_argument(
        "--jpeg",
        type=int,
        default=None,
        metavar="Q",
        help="save every photo (after --resample) as a JPEG of quality Q and read it back first "
        "(the same scenes through other pixels)",
    )
    ap.add_argument(
        "--mirror",
        action="store_true",
        help="mirror every photo left to right first (a left hand becomes a right one; the "
        "pixels are the same)",
    )
    ap.add_argument(
        "--rotate",
        type=int,
        default=0,
        choices=(0, 1, 2, 3),
        help="turn every photo by this many quarter turns counter-clockwise first (hands and "
        "objects are seen at every angle; the pixels are the same)",
    )
    ap.add_argument(
        "--crop",
        type=float,
        default=None,
        help="cut every photo to the box around its reference holding hands and held object, "
        "grown this many times (>= 1; as hand-object datasets crop their frames)",
    )
    ap.add_argument(
        "--choices",
        action="store_true",
        help="also pick each object region the automatic path offers (--object-choice K) and "
        "report the best (best_choice_iou_ge_0.5); with --click-only, each of the point's "
        "regions (point_best_of_K_ge_0.5)",
    )
    ap.add_argument(
        "--click-depth",
        type=float,
        default=None,
        metavar="F",
        help="click a pixel drawn (seeded by the photo's name) among those of the reference "
        "object at least F times as deep as its deepest pixel, instead of the deepest one",
    )
    ap.add_argument(
        "--click-draw",
        type=int,
        default=0,
        metavar="K",
        help="with --click-depth: the K-th draw of the click (0: seeded by the photo's name "
        "alone; K > 0: by the name and K), for several users' clicks on the same photos",
    )
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_perception.json")
    ap.add_argument(
        "--grabcut-seed", type=int, default=0,
        help="seed of OpenCV's random generator for GrabCut's colour models (the product's: 0); "
        "another seed shows how much the rates depend on one draw",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.jpeg is not None and not 1 <= args.jpeg <= 100:
        ap.error(f"--jpeg takes a quality from 1 to 100, got {args.jpeg}")
    if args.click_depth is not None and not 0.0 <= args.click_depth <= 1.0:
        ap.error(f"--click-depth must be in [0, 1], got {args.click_depth}")
    if args.click_draw < 0 or (args.click_draw and args.click_depth is None):
        ap.error("--click-draw takes K >= 0 and needs --click-depth")
    if not args.resample > 0:
        ap.error(f"--resample must be > 0, got {args.resample}")
    if args.crop is not None and not args.crop >= 1:
        ap.error(f"--crop must be >= 1, got {args.crop}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")

    from easyhoi.io.image import load_image
    from easyhoi.perception.masks import ClassicalHOISegmenter
    from easyhoi.perception.mediapipe_hand import MediaPipeHands

    files = sorted(args.refs.glob("*.json"))
    if not files:
        print(f"no reference files in {args.refs}", file=sys.stderr)
        return 1
    detector, segmenter = MediaPipeHands(), ClassicalHOISegmenter(seed=args.grabcut_seed)
    rows, names = [], []
    for f in files:
        half = "tune" if zlib.crc32(f.stem.encode()) % 2 == 0 else "check"
        if args.split != "all" and half != args.split:
            continue
        ref = reference(f)
        name = Path(ref["image"]).name
        if args.only and args.only not in name:
            continue
        rgb = resample(load_image(args.data / ref["image"]).rgb, args.resample)
        if args.jpeg is not None:
            rgb = reencode(rgb, args.jpeg)
        ref = fit_to(ref, rgb.shape[:2])
        if args.mirror:
            rgb, ref = mirror(rgb, ref)
        if args.rotate:
            rgb, ref = rotate(rgb, ref, args.rotate)
        if args.crop:
            rgb, ref = crop_around(rgb, ref, args.crop)
        if args.click_depth is not None and ref["object"] is not None:
            from tests.perception_refs import drawn_point  # on the path since reference()

            key = name if args.click_draw == 0 else f"{name}#{args.click_draw}"
            ref["point"] = drawn_point(ref["object"], args.click_depth, key)
        if args.click_only:
            row = run_click(rgb, ref, detector, segmenter, args.choices)
            row["half"] = half
            rows.append(row)
            names.append(name)
            print(
                f"{name[:44]:44s} {half:5s} pt={row.get('iou_point', float('nan')):.2f} "
                f"on={row.get('iou_point_clicked', float('nan')):.2f} "
                f"pt2={row.get('iou_point2', float('nan')):.2f} "
                f"fix={row.get('iou_fix', float('nan')):.2f}{row.get('fix', '')[:2]} "
                f"cands={row.get('ceiling_point') or float('nan'):.2f} "
                f"box={row.get('iou_box', float('nan')):.2f} "
                f"choices={[round(v, 2) for v in row.get('iou_point_choices', [])]} "
                f"{row.get('seconds_point', 0.0):.2f}s "
                f"cpu {row.get('cpu_seconds_point', 0.0):.2f}s",
                file=sys.stderr,
                flush=True,
            )
            continue
        row = run_photo(rgb, ref, detector, segmenter, not args.no_point, args.choices)
        row["half"] = half
        rows.append(row)
        names.append(name)
        print(
            f"{name[:44]:44s} {half:5s} iou={row['iou']:.2f} conf={row['confidence']} "
            f"pt={row.get('iou_point', float('nan')):.2f} "
            f"box={row.get('iou_box', float('nan')):.2f} "
            f"{row['seconds']:.2f}s",
            file=sys.stderr,
            flush=True,
        )
    summarise = click_summary if args.click_only else summary
    summ = {"all": summarise(rows)}
    for half in ("tune", "check"):
        part = [r for r in rows if r["half"] == half]
        if part and args.split == "all":
            summ[half] = summarise(part)
    if args.click_only:
        print(summary_table(summ))
        out = args.out.with_name(args.out.stem + "_click.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(
            json.dumps({"photos": dict(zip(names, rows, strict=True)), "summary": summ}, indent=1)
        )
        return 0
    print(table(rows, names))
    print()
    print(summary_table(summ))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"photos": dict(zip(names, rows, strict=True)), "summary": summ}, indent=1)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
