"""Batch throughput on real photos: ``easyhoi batch --workers 1`` against ``--workers 2``.

Both runs happen in one invocation of this script, one after the other, on the same photos:
each is the ``easyhoi batch`` command itself (a fresh process with its local process pool,
the ``fast`` preset, one torch thread per worker), so the wall time includes everything a user
waits for: start-up, every worker's imports and first-use costs, all outputs. The figure of
merit is photos per minute (photos / wall time); the ratio of the two runs is the speed-up of
the second worker.

The photos are copied into a temporary folder (a batch refuses links that lead out of its
folder). By default they are 12 shared photos that reach a result: the 6 of
``shared/data/images`` where perception found a held object when this script was written and
the first 6 ``ihoi-demo`` frames of ``shared/data/photos-dev``.

Each worker records the CPU seconds of every photo in the manifest (``info.cpu_seconds``; the
first photo of a worker process carries its imports); their sum is printed with the wall time.
The machine's load average is printed before and after each run: on a shared machine the
ratio depends on it, and on a kernel that schedules by session (``sched_autogroup_enabled``,
the default of many distributions) all processes of the batch share one session's part of
the CPU, so that with other sessions busy two workers get no more CPU than one. Compare
ratios measured on an otherwise idle machine. Both runs must produce the same meshes (same
seeds): the script compares ``hand.ply`` and ``object.ply`` byte for byte.

Usage::

    python benchmarks/bench_batch_e2e.py                     # 12 photos, workers 1 then 2
    python benchmarks/bench_batch_e2e.py --photos a.jpg b.jpg c.png --workers 1 2

Results: a table on stdout and ``benchmarks/results/bench_batch_e2e.{md,json}``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

#: Photos of the shared data that reach a result (the others stop with NoObjectError).
DEFAULT_PHOTOS = (
    "images/easyhoi-airplane.jpg",
    "images/easyhoi-coffee-1.png",
    "images/easyhoi-coffee-2.jpg",
    "images/easyhoi-game-controller.jpg",
    "images/hort-can.png",
    "images/hort-phone.png",
    "photos-dev/ihoi-demo_01.jpg",
    "photos-dev/ihoi-demo_02.jpg",
    "photos-dev/ihoi-demo_03.jpg",
    "photos-dev/ihoi-demo_04.jpg",
    "photos-dev/ihoi-demo_05.jpg",
    "photos-dev/ihoi-demo_06.jpg",
)


def _load() -> tuple[float, float, float]:
    return tuple(round(x, 2) for x in os.getloadavg())


def run_batch_command(folder: Path, out: Path, workers: int, src: Path | None) -> dict:
    """Run ``easyhoi batch folder --out out --workers N``; wall time, load, manifest lines."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    if src is not None:
        env["PYTHONPATH"] = str(src)
    cmd = [sys.executable, "-m", "easyhoi.cli", "batch", str(folder), "--out", str(out),
           "--workers", str(workers), "--quiet"]  # fmt: skip
    load0 = _load()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, env=env)
    wall = time.perf_counter() - t0
    load1 = _load()
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines() if x]
    ok = [x for x in lines if x["status"] == "ok"]
    cpu = [x["info"].get("cpu_seconds") for x in ok]
    return {
        "workers": workers,
        "exit_code": proc.returncode,
        "ok": len(ok),
        "failed": [f"{x['path']}: {x['error_type']}" for x in lines if x["status"] != "ok"],
        "wall_s": round(wall, 2),
        "photos_per_min": round(60 * len(ok) / wall, 2),
        "worker_cpu_s": round(sum(c for c in cpu if c is not None), 2),
        "photo_wall_s": {x["path"]: x["seconds"] for x in ok},
        "photo_cpu_s": {x["path"]: x["info"].get("cpu_seconds") for x in ok},
        "load_start": load0,
        "load_end": load1,
        "stderr_tail": proc.stderr.decode(errors="replace")[-400:] if proc.returncode else "",
    }


def mesh_digests(out: Path) -> dict[str, str]:
    """sha256 of every result's ``hand.ply`` and ``object.ply``, by relative path."""
    return {
        p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()[:16]
        for name in ("hand.ply", "object.ply")
        for p in sorted(out.rglob(name))
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photos", nargs="*", type=Path, default=None,
                    help="photos (default: the 12 shared photos that reach a result)")  # fmt: skip
    ap.add_argument("--workers", nargs="+", type=int, default=[1, 2], help="runs, in order")
    ap.add_argument("--src", type=Path, default=None,
                    help="the package's src folder to measure (default: as installed)")  # fmt: skip
    args = ap.parse_args(argv)
    photos = args.photos or [SHARED / p for p in DEFAULT_PHOTOS]
    missing = [str(p) for p in photos if not Path(p).is_file()]
    if missing:
        print(f"missing photos: {', '.join(missing)}", file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "photos"
        folder.mkdir()
        for p in photos:
            shutil.copyfile(p, folder / Path(p).name)
        digests = {}
        for n in args.workers:
            out = Path(tmp) / f"out-w{n}-{len(rows)}"
            row = run_batch_command(folder, out, n, args.src)
            digests[len(rows)] = mesh_digests(out)
            rows.append(row)
            brief = {k: v for k, v in row.items() if not k.startswith("photo_")}
            print(json.dumps(brief), file=sys.stderr)
    same = all(d == digests[0] for d in digests.values())
    base = rows[0]["photos_per_min"]
    lines = [
        f"easyhoi batch, fast preset, one torch thread per worker, {len(photos)} photos "
        f"({platform.machine()}, {os.cpu_count()} cores, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})",
        "",
        "| workers | photos ok | wall s | photos / min | ratio to the first run | "
        "worker CPU s (sum) | load at start (1, 5, 15 min) | load at end |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = r["photos_per_min"] / base if base else float("nan")
        lines.append(
            f"| {r['workers']} | {r['ok']} | {r['wall_s']:.1f} | {r['photos_per_min']:.2f} | "
            f"{ratio:.2f} | {r['worker_cpu_s']:.1f} | {r['load_start']} | {r['load_end']} |"
        )
    lines += ["", f"Same meshes (hand.ply, object.ply) in every run: {same}."]
    for r in rows:
        if r["failed"] or r["exit_code"]:
            lines.append(f"- workers {r['workers']}: exit {r['exit_code']}, failed {r['failed']}")
    md = "\n".join(lines) + "\n"
    print(md)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "bench_batch_e2e.md").write_text(md)
    doc = {"rows": rows, "same_meshes": same, "photos": [str(p) for p in photos]}
    (RESULTS / "bench_batch_e2e.json").write_text(json.dumps(doc, indent=1))
    return 0 if same and all(r["exit_code"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
