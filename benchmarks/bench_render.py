"""Benchmark of the soft silhouette renderer and depth peeling (CPU).

Times forward + backward of a loss on the soft silhouettes of a hand-sized mesh (~1.5k faces)
and an object (~5k faces) at 128/256/512 px: the culled renderer (eager and ``torch.compile``)
against the dense reference (every pixel x every face, chunked with checkpointing so memory
stays bounded) in the same run. Each configuration runs in its own subprocess so its peak
resident memory (``ru_maxrss``) is its own. Also times depth peeling (4 layers) of the object.

The dense reference costs exactly (pixels x faces) work, so by default it is timed on a band of
``--band`` image rows (the same camera cropped) and scaled to the full image; ``--full-dense``
times the whole image instead (minutes).

Usage::

    python benchmarks/bench_render.py            # 128, 256, 512 px (about 2-3 minutes idle)
    python benchmarks/bench_render.py --quick    # 128 px only
    python benchmarks/bench_render.py --no-compile --threads 2

Results: a table on stdout and ``benchmarks/results/bench_render.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _scene(size: int, dtype=None):
    import numpy as np
    import torch
    import trimesh

    from easyhoi.structures import Camera

    hand = trimesh.creation.capsule(height=0.12, radius=0.03, count=[28, 28])  # 1568 faces
    hand.apply_transform(trimesh.transformations.rotation_matrix(1.1, [0, 1, 0]))
    hand.apply_translation((0.04, 0.02, -0.07))
    obj = trimesh.creation.icosphere(4, radius=0.08)  # 5120 faces
    obj.vertices *= np.array([1.0, 0.8, 0.9])
    cam = Camera.look_at((0, 0, -0.6), (0, 0, 0), focal=size * 1.6, width=size, height=size)

    def t(m):
        return torch.tensor(m.vertices, dtype=torch.float32), torch.tensor(m.faces)

    return t(hand), t(obj), cam


def _band(cam, rows: int):
    """The same camera cropped to its middle ``rows`` image rows."""

    from easyhoi.structures import Camera

    top = (cam.height - rows) // 2
    K = cam.K.clone()
    K[1, 2] -= top
    return Camera(K, cam.R, cam.t, cam.width, rows), cam.height / rows


def _worker(cfg: dict) -> dict:
    import torch

    torch.set_num_threads(cfg["threads"])
    from easyhoi.render import soft
    from easyhoi.render.raster import peel, peel_pixels
    from easyhoi.render.reference import dense_soft_silhouette

    (hv, hf), (ov, of), cam = _scene(cfg["size"])
    meshes = {"hand": [(hv, hf)], "object": [(ov, of)], "hand+object": [(hv, hf), (ov, of)]}
    meshes = meshes[cfg["meshes"]]
    scale = 1.0
    method = cfg["method"]
    if method == "dense":
        if cfg.get("band"):
            cam, scale = _band(cam, cfg["band"])
        render = lambda v, f: dense_soft_silhouette(v, f, cam, sigma=cfg["sigma"], chunk_faces=512)  # noqa: E731
    elif method.startswith("culled"):
        backend = {"culled": "numba", "culled-torch": "torch", "culled-compiled": "compile"}[method]
        soft.set_backend(backend)
        sigma = cfg["sigma"]
        render = lambda v, f: soft.soft_silhouette(v, f, cam, sigma=sigma)  # noqa: E731
    target = torch.rand(cam.height, cam.width)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = {"pairs": None}

    if method in ("peel", "peel_pixels"):
        uv = torch.rand(500, 2) * cam.width

        def step():
            if method == "peel":
                return peel(ov, of, cam, num_layers=4)
            return peel_pixels(ov, of, cam, uv, num_layers=4)
    else:
        params = [v.clone().requires_grad_(True) for v, _ in meshes]

        def step():
            loss = 0.0
            for p, (_, f) in zip(params, meshes, strict=True):
                loss = loss + ((render(p, f) - target) ** 2).mean()
            loss.backward()

    kernel_s = [0.0]
    if method == "culled":  # time spent inside the numba kernels (the rest: projection, autograd)
        from easyhoi.render import _numba_kernels as kern

        for name in ("soft_logsum_forward", "soft_logsum_backward"):
            fn = getattr(kern, name)

            def timed(*a, _fn=fn):
                t = time.perf_counter()
                _fn(*a)
                kernel_s[0] += time.perf_counter() - t

            setattr(kern, name, timed)

    t0 = time.perf_counter()
    step()  # warm-up (includes compilation for the compiled variant)
    out["first_s"] = time.perf_counter() - t0
    times, cpu = [], []
    kernel_s[0] = 0.0
    for _ in range(cfg["repeats"]):
        t0, c0 = time.perf_counter(), time.process_time()
        step()
        times.append((time.perf_counter() - t0) * scale)
        cpu.append((time.process_time() - c0) * scale)
    out["ms_median"] = 1000 * statistics.median(times)
    out["cpu_ms_median"] = 1000 * statistics.median(cpu)
    out["ms_min"] = 1000 * min(times)
    out["peak_mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    out["extrapolated_x"] = scale
    out["kernel_share"] = kernel_s[0] / sum(times) if method == "culled" else None
    if method.startswith("culled"):
        from easyhoi.render._common import project_faces

        n = 0
        for v, f in meshes:
            tri_uv, _, _ = project_faces(v[None], f, cam, 1e-3)
            face, _ = soft._face_table(tri_uv, cam.height, cam.width, soft.cull_margin(sigma),
                                       torch.zeros(tri_uv.shape[0], dtype=torch.long))  # fmt: skip
            n += face.numel()
        out["pairs"] = n
    return out


def _run(cfg: dict) -> dict:
    proc = subprocess.run(
        [sys.executable, __file__, "--worker", json.dumps(cfg)],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        return {**cfg, "error": proc.stderr.strip().splitlines()[-1:] or ["failed"]}
    return {**cfg, **json.loads(proc.stdout.strip().splitlines()[-1])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="128 px only, fewer repeats")
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile variant")
    ap.add_argument("--full-dense", action="store_true", help="time dense on the whole image")
    ap.add_argument("--band", type=int, default=8, help="rows of the dense timing band")
    ap.add_argument("--threads", type=int, default=1, help="torch threads per worker")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--sigma", type=float, default=1.0, help="sharpness (px^2) of the main rows")
    ap.add_argument("--opt-sigma", type=float, default=0.1,
                    help="sharpness (px^2) of the extra optimizer-setting rows")  # fmt: skip
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(_worker(json.loads(args.worker))))
        return

    sizes = [128] if args.quick else [128, 256, 512]
    reps = args.repeats or (3 if args.quick else 7)
    base = {"threads": args.threads, "repeats": reps, "sigma": args.sigma}
    band = None if args.full_dense else args.band
    cfgs = []
    for s in sizes:
        cfgs.append({**base, "size": s, "meshes": "hand+object", "method": "culled"})
        cfgs.append({**base, "size": s, "meshes": "hand+object", "method": "culled-torch"})
        if not args.no_compile:
            cfgs.append({**base, "size": s, "meshes": "hand+object", "method": "culled-compiled"})
        cfgs.append({**base, "size": s, "meshes": "hand+object", "method": "dense",
                     "band": band, "repeats": 1})  # fmt: skip
        for m in ("hand", "object"):
            cfgs.append({**base, "size": s, "meshes": m, "method": "culled"})
        for m in ("hand", "hand+object"):  # the optimizer's sharpness; stages 2-3 render the hand
            for meth in ("culled", "culled-torch"):
                cfgs.append({**base, "size": s, "meshes": m, "method": meth,
                             "sigma": args.opt_sigma})  # fmt: skip
        cfgs.append({**base, "size": s, "meshes": "object", "method": "peel"})
        cfgs.append({**base, "size": s, "meshes": "object", "method": "peel_pixels"})

    rows = []
    print("ms per forward+backward = seconds per 1,000 iterations; kern = share of the time spent")
    print("inside the numba kernels (the rest: projection, autograd, loss)")
    hdr = f"{'px':>4} {'meshes':<12} {'method':<16} {'sigma':>5} {'pairs':>9} {'ms med':>9} "
    hdr += f"{'ms min':>9} "
    hdr += f"{'cpu ms':>9} "
    hdr += f"{'first s':>8} {'peak MB':>8} {'kern':>5} {'dense/culled':>12}"
    print(hdr)
    print("-" * len(hdr))
    for cfg in cfgs:
        r = _run(cfg)
        rows.append(r)
        if "error" in r:
            print(f"{cfg['size']:>4} {cfg['meshes']:<12} {cfg['method']:<16} ERROR {r['error']}")
            continue
        ratio = ""
        if r["method"] == "dense":
            for c in rows:
                if c.get("method") == "culled" and c["size"] == r["size"] and "error" not in c \
                        and c["meshes"] == r["meshes"] and c["sigma"] == r["sigma"]:  # fmt: skip
                    r["speedup_vs_culled"] = r["ms_median"] / c["ms_median"]
                    ratio = f"{r['speedup_vs_culled']:.0f}x"
            if r["extrapolated_x"] != 1.0:
                ratio += f" (band x{r['extrapolated_x']:.0f})"
        pairs = "" if r["pairs"] is None else str(r["pairs"])
        kern = "" if r.get("kernel_share") is None else f"{100 * r['kernel_share']:.0f}%"
        sig = "" if r["method"].startswith("peel") else f"{r['sigma']:g}"
        print(f"{r['size']:>4} {r['meshes']:<12} {r['method']:<16} {sig:>5} {pairs:>9} "
              f"{r['ms_median']:>9.1f} {r['ms_min']:>9.1f} {r['cpu_ms_median']:>9.1f} "
              f"{r['first_s']:>8.2f} "
              f"{r['peak_mb']:>8.0f} {kern:>5} {ratio:>12}", flush=True)  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    meta = {"python": platform.python_version(), "machine": platform.machine(),
            "threads": args.threads, "time": time.strftime("%Y-%m-%d %H:%M:%S")}  # fmt: skip
    path = RESULTS / "bench_render.json"
    path.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(f"\nwritten {path}")


if __name__ == "__main__":
    main()
