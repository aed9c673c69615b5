"""Object-shape benchmark: the object step on synthetic photos of scanned and procedural objects.

Each scene (:func:`easyhoi.synth.scene.make_scene`) is a rendered photo of an object held by a
synthesized grasp. The object step runs as in the chain: the hand is inpainted away (classical
inpainter), the amodal mask is completed from the visible object mask behind the hand mask
(classical amodal segmenter, occluder-bounded; ``--grabcut-amodal``: prompted GrabCut alone), and
the silhouette reconstructor fits its shapes with the hand's keypoints. The keypoints stand in
for a detector + hand fit: the scene's 2D keypoints with 1.5 px noise and its
camera-frame 3D keypoints with 4 mm noise and a random hand-size error of 7 % (a fitted hand
model has the mean size, real hands differ), drawn for each scene (seed and object).

Per scene, against the scanned mesh (metres):

* ``cd``, ``f5``, ``f10``: Chamfer distance (cm^2 / 10) and F-scores at 5 / 10 mm after a
  similarity alignment that also solves the rotation (:func:`similarity_align`: symmetric ICP
  with scale from the 24 axis-aligned starts of the principal frames, best kept);
* ``cd_placed``, ``f10_placed``: as placed by the object step (metric size from the hand,
  position from the grip, no alignment);
* ``scale_err``: ``|s - 1|`` for the scale ``s`` the alignment applies to the metric prediction;
  it splits into ``scale_cue`` (the hand's image scale over the true one at the object's centre:
  the part a perfect shape in pixels would keep) and ``scale_shape = s / scale_cue`` (the part
  from the outline and the depth: amodal errors, foreshortening, thickness);
* ``oracle`` (``--oracle``): every family fitted alone, its C.D.; ``oracle_cd`` is the best one
  (what perfect selection would give) and ``oracle_shape`` its family;
* the same C.D. / F-scores for two baselines, aligned the same way: a sphere of the object's
  volume (``sphere_*``) and the object's oriented bounding box (``box_*``, true proportions).

Usage: ``python benchmarks/bench_object.py [--seeds 0 1] [--objects DIR] [--size 320]
[--procedural] [--oracle] [--grabcut-amodal] [--amodal-only] [--json OUT]``; prints a Markdown
table and a summary.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from easyhoi.geometry.masks import mask_iou

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OBJECTS = ROOT.parent / "shared" / "data" / "objects"


def _rotations24() -> list[np.ndarray]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            R = np.zeros((3, 3))
            for i, (j, s) in enumerate(zip(perm, signs, strict=True)):
                R[i, j] = s
            if np.linalg.det(R) > 0:
                out.append(R)
    return out


def _pca(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = points.mean(0)
    _, vec = np.linalg.eigh(np.cov((points - c).T))
    return c, vec[:, ::-1]


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / max((a**2).sum() / len(src), 1e-18))
    return s, R, md - s * R @ ms


def similarity_align(pred: np.ndarray, gt: np.ndarray, iterations: int = 25):
    """(scale, R, t) moving ``pred`` points onto ``gt`` (symmetric ICP, 24 starts)."""
    tree_g = cKDTree(gt)
    cg, Eg = _pca(gt)
    cp, Ep = _pca(pred)
    rms = lambda x: np.sqrt(((x - x.mean(0)) ** 2).sum(1).mean())  # noqa: E731
    s0 = rms(gt) / max(rms(pred), 1e-12)
    best = None
    for Q in _rotations24():
        R = Eg @ Q @ Ep.T
        s, t = s0, cg - s0 * R @ cp
        for _ in range(iterations):
            moved = s * pred @ R.T + t
            _, ig = tree_g.query(moved, workers=1)
            _, ip = cKDTree(moved).query(gt, workers=1)
            src = np.concatenate([pred, pred[ip]])
            dst = np.concatenate([gt[ig], gt])
            s, R, t = _umeyama(src, dst)
        moved = s * pred @ R.T + t
        err = tree_g.query(moved, workers=1)[0].mean() + cKDTree(moved).query(gt)[0].mean()
        if best is None or err < best[0]:
            best = (err, s, R, t)
    return best[1:]


def _metrics(pred: trimesh.Trimesh, gt: trimesh.Trimesh, align: bool, n: int = 10000) -> dict:
    from easyhoi.metrics.object import chamfer_fscore, sample_surface

    s, R, t = 1.0, np.eye(3), np.zeros(3)
    if align:
        s, R, t = similarity_align(sample_surface(pred, 1500, 1), sample_surface(gt, 1500, 1))
    moved = trimesh.Trimesh(s * np.asarray(pred.vertices) @ R.T + t, pred.faces, process=False)
    m = chamfer_fscore(moved, gt, n_samples=n, align="none", thresholds_mm=(5, 10))
    return {"cd": m.chamfer, "f5": m.f_at(5), "f10": m.f_at(10), "scale": s}


def _baselines(gt: trimesh.Trimesh) -> dict[str, trimesh.Trimesh]:
    r = (3 * gt.volume / (4 * np.pi)) ** (1 / 3)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=r)
    obb = gt.bounding_box_oriented
    box = trimesh.creation.box(extents=obb.primitive.extents, transform=obb.primitive.transform)
    return {"sphere": sphere, "box": box}


def _placed(mesh: trimesh.Trimesh, K: np.ndarray) -> trimesh.Trimesh | None:
    """The object step's mesh in the camera frame, metres (metric size and grip depth)."""
    md = mesh.metadata["easyhoi"]
    if "meters_per_unit" not in md:
        return None
    ppm = md["hand_cues"]["px_per_m"]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    z_hand = 0.5 * (fx + fy) / ppm
    v = np.asarray(mesh.vertices) * md["pixels_per_unit"]
    u = v[:, 0] + md["center_px"][0]
    w = v[:, 1] + md["center_px"][1]
    z0 = z_hand + md["grip_depth_m"]
    Z = z0 + v[:, 2] / ppm
    X = (u - cx) * z0 / fx
    Y = (w - cy) * z0 / fy
    return trimesh.Trimesh(np.stack([X, Y, Z], 1), mesh.faces, process=False)


