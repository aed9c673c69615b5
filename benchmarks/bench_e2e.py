"""Photo to result folder, end to end: CPU and wall seconds per step, one process per photo.

Each photo runs in a fresh Python process (a cold start: imports, compiled-kernel cache loads
and the hand model included), with one torch thread, the ``fast`` preset and the default
backends, writing the whole result folder. The child times every step with the process CPU
clock and the wall clock:

* ``imports``: interpreter start-up and every import a reconstruction needs (torch included);
* ``decode``: reading the photo; ``perception``: hand, masks, inpainting, amodal mask, object;
* the optimizer's steps: ``setup`` (scene), ``initial`` (first camera), ``hand placement``
  (every placement of the estimator's hand), the ``camera``, ``contact`` and ``refine`` stages,
  ``plausibility``;
* ``outputs``: meshes, JSON, the five pictures and the report.

The optimizer's steps are timed by wrapping the functions :mod:`easyhoi.optim.run` calls
(missing names are skipped, so the script also measures other versions of the package: point
``--src`` at their ``src`` folder). The process's whole CPU time comes from the operating system
(``getrusage`` of the waited-for child), so it includes what the step clocks miss (the
process's exit, done as the ``easyhoi`` command does it where the package has
``easyhoi.cli.fast_exit``).

The package's modules are compiled to bytecode first (``compileall``), as ``pip install`` does
for an installed package and as Python does at a package's first import: a user's cold start
reads them from the cache. Without it, a process started with ``PYTHONDONTWRITEBYTECODE`` set
(as on some development machines) compiles the package's hundred-odd modules from source in
every run, about 0.3 s of CPU.

The machine may be shared: CPU time is the primary figure (wall time grows with the load); the
load average is recorded at the start and the end. Photos where perception finds no held object
(or no hand) are reported as such and left out of the medians.

With ``--warm`` all photos run one after the other in one process (as ``easyhoi reconstruct
a.jpg b.jpg ...`` does): the rows are then each photo's CPU and wall seconds inside that
process, and the medians leave out the first photo (which carries the start-up).

With ``--compare OTHER_SRC`` every photo runs cold in both versions, one right after the
other (the order alternating from photo to photo), so that both see the same load: on a
shared machine the CPU seconds of a process grow with the load (shared caches and cores), and
versions measured minutes apart differ by more than the change being measured. Both tables and
the per-photo ratio are written.

Usage::

    python benchmarks/bench_e2e.py                          # the photos of shared/data/images
    python benchmarks/bench_e2e.py --warm                   # all of them in one process
    python benchmarks/bench_e2e.py --photos a.jpg b.png --out /tmp/e2e
    python benchmarks/bench_e2e.py --src /path/to/other/checkout/src   # another version
    python benchmarks/bench_e2e.py --compare /path/to/other/checkout/src  # both, interleaved

Results: a markdown table on stdout, ``benchmarks/results/bench_e2e.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
#: The shared photos, next to the checkout (as tests/conftest.py finds them).
DEFAULT_PHOTOS = Path(__file__).resolve().parents[2] / "shared" / "data" / "images"

#: Steps in table order (optimizer steps between perception and outputs).
STEPS = ("imports", "decode", "perception", "setup", "initial", "hand placement", "camera",
         "contact", "refine", "plausibility", "outputs")  # fmt: skip

_CHILD = r"""
import json, sys, time
_c0, _w0 = time.process_time(), time.perf_counter()
import torch
torch.set_num_threads(1)
from easyhoi.errors import NoHandError, NoObjectError
from easyhoi.io.image import load_image
from easyhoi.optim import run as optim_run
from easyhoi.optim.run import optimize
from easyhoi.perception.chain import perceive
from easyhoi.result_folder import write_result_folder
from easyhoi.settings import resolve_run
from easyhoi.config import get_preset

steps = {}

def add(name, cpu, wall):
    c, w = steps.get(name, (0.0, 0.0))
    steps[name] = (c + cpu, w + wall)

def timed(name, fn):
    def inner(*a, **k):
        c, w = time.process_time(), time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            add(name, time.process_time() - c, time.perf_counter() - w)
    return inner

for name, attr in (("initial", "initial_camera"), ("hand placement", "_place_hand"),
                   ("camera", "fit_camera"), ("contact", "fit_contact"),
                   ("refine", "fit_refine"), ("plausibility", "plausibility")):
    if hasattr(optim_run, attr):
        setattr(optim_run, attr, timed(name, getattr(optim_run, attr)))
if hasattr(optim_run, "Scene"):
    optim_run.Scene.from_input = timed("setup", optim_run.Scene.from_input)

