"""Synthetic benchmark, quick mode (3 scenes; paper preset on 1 scene capped at 100 iterations).

A thin wrapper over ``easyhoi bench --quick`` (see docs/benchmark.md); extra arguments are passed
through, e.g. ``python benchmarks/bench_synth.py --scenes 20`` for the full run (drop --quick
by passing ``--full``).

Results: tables on stdout; JSON, Markdown and plots in ``benchmarks/results/synth_quick``.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    from easyhoi.cli import main as cli_main

    args = list(sys.argv[1:] if argv is None else argv)
    if "--full" in args:
        args.remove("--full")
        out = ROOT / "benchmarks" / "results" / "synth"
    else:
        args.insert(0, "--quick")
        out = ROOT / "benchmarks" / "results" / "synth_quick"
    if "--out" not in args:
        args += ["--out", str(out)]
    return cli_main(["bench", *args])


if __name__ == "__main__":
    raise SystemExit(main())