def run_scene(
    obj, seed: int, size: int, gt_amodal: bool = False, oracle: bool = False, grabcut: bool = False
) -> dict:
    import torch

    from easyhoi.perception.amodal import ClassicalAmodalSegmenter, amodal_prompts
    from easyhoi.perception.base import create
    from easyhoi.perception.objects import SilhouetteReconstructor
    from easyhoi.synth.scene import make_scene

    sc = make_scene(seed, obj, image_size=size)
    # the detector's noise and the hand-size error are drawn per scene: one draw per seed would
    # give every object of the seed the same size error, and a seed's median would be that draw
    rng = np.random.default_rng([seed, 4242, zlib.crc32(Path(str(obj)).stem.encode())])
    k2 = sc.keypoints_2d + rng.normal(0, 1.5, sc.keypoints_2d.shape)
    cam = sc.camera
    k3 = cam.world_to_camera(torch.as_tensor(sc.keypoints_3d, dtype=cam.R.dtype)).numpy()
    k3 = (k3 - k3.mean(0)) * (1 + rng.normal(0, 0.07)) + rng.normal(0, 0.004, k3.shape)
    inpainted = create("inpainter", "opencv").inpaint(sc.image, sc.hand_mask)
    pts, box = amodal_prompts(sc.object_mask, seed=seed)
    amodal = ClassicalAmodalSegmenter().segment(
        inpainted, pts, box, sc.object_mask, hand_mask=None if grabcut else sc.hand_mask
    )
    amodal = (sc.object_amodal if gt_amodal else amodal) | sc.object_mask
    kw = dict(visible_mask=sc.object_mask, hand_mask=sc.hand_mask, hand_keypoints2d=k2,
              hand_keypoints3d=k3)  # fmt: skip
    t0 = time.perf_counter()
    mesh = SilhouetteReconstructor().reconstruct(inpainted, amodal, **kw)
    seconds = time.perf_counter() - t0
    md = mesh.metadata["easyhoi"]
    gt_world = sc.object.mesh
    R = cam.R.numpy()
    t = cam.t.numpy()
    gt_cam = trimesh.Trimesh(np.asarray(gt_world.vertices) @ R.T + t, gt_world.faces)
    metric = mesh.copy()
    metric.vertices = np.asarray(mesh.vertices) * md["meters_per_unit"]
    row = {"object": sc.object.name, "seed": seed, "shape": md["method"], "seconds": seconds,
           "amodal_iou": mask_iou(amodal, sc.object_amodal)}  # fmt: skip
    a = _metrics(metric, gt_world, align=True)
    row.update(cd=a["cd"], f5=a["f5"], f10=a["f10"], scale_err=abs(a["scale"] - 1))
    centre = gt_world.bounds.mean(0) @ R.T + t
    px_true = float(cam.K[0, 0]) / float(centre[2])
    row["scale_cue"] = md["hand_cues"]["px_per_m"] / px_true
    row["scale_shape"] = a["scale"] / row["scale_cue"]
    # the step's own record of every family's score and its parts, to study the selection
    row["scores"] = md["shape"]["scores"]
    row["flat_by_grip"] = md["shape"]["flat_by_grip"]
    if oracle:
        from easyhoi.perception.shapes import FAMILIES

        fam = {}
        for name in FAMILIES:
            one = SilhouetteReconstructor(families=(name,)).reconstruct(inpainted, amodal, **kw)
            one.vertices = np.asarray(one.vertices) * one.metadata["easyhoi"]["meters_per_unit"]
            fam[name] = _metrics(one, gt_world, align=True)["cd"]
        row["oracle"] = fam
        row["oracle_shape"] = min(fam, key=fam.get)
        row["oracle_cd"] = fam[row["oracle_shape"]]
    placed = _placed(mesh, cam.K.numpy())
    p = _metrics(placed, gt_cam, align=False)
    row.update(cd_placed=p["cd"], f10_placed=p["f10"])
    for name, base in _baselines(gt_world).items():
        b = _metrics(base, gt_world, align=True)
        row.update({f"{name}_cd": b["cd"], f"{name}_f5": b["f5"], f"{name}_f10": b["f10"]})
    return row


