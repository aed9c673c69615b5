"""Real photos with reference 2D keypoints: the detector's keypoints against the final hand's.

For every photo of a COCO keypoint file (21 hand keypoints per image, OpenPose / MANO order),
the whole pipeline runs (``easyhoi.pipeline.reconstruct_photo``, the ``fast`` preset, seed 0)
and two sets of 2D keypoints are compared with the reference:

* the detector's (``HOIInput.meta["keypoints2d"]``, what the hand estimate was fitted to);
* the final hand's, its 21 keypoints reprojected through the fitted object camera.

Per image: mean pixel error and PCK@0.05 / PCK@0.1 (a keypoint within 5 % / 10 % of the larger
side of the reference keypoints' box), the mean pixel error of every stage snapshot (initial,
camera, contact, refine: where the hand gains or loses in the photo), and the ``hand_change``
summary of the result (how far the optimizer moved the hand from the estimator) and the
result's contact (``contact_distance_cm``, ``in_contact`` of its plausibility). The optimizer
must not make the hand worse in the photo than the detector's keypoints: ``final <= detector``
per image is the check.

Data: ``../shared/data/keypoints-dev`` (8 FreiHAND crops, ``test_freihand.json``) and the
project's own references ``tests/data/keypoint_refs/*.json`` (one hand of a development photo
each, format in ``tests/keypoint_refs.py``). On the own references the errors count only the
joints marked visible (a hidden joint's reference is a guess), and the annotated hand is chosen
with a hand point at the centre of its reference keypoints (the photos may show two hands; the
check is about the hand, not about which hand perception picks). Missing photos are skipped.

Usage::

    python benchmarks/bench_keypoints.py                 # every data set found
    python benchmarks/bench_keypoints.py --limit 2       # first 2 photos of each
    python benchmarks/bench_keypoints.py --coco FILE.json --images DIR
    python benchmarks/bench_keypoints.py --set optim.contact.keypoint_weight=0   # a variant

Results: a table on stdout and ``benchmarks/results/bench_keypoints.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from preset_overrides import add_set_option, fast_overrides  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
SHARED = (ROOT.parent / "shared" / "data", Path("/work/shared/data"))
OWN_REFS = ROOT / "tests" / "data" / "keypoint_refs"
DATASETS = (
    (ROOT.parent / "shared" / "data" / "keypoints-dev" / "test_freihand.json", None),
    (Path("/work/shared/data/keypoints-dev/test_freihand.json"), None),
)


def load_coco(path: Path, images: Path | None = None) -> list[tuple[Path, np.ndarray]]:
    """(photo path, (21, 2) reference keypoints) per annotated image of a COCO keypoint file."""
    data = json.loads(path.read_text())
    folder = images or path.parent
    names = {im["id"]: im["file_name"] for im in data["images"]}
    out = []
    for ann in data["annotations"]:
        kp = np.asarray(ann["keypoints"], dtype=np.float64).reshape(-1, 3)
        if kp.shape[0] != 21:
            continue
        out.append((folder / names[ann["image_id"]], kp[:, :2]))
    return sorted(out, key=lambda x: x[0].name)


def load_own_refs(folder: Path, shared: Path) -> list[tuple[Path, np.ndarray, np.ndarray]]:
    """(photo path, (21, 2) keypoints, (21,) visible) per own reference whose photo exists."""
    out = []
    for path in sorted(folder.glob("*.json")):
        data = json.loads(path.read_text())
        kp = np.asarray(data["keypoints"], dtype=np.float64).reshape(-1, 3)
        photo = shared / data["image"]
        if kp.shape[0] == 21 and photo.is_file():
            out.append((photo, kp[:, :2], kp[:, 2] > 0.5))
    return out


def errors(pred: np.ndarray, ref: np.ndarray, visible: np.ndarray | None = None) -> dict:
    """Mean pixel error and PCK at 5 % / 10 % of the reference box's larger side.

    With ``visible``, only those joints are counted (the box is still all 21 joints').
    """
    d = np.linalg.norm(np.asarray(pred, dtype=np.float64) - ref, axis=1)
    size = float(np.ptp(ref, axis=0).max())
    if visible is not None:
        d = d[np.asarray(visible, bool)]
    return {
        "mean_px": float(d.mean()),
        "pck05": float((d <= 0.05 * size).mean()),
        "pck10": float((d <= 0.1 * size).mean()),
    }


def final_keypoints(result) -> np.ndarray:
    """(21, 2) keypoints of the result's hand reprojected through its camera."""
    return _reprojected(result.hand_model, result.hand_params, result.camera, result.metric_scale)


def stage_keypoints(result) -> dict[str, np.ndarray]:
    """Stage name -> (21, 2) keypoints of that stage's snapshot through its camera."""
    return {
        st.name: _reprojected(result.hand_model, st.hand_params, st.camera, st.metric_scale)
        for st in result.stages
        if st.hand_params is not None and st.camera is not None
    }


def _reprojected(hand_model: str, params, camera, metric_scale: float) -> np.ndarray:
    import torch

    from easyhoi.hand import load_hand_model
    from easyhoi.optim.hand_change import reprojected_keypoints

    model = load_hand_model(hand_model, dtype=torch.float64)
    return reprojected_keypoints(model, params, camera, metric_scale)


def run_photo(
    photo: Path,
    ref: np.ndarray,
    visible: np.ndarray | None = None,
    hand_point: bool = False,
    overrides: dict | None = None,
) -> dict:
    from easyhoi.config import get_preset, with_overrides
    from easyhoi.errors import EasyHOIError
    from easyhoi.perception.prompts import Prompts
    from easyhoi.pipeline import reconstruct_photo

    prompts = None
    if hand_point:
        cx, cy = ref.mean(axis=0)
        prompts = Prompts(hand_point=(float(cx), float(cy)))
    t0 = time.perf_counter()
    try:
        cfg = with_overrides(get_preset("fast"), overrides or {})
        rec = reconstruct_photo(photo, None, cfg, seed=0, prompts=prompts)
    except EasyHOIError as exc:
        return {"photo": photo.name, "error": f"{type(exc).__name__}: {exc}"}
    det = rec.inp.meta.get("keypoints2d")
    row = {"photo": photo.name, "seconds": time.perf_counter() - t0}
    if det is not None:
        row["detector"] = errors(np.asarray(det), ref, visible)
    row["final"] = errors(final_keypoints(rec.result), ref, visible)
    row["stages_px"] = {
        name: errors(uv, ref, visible)["mean_px"]
        for name, uv in stage_keypoints(rec.result).items()
    }
    row["hand_change"] = {
        k: v for k, v in rec.result.hand_change.items() if k.startswith(("mean", "max"))
    }
    plaus = rec.result.plausibility
    row["contact_cm"] = plaus.get("contact_distance_cm")
    row["in_contact"] = plaus.get("in_contact")
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--coco", type=Path, help="a COCO keypoint file (default: the data sets)")
    ap.add_argument("--images", type=Path, help="folder of its photos (default: beside it)")
    ap.add_argument("--limit", type=int, default=0, help="first N photos of each set (0: all)")
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_keypoints.json")
    add_set_option(ap)
    args = ap.parse_args(argv)
    overrides = fast_overrides(ap, args.set)
    import torch

    torch.set_num_threads(1)
    sets = [(args.coco, args.images)] if args.coco else list(DATASETS)
    rows, seen = [], set()
    for coco, images in sets:
        if coco is None or not coco.exists() or coco.resolve() in seen:
            continue
        seen.add(coco.resolve())
        items = load_coco(coco, images)
        for photo, ref in items[: args.limit or None]:
            row = run_photo(photo, ref, overrides=overrides)
            row["set"] = coco.name
            rows.append(row)
            print(_line(row), flush=True)
    if not args.coco:
        shared = next((d for d in SHARED if d.is_dir()), None)
        own = load_own_refs(OWN_REFS, shared) if shared else []
        for photo, ref, visible in own[: args.limit or None]:
            row = run_photo(photo, ref, visible, hand_point=True, overrides=overrides)
            row["set"] = "keypoint_refs"
            rows.append(row)
            print(_line(row), flush=True)
    if not rows:
        print("no keypoint data found", file=sys.stderr)
        return 1
    ok = [r for r in rows if "detector" in r and "final" in r]
    worse = [r["photo"] for r in ok if r["final"]["mean_px"] > r["detector"]["mean_px"]]
    summary = {
        "photos": len(rows),
        "detector_mean_px": float(np.mean([r["detector"]["mean_px"] for r in ok])) if ok else None,
        "final_mean_px": float(np.mean([r["final"]["mean_px"] for r in ok])) if ok else None,
        "final_worse_than_detector": worse,
    }
    print(json.dumps(summary, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"summary": summary, "photos": rows}, indent=1))
    return 0


def _line(row: dict) -> str:
    if "error" in row:
        return f"{row['photo']}: {row['error']}"
    d, f = row.get("detector"), row["final"]
    det = f"detector {d['mean_px']:.2f} px PCK@0.05 {d['pck05']:.2f}" if d else "detector n/a"
    stages = " -> ".join(f"{v:.2f}" for v in row.get("stages_px", {}).values())
    return (f"{row['photo']}: {det}; final {f['mean_px']:.2f} px PCK@0.05 {f['pck05']:.2f}; "
            f"stages {stages} px; "
            f"moved {row['hand_change'].get('mean_px', float('nan')):.2f} px, "
            f"{row['hand_change'].get('mean_cm', float('nan')):.2f} cm; "
            f"contact {row.get('contact_cm', float('nan')):.2f} cm")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