out_dir, photos = sys.argv[1], sys.argv[2:]
run = resolve_run(get_preset("fast"))
add("imports", time.process_time(), time.perf_counter() - _w0)
records = []
mark_c, mark_w = 0.0, _w0
for photo in photos:
    status = "ok"
    try:
        image = timed("decode", load_image)(photo)
        inp, _ = timed("perception", perceive)(image.rgb, run)
        result = optimize(inp, run.config.optim, hand_model=run.hand_model)
        folder = out_dir + "/" + photo.rsplit("/", 1)[-1].rsplit(".", 1)[0]
        timed("outputs", write_result_folder)(result, inp, folder, hand_model=run.hand_model)
    except (NoHandError, NoObjectError) as exc:
        status = f"{type(exc).__name__}: {exc}"
    now_c, now_w = time.process_time(), time.perf_counter()
    records.append({"status": status, "steps": steps, "cpu": now_c - mark_c,
                    "wall": now_w - mark_w, "dynamo": "torch._dynamo" in sys.modules})
    mark_c, mark_w = now_c, now_w
    steps = {}
print(json.dumps(records))
try:
    from easyhoi.cli import fast_exit  # ends the process as the easyhoi command does
except ImportError:
    sys.exit(0)
fast_exit(0)
"""


def run_child(photos: list[Path], out: Path, src: Path | None) -> tuple[list[dict], float, float]:
    """Reconstruct ``photos`` one after the other in one fresh process.

    Returns the child's record per photo (its steps, and the CPU and wall seconds since the
    previous photo ended: the first photo's include the start-up), the whole process's CPU
    seconds (from the operating system) and its wall seconds.
    """
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1",
               EASYHOI_TORCH_THREADS="1")  # fmt: skip
    if src is not None:
        env["PYTHONPATH"] = str(src)
    t0 = time.perf_counter()
    before = _children_cpu()
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(out), *map(str, photos)],
                          capture_output=True, env=env)  # fmt: skip
    wall = time.perf_counter() - t0
    cpu = _children_cpu() - before  # run() waited for the child: its CPU joined RUSAGE_CHILDREN
    if proc.returncode:
        failed = {"status": f"failed: {proc.stderr.decode()[-300:]}", "steps": {}}
        return [dict(failed, photo=p.name) for p in photos], cpu, wall
    records = json.loads(proc.stdout.decode().strip().splitlines()[-1])
    for rec, photo in zip(records, photos, strict=True):
        rec["photo"] = photo.name
    return records, cpu, wall


def compile_package(src: Path | None) -> None:
    """Compile the measured package's modules to bytecode (``src``, or the installed one), as
    an installed package has them; their ``__pycache__`` folders are git-ignored."""
    import compileall

    if src is None:
        import importlib.util

        spec = importlib.util.find_spec("easyhoi")
        if spec is None or spec.origin is None:
            return
        folder = Path(spec.origin).parent
    else:
        folder = Path(src) / "easyhoi"
    if folder.is_dir():
        compileall.compile_dir(str(folder), quiet=1)


def _children_cpu() -> float:
    """User + system seconds of every child process waited for so far."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def measure(photos: list[Path], out: Path, src: Path | None, warm: bool) -> list[dict]:
    """Cold: one process per photo, whose whole CPU and wall time are the photo's. Warm: one
    process for all photos, each photo's CPU and wall time measured inside it."""
    if warm:
        rows, cpu, wall = run_child(photos, out, src)
        for r in rows:
            r["process_cpu"], r["process_wall"] = r.get("cpu", 0.0), r.get("wall", 0.0)
        rows[0]["first"] = True  # carries the start-up: left out of the medians
        print(f"one process: CPU {cpu:.2f} s, wall {wall:.1f} s", file=sys.stderr)
        return rows
    rows = []
    for photo in photos:
        (rec,), cpu, wall = run_child([photo], out, src)
        rec["process_cpu"], rec["process_wall"] = cpu, wall
        rows.append(rec)
        print(f"{photo.name}: {rec['status']}, CPU {cpu:.2f} s", file=sys.stderr)
    return rows


def compare(photos: list[Path], out: Path, src: Path | None, other: Path) -> tuple[list, list]:
    """Each photo cold in this version (``src``) and in ``other``, back to back, alternating
    which runs first. Returns the rows of this version and of the other."""
    mine, theirs = [], []
    for i, photo in enumerate(photos):
        order = [(src, mine, "this"), (other, theirs, "other")]
        for path, rows, name in order if i % 2 == 0 else order[::-1]:
            (rec,), cpu, wall = run_child([photo], out / name, path)
            rec["process_cpu"], rec["process_wall"] = cpu, wall
            rows.append(rec)
            print(f"{photo.name} ({name}): {rec['status']}, CPU {cpu:.2f} s", file=sys.stderr)
    return mine, theirs