def amodal_scene(obj, seed: int, size: int) -> dict:
    """Amodal-mask diagnostic (``--amodal-only``): IoU with the true amodal mask of the visible
    mask, of prompted GrabCut, and of the occluder-bounded completion; and, as fractions of the
    true area, what each adds outside the truth inside / outside the hand region and what it
    misses."""
    from easyhoi.perception.amodal import ClassicalAmodalSegmenter, amodal_prompts
    from easyhoi.perception.base import create
    from easyhoi.synth.scene import make_scene

    sc = make_scene(seed, obj, image_size=size)
    inpainted = create("inpainter", "opencv").inpaint(sc.image, sc.hand_mask)
    pts, box = amodal_prompts(sc.object_mask, seed=seed)
    vis, hand, gt = sc.object_mask, sc.hand_mask, sc.object_amodal
    seg = ClassicalAmodalSegmenter()
    masks = {
        "grabcut": seg.segment(inpainted, pts, box, vis),
        "occluder": seg.segment(inpainted, pts, box, vis, hand_mask=hand),
    }
    area = max(1, int(gt.sum()))
    row = {"object": sc.object.name, "seed": seed, "visible_iou": mask_iou(vis, gt, empty=0.0)}
    for k, m in masks.items():
        row[f"{k}_iou"] = mask_iou(m, gt, empty=0.0)
        row[f"{k}_add_hand"] = float((m & ~gt & hand).sum() / area)
        row[f"{k}_add_out"] = float((m & ~gt & ~hand).sum() / area)
        row[f"{k}_miss"] = float((gt & ~m).sum() / area)
    return row


