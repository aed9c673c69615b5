"""CPU against GPU: the optimizer's stages, the renderer and the large-model adapters.

Three tables, each with a CPU and a GPU column (the GPU columns say "no GPU" where torch sees
none; the script runs the same either way):

1. **Optimizer**: seconds per stage (setup, initial, camera, contact, refine, plausibility,
   total) of the "fast" and "paper" presets on the synthetic benchmark's held grasps
   (:func:`easyhoi.synth.scene.make_scene`, the scenes of ``easyhoi bench``, "hamer"
   perturbation), ``device="cpu"`` (numba kernels) and ``device="cuda"`` (torch kernels). Every
   row also gives the largest hand-vertex difference between the two devices (object units),
   which docs/gpu.md bounds. One untimed warm-up run per device first (numba compilation, CUDA
   context and kernel loading).
2. **Renderer**: forward + backward of a loss on the soft silhouette of a ~5k-face sphere, the
   z-buffer and 4-layer depth peeling, at 256 / 512 / 1024 px (median of ``--repeat`` runs):
   CPU numba, CPU torch and CUDA torch (with ``torch.cuda.synchronize``); ``--compile`` adds
   the ``torch.compile`` kernels on each device (whether they pay on a GPU is open).
3. **Adapters**: one call of each large-model adapter (SAM amodal completion, depth-to-mesh,
   diffusion inpainting) built with a tiny random-weight model (transformers / diffusers
   configurations, nothing downloaded), on each device: the adapters' own overhead and data
   movement, not the real models' speed.

CPU timings use ``--threads`` torch threads (default 1; set it explicitly: torch's default of
one thread per core is several times slower on these small problems on a shared machine).

Usage::

    python benchmarks/bench_gpu.py                    # 2 scenes, 256/512/1024 px, adapters
    python benchmarks/bench_gpu.py --quick            # 1 small scene, paper capped at 20
                                                      # iterations, 256 px only, no adapters
    python benchmarks/bench_gpu.py --scenes 5 --threads 4

Results: tables on stdout and ``benchmarks/results/bench_gpu.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

RESULTS = Path(__file__).resolve().parent / "results"
STAGES = ("setup", "initial", "camera", "contact", "refine", "plausibility", "total")
NO_GPU = "no GPU"


def _devices() -> list[str]:
    return ["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _fmt(x, digits: int = 3) -> str:
    return NO_GPU if x is None else f"{x:.{digits}f}"


# ----------------------------------------------------------------------------------------------
# optimizer
# ----------------------------------------------------------------------------------------------


def _scenes(n: int, size: int) -> list[tuple[str, object]]:
    """The benchmark's held grasps. Holding them (the camera rolled until the grasp holds under
    gravity) runs the simulation metric, which needs pybullet; where it is missing (no wheel
    for Python 3.12 and later) the scenes are drawn without the roll, with a note: the timings
    and the CPU-GPU agreement do not depend on which way up the photo is."""
    from easyhoi.errors import MissingDependencyError
    from easyhoi.synth.benchmark import scene_specs
    from easyhoi.synth.scene import make_scene

    out = []
    hold = True
    for seed, kind, grasp in scene_specs(n):
        try:
            scene = make_scene(seed, kind, grasp, image_size=size, hold=hold)
        except MissingDependencyError as exc:
            print(f"note: {exc}; scenes drawn without the holding roll", file=sys.stderr)
            hold = False
            scene = make_scene(seed, kind, grasp, image_size=size, hold=False)
        out.append((f"{seed}-{kind}-{grasp}", scene.to_hoi_input("hamer", seed=seed)))
    return out


def _preset(name: str, cap: int):
    from easyhoi.config import get_preset, with_overrides

    cfg = get_preset(name).optim
    if cap <= 0:
        return cfg
    return with_overrides(cfg, {f"{s}.max_iters": min(getattr(cfg, s).max_iters, cap)
                                for s in ("camera", "contact", "refine")})  # fmt: skip


def bench_optimizer(scenes, presets: dict, devices: list[str]) -> list[dict]:
    from easyhoi.config import with_overrides
    from easyhoi.optim.run import optimize

    tiny = {"camera.max_iters": 2, "contact.max_iters": 2, "refine.max_iters": 2}
    for device in devices:  # warm-up, untimed
        optimize(scenes[0][1], with_overrides(presets["fast"], tiny), device=device)
    rows = []
    for label, inp in scenes:
        for preset, cfg in presets.items():
            row = {"scene": label, "preset": preset}
            verts = {}
            for device in devices:
                _sync(device)
                res = optimize(inp, cfg, device=device)
                _sync(device)
                row[device] = {k: round(float(res.timings.get(k, 0.0)), 3) for k in STAGES}
                verts[device] = res.hand_vertices
            if "cuda" in verts:
                row["max_vertex_diff"] = float(np.abs(verts["cuda"] - verts["cpu"]).max())
            rows.append(row)
            print(_optim_line(row), flush=True)
    return rows


def _optim_line(row: dict) -> str:
    cpu, gpu = row["cpu"], row.get("cuda")
    stages = " ".join(f"{k}={cpu[k]:.2f}/{_fmt(gpu and gpu[k], 2)}" for k in STAGES)
    diff = row.get("max_vertex_diff")
    tail = "" if diff is None else f" | max vertex diff {diff:.2e}"
    return f"{row['scene']:<24} {row['preset']:<6} cpu/gpu s: {stages}{tail}"


# ----------------------------------------------------------------------------------------------
# renderer
# ----------------------------------------------------------------------------------------------


def _render_scene(size: int):
    import trimesh

    from easyhoi.structures import Camera

    m = trimesh.creation.icosphere(4, radius=1.0)  # 5120 faces
    v = torch.tensor(m.vertices * [1.0, 0.8, 0.9], dtype=torch.float32)
    cam = Camera.look_at((0.4, 0.3, -3.0), (0, 0, 0), focal=size * 1.2, width=size,
                         height=size, dtype=torch.float32)  # fmt: skip
    return v, torch.tensor(m.faces), cam


def _time(fn, device: str, repeat: int) -> float:
    fn()  # warm-up (numba compilation, CUDA kernels)
    times = []
    for _ in range(repeat):
        _sync(device)
        t = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def bench_renderer(sizes, repeat: int, compile_: bool = False) -> list[dict]:
    from easyhoi.render import depth_map, peel, soft, soft_silhouette

    configs = [("cpu", "numba"), ("cpu", "torch")]
    configs += [("cuda", "torch")] if torch.cuda.is_available() else []
    if compile_:  # torch.compile of the soft kernels (dynamic shapes); compiled once, untimed
        configs += [(device, "compile") for device, _ in configs if _ == "torch"]
    rows = []
    for size in sizes:
        v0, f0, cam0 = _render_scene(size)
        row = {"size": size}
        for device, backend in configs:
            v, f, cam = v0.to(device), f0.to(device), cam0.to(device=device)
            w = torch.rand(size, size, device=device, generator=None)

            def soft_fb(v=v, f=f, cam=cam, w=w):
                vv = v.clone().requires_grad_(True)
                (soft_silhouette(vv, f, cam, sigma=0.5) * w).sum().backward()

            soft.set_backend(backend)
            try:
                row[f"{device}-{backend}"] = {
                    "soft_fwd_bwd": _time(soft_fb, device, repeat),
                    "zbuffer": _time(
                        lambda v=v, f=f, cam=cam: depth_map(v, f, cam), device, repeat
                    ),
                    "peel4": _time(lambda v=v, f=f, cam=cam: peel(v, f, cam, 4), device, repeat),
                }
            finally:
                soft.set_backend("auto")
        rows.append(row)
        print(_render_line(row), flush=True)
    return rows


def _render_line(row: dict) -> str:
    parts = []
    names = [k for k in row if k != "size"]
    names += [] if "cuda-torch" in names else ["cuda-torch"]
    for key in ("soft_fwd_bwd", "zbuffer", "peel4"):
        cols = [_fmt(row.get(c, {}).get(key), 4) for c in names]
        parts.append(f"{key} " + "/".join(cols))
    return f"{row['size']:>5} px  {'/'.join(names)} s: " + " | ".join(parts)


# ----------------------------------------------------------------------------------------------
# adapters with tiny random-weight models
# ----------------------------------------------------------------------------------------------


def bench_adapters(repeat: int) -> list[dict]:
    from easyhoi.perception.base import create

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)
    yy, xx = np.mgrid[:96, :128]
    mask = (yy - 48) ** 2 + (xx - 64) ** 2 < 30**2
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        specs = []
        # the tiny inpainter runs 2 denoising steps at 64 px (the defaults, 25 at 512 px,
        # take minutes on a CPU even with a tiny UNet)
        from easyhoi.testing.tiny_models import (
            write_tiny_depth,
            write_tiny_inpainter,
            write_tiny_sam,
        )

        for name, build, role, call, kw in (
            ("sam", write_tiny_sam, "amodal", lambda a: a.segment(image, None, None, mask), {}),
            ("depth", write_tiny_depth, "object", lambda a: a.reconstruct(image, mask), {}),
            ("diffusion", write_tiny_inpainter, "inpainter", lambda a: a.inpaint(image, mask),
             {"steps": 2, "resolution": 64}),
        ):  # fmt: skip
            folder = Path(tmp) / name
            folder.mkdir()
            try:
                sub = build(folder)
            except ImportError as exc:
                print(f"{name}: skipped ({exc})")
                continue
            specs.append((name, role, sub, call, kw))
        for name, role, folder, call, kw in specs:
            row = {"adapter": name}
            for device in _devices():
                adapter = create(role, name, model_dir=folder, device=device, **kw)
                row[device] = _time(lambda a=adapter, c=call: c(a), device, repeat)
            rows.append(row)
            gpu = row.get("cuda")
            gpu = NO_GPU if gpu is None else f"{gpu:.4f} s"
            print(f"{name:<10} cpu {row['cpu']:.4f} s, gpu {gpu}", flush=True)
    return rows


# ----------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=2, help="synthetic scenes (default 2)")
    ap.add_argument("--size", type=int, default=256, help="scene image size (default 256)")
    ap.add_argument(
        "--paper-cap",
        type=int,
        default=0,
        help="cap the paper preset's stages at N iterations (default 0: none)",
    )
    ap.add_argument("--sizes", default="256,512,1024", help="renderer image sizes")
    ap.add_argument("--repeat", type=int, default=5, help="renderer/adapter runs (median)")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    ap.add_argument("--no-adapters", action="store_true", help="skip the adapter table")
    ap.add_argument(
        "--compile",
        action="store_true",
        help="also time the renderer's torch.compile kernels (compiles first)",
    )
    ap.add_argument("--quick", action="store_true",
                    help="1 scene at 96 px, paper capped at 20 iterations, 256 px renders, "
                         "2 repeats, no adapters (checks that the script runs)")  # fmt: skip
    ap.add_argument("--out", default=str(RESULTS / "bench_gpu.json"))
    args = ap.parse_args(argv)
    if args.quick:
        args.scenes, args.size, args.paper_cap = 1, 96, 20
        args.sizes, args.repeat, args.no_adapters = "256", 2, True
    torch.set_num_threads(max(1, args.threads))
    devices = _devices()
    gpu = torch.cuda.get_device_name(0) if "cuda" in devices else None
    print(f"torch {torch.__version__}, CPU threads {torch.get_num_threads()}, GPU: {gpu or NO_GPU}")
    presets = {"fast": _preset("fast", 0), "paper": _preset("paper", args.paper_cap)}
    if args.quick:
        presets = {k: replace(v, render_size=min(v.render_size, args.size))
                   for k, v in presets.items()}  # fmt: skip
    report = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "threads": torch.get_num_threads(),
        "gpu": gpu,
        "args": vars(args),
        "optimizer": bench_optimizer(_scenes(args.scenes, args.size), presets, devices),
        "renderer": bench_renderer(
            [int(s) for s in args.sizes.split(",")], args.repeat, args.compile
        ),
        "adapters": [] if args.no_adapters else bench_adapters(args.repeat),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