def ratio_table(mine: list[dict], theirs: list[dict], label: str, other: Path) -> str:
    """Per-photo CPU seconds of both versions and their ratio, with the medians."""
    head = f"CPU seconds per photo, this version ({label}) against {other}, back to back"
    lines = [head, "", "| photo | this | other | this / other |", "|---|---|---|---|"]
    pairs = [(a, b) for a, b in zip(mine, theirs, strict=True)
             if a.get("status") == "ok" and b.get("status") == "ok"]  # fmt: skip
    for a, b in pairs:
        ca, cb = a["process_cpu"], b["process_cpu"]
        lines.append(f"| {a['photo']} | {ca:.2f} | {cb:.2f} | {ca / cb:.3f} |")
    if pairs:
        ma = statistics.median(a["process_cpu"] for a, _ in pairs)
        mb = statistics.median(b["process_cpu"] for _, b in pairs)
        mr = statistics.median(a["process_cpu"] / b["process_cpu"] for a, b in pairs)
        lines.append(f"| **median** | **{ma:.2f}** | **{mb:.2f}** | **{mr:.3f}** |")
    return "\n".join(lines) + "\n"


def _other(rec: dict) -> float:
    return rec["process_cpu"] - sum(c for c, _ in rec["steps"].values())


def table(rows: list[dict], load: tuple, header: str) -> str:
    ok = [r for r in rows if r.get("status") == "ok"]
    loads = f"Load average (1, 5, 15 min) at the start {load[0]}, at the end {load[1]}."
    lines = [header, "", loads, ""]
    cols = ["photo", "CPU s", "wall s", *STEPS, "other"]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for r in [r for r in rows if r.get("status") == "ok"]:
        name = r["photo"] + (" (first)" if r.get("first") else "")
        cells = [name, f"{r['process_cpu']:.2f}", f"{r['process_wall']:.1f}"]
        cells += [f"{r['steps'][s][0]:.2f}" if s in r["steps"] else "-" for s in STEPS]
        cells.append(f"{_other(r):.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    ok = [r for r in ok if not r.get("first")]
    if ok:
        med = [statistics.median(r["process_cpu"] for r in ok),
               statistics.median(r["process_wall"] for r in ok)]  # fmt: skip
        cells = ["**median**", f"**{med[0]:.2f}**", f"{med[1]:.1f}"]
        for s in STEPS:
            vals = [r["steps"][s][0] for r in ok if s in r["steps"]]
            cells.append(f"{statistics.median(vals):.2f}" if vals else "-")
        cells.append(f"{statistics.median(_other(r) for r in ok):.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    if any(r.get("first") for r in rows):
        lines.append("One process for all photos: each row is the CPU and wall time since the "
                     "previous photo ended; the first photo's (start-up and imports included) "
                     "is left out of the medians.")  # fmt: skip
    lines.append("Step columns are CPU seconds of the process (wall seconds in the JSON); "
                 "'other' is the process's CPU outside the timed steps (the optimizer's "
                 "bookkeeping between stages, interpreter exit).")  # fmt: skip
    for r in rows:
        if r.get("status") != "ok":
            lines.append(f"- {r['photo']}: not reconstructed ({r['status'][:160]})")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photos", nargs="*", type=Path, default=None,
                    help="photos (default: every photo of shared/data/images)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=None, help="result folders (default: temp)")
    ap.add_argument("--src", type=Path, default=None,
                    help="the package's src folder to measure (default: as installed)")  # fmt: skip
    ap.add_argument("--label", default="", help="name of this measurement in the outputs")
    warm_help = "all photos in one process (the first one carries the start-up)"
    ap.add_argument("--warm", action="store_true", help=warm_help)
    cmp_help = "also run another version's src folder, photo by photo, interleaved"
    ap.add_argument("--compare", type=Path, default=None, metavar="OTHER_SRC", help=cmp_help)
    args = ap.parse_args(argv)
    if args.compare is not None and args.warm:
        ap.error("--compare measures cold processes; leave out --warm")
    photos = args.photos
    if photos is None:
        photos = sorted(p for p in DEFAULT_PHOTOS.iterdir() if p.suffix.lower() in
                        (".jpg", ".jpeg", ".png", ".webp"))  # fmt: skip
    for src in (args.src, args.compare) if args.compare is not None else (args.src,):
        compile_package(src)
    load0 = tuple(round(x, 2) for x in os.getloadavg())
    theirs = None
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        if args.compare is not None:
            rows, theirs = compare(photos, out, args.src, args.compare)
        else:
            rows = measure(photos, out, args.src, args.warm)
    load1 = tuple(round(x, 2) for x in os.getloadavg())
    label = args.label or "easyhoi"
    how = "all photos in one process" if args.warm else "one process per photo"
    header = (f"End to end, fast preset, 1 torch thread, {how} ({label}; "
              f"{platform.machine()}, {os.cpu_count()} cores, "
              f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})")  # fmt: skip
    md = table(rows, (load0, load1), header)
    if theirs is not None:
        md += "\n" + table(theirs, (load0, load1), f"The other version ({args.compare})")
        md += "\n" + ratio_table(rows, theirs, label, args.compare)
    print(md)
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "bench_e2e" + (f"_{args.label}" if args.label else "")
    (RESULTS / f"{stem}.md").write_text(md)
    doc = {"rows": rows, "load_start": load0, "load_end": load1, "label": label}
    if theirs is not None:
        doc["other_rows"], doc["other_src"] = theirs, str(args.compare)
    (RESULTS / f"{stem}.json").write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