def _amodal_main(objs, args) -> int:
    rows = [amodal_scene(o if args.procedural else str(o), s, args.size) for o in objs
            for s in args.seeds]  # fmt: skip
    cols = list(rows[0])
    print("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.3f}" if isinstance(r[c], float) else str(r[c])
                                for c in cols) + " |")  # fmt: skip
    summary = {f"{c}_median": float(np.median([r[c] for r in rows])) for c in cols[2:]}
    summary |= {f"{c}_mean": float(np.mean([r[c] for r in rows])) for c in cols[2:]}
    print(json.dumps(summary, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


def _table(rows: list[dict]) -> str:
    cols = ["object", "seed", "shape", "cd", "f5", "f10", "scale_err", "scale_cue",
            "scale_shape", "cd_placed", "f10_placed", "box_cd", "box_f10", "sphere_cd",
            "sphere_f10", "seconds"]  # fmt: skip
    if rows and "oracle" in rows[0]:
        cols[3:3] = ["oracle_shape", "oracle_cd"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = [f"{r[c]:.3f}" if isinstance(r[c], float) else str(r[c]) for c in cols]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def summarize(rows: list[dict]) -> dict:
    """Per-object means over seeds, then the acceptance figures."""
    by = {}
    for r in rows:
        by.setdefault(r["object"], []).append(r)
    keys = ["cd", "f10", "box_cd", "sphere_cd", "scale_err", "f5", "cd_placed"]
    keys += ["oracle_cd"] if all("oracle_cd" in r for r in rows) else []
    per = {k: {c: float(np.mean([r[c] for r in v])) for c in keys} for k, v in by.items()}
    n = len(per)
    extra = {}
    if "oracle_cd" in keys:
        extra["beats_box_oracle"] = sum(v["oracle_cd"] < v["box_cd"] for v in per.values())
        extra["oracle_cd_median"] = float(np.median([v["oracle_cd"] for v in per.values()]))
    return extra | {
        "objects": n,
        "beats_box": sum(v["cd"] < v["box_cd"] for v in per.values()),
        "beats_sphere": sum(v["cd"] < v["sphere_cd"] for v in per.values()),
        "f10_mean": float(np.mean([v["f10"] for v in per.values()])),
        "f5_mean": float(np.mean([v["f5"] for v in per.values()])),
        "cd_median": float(np.median([v["cd"] for v in per.values()])),
        "box_cd_median": float(np.median([v["box_cd"] for v in per.values()])),
        "sphere_cd_median": float(np.median([v["sphere_cd"] for v in per.values()])),
        "scale_err_median": float(np.median([r["scale_err"] for r in rows])),
        "scale_cue_err_median": float(np.median([abs(r["scale_cue"] - 1) for r in rows])),
        "scale_shape_err_median": float(np.median([abs(r["scale_shape"] - 1) for r in rows])),
        "cd_placed_median": float(np.median([r["cd_placed"] for r in rows])),
        "seconds_median": float(np.median([r["seconds"] for r in rows])),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default=str(DEFAULT_OBJECTS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--procedural", action="store_true", help="the procedural kinds instead")
    ap.add_argument("--only", nargs="*", default=None, help="object names to run")
    ap.add_argument("--json", default=None)
    ap.add_argument("--jsonl", default=None, help="append each row as it is measured")
    ap.add_argument("--gt-amodal", action="store_true", help="the true amodal mask as input")
    ap.add_argument("--oracle", action="store_true", help="also fit every family alone")
    ap.add_argument("--grabcut-amodal", action="store_true",
                    help="prompted GrabCut amodal mask (no occluder bound) as input")  # fmt: skip
    ap.add_argument("--amodal-only", action="store_true",
                    help="diagnostic: amodal-mask IoU per scene, no object step")  # fmt: skip
    args = ap.parse_args(argv)
    from easyhoi.synth.objects import OBJECT_KINDS, list_objects

    objs = list(OBJECT_KINDS) if args.procedural else list_objects(args.objects)
    if args.only:
        objs = [o for o in objs if Path(str(o)).stem in args.only]
    if args.amodal_only:
        return _amodal_main(objs, args)
    rows = []
    for obj in objs:
        for seed in args.seeds:
            r = run_scene(
                obj if args.procedural else str(obj),
                seed,
                args.size,
                args.gt_amodal,
                args.oracle,
                args.grabcut_amodal,
            )
            rows.append(r)
            if args.jsonl:
                with open(args.jsonl, "a") as fh:
                    fh.write(json.dumps(r) + "\n")
            print(f"{r['object']:28s} s{seed} {r['shape']:12s} cd {r['cd']:.3f} f5 {r['f5']:.3f} "
                  f"box {r['box_cd']:.3f} sph {r['sphere_cd']:.3f} f10 {r['f10']:.3f} "
                  f"scale {r['scale_err']:.3f} placed {r['cd_placed']:.2f} "
                  f"amodal {r['amodal_iou']:.2f} {r['seconds']:.2f}s", file=sys.stderr)  # fmt: skip
    print(_table(rows))
    summary = summarize(rows)
    print(json.dumps(summary, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
