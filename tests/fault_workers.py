"""Workers and a batch runner for the fault-injection tests (importable by worker processes).

``python -m tests.fault_workers PHOTOS OUT LOG DELAY WORKERS`` runs a local-engine batch of
:class:`SlowWorker` so that a test can kill it at a chosen point.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from easyhoi.batch import run_batch, summarize_photo
from easyhoi.distributed import Task


def _log(path: str, line: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (line + "\n").encode())
    finally:
        os.close(fd)


class SlowWorker:
    """summarize_photo after ``delay`` seconds; logs ``start KEY PID`` and ``done KEY PID``."""

    def __init__(self, log: str, delay: float = 0.0):
        self.log, self.delay = log, delay

    def __call__(self, task: Task) -> dict:
        _log(self.log, f"start {task.key} {os.getpid()}")
        time.sleep(self.delay)
        info = summarize_photo(task)
        _log(self.log, f"done {task.key} {os.getpid()}")
        return info


def log_lines(path: Path, kind: str) -> list[str]:
    """Keys of the ``kind`` ("start" or "done") lines of a log."""
    if not path.exists():
        return []
    return [ln.split()[1] for ln in path.read_text().splitlines() if ln.startswith(kind + " ")]


def main(argv: list[str]) -> int:
    photos, out, log, delay, workers = argv
    images = sorted(Path(photos).iterdir())
    summary = run_batch(images, out, SlowWorker(log, float(delay)), engine="local",
                        workers=int(workers), root=photos)  # fmt: skip
    return summary.exit_code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
