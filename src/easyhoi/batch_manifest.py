"""The batch manifest: one JSON line per photo, appended durably, and its CSV copy.

:mod:`easyhoi.batch` describes the fields and when lines are written. Here: the record of one
photo (:class:`ItemRecord`), the append-only writer that keeps ``manifest.jsonl`` valid JSONL
through a crash or a full disk (:class:`ManifestWriter`), reading it back
(:func:`read_manifest`) and the sorted CSV written at the end (:func:`write_manifest_csv`).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import logging
import os
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

from easyhoi.distributed import Task, TaskResult

logger = logging.getLogger("easyhoi.batch")

MANIFEST_JSONL = "manifest.jsonl"
MANIFEST_CSV = "manifest.csv"

_CSV_FIELDS = ("path", "status", "error_type", "error", "exit_code", "internal", "seconds",
               "output", "seed", "image")  # fmt: skip


@dataclass(frozen=True)
class ItemRecord:
    """One manifest line (its fields: the module docstring of :mod:`easyhoi.batch`)."""

    path: str
    image: str
    status: str
    error_type: str | None
    error: str | None
    exit_code: int
    internal: bool
    seconds: float
    output: str
    seed: int
    info: dict

    def to_dict(self) -> dict:
        """The JSON object written to ``manifest.jsonl``."""
        return asdict(self)

    @classmethod
    def from_result(cls, task: Task, result: TaskResult, out_dir: Path) -> ItemRecord:
        """Combine a task and its outcome."""
        return cls(
            path=task.key, image=task.image, status=result.status, error_type=result.error_type,
            error=result.error, exit_code=int(result.exit_code), internal=bool(result.internal),
            seconds=round(float(result.seconds), 4), output=_rel(task.output, out_dir),
            seed=task.seed, info=dict(result.info),
        )  # fmt: skip

    @classmethod
    def skipped(cls, task: Task, out_dir: Path) -> ItemRecord:
        """Record of a photo that an earlier run finished."""
        return cls(task.key, task.image, "skipped", None, None, 0, False, 0.0,
                   _rel(task.output, out_dir), task.seed, {})  # fmt: skip

    @classmethod
    def recovered(cls, task: Task, out_dir: Path) -> ItemRecord:
        """Record of a photo whose result folder exists but had no manifest line (resume)."""
        note = "result folder found without a manifest line (its run was killed); kept"
        return cls(task.key, task.image, "ok", None, None, 0, False, 0.0,
                   _rel(task.output, out_dir), task.seed, {"recovered": note})  # fmt: skip


def _rel(path: str | Path, base: Path) -> str:
    return Path(os.path.relpath(Path(path), base)).as_posix()


class ManifestWriter:
    """Append-only JSONL writer: each line is one ``os.write`` then ``fsync``.

    Opening an existing file (``fresh=False``) first drops a partial last line left by a crash,
    so the file stays valid JSONL.
    """

    def __init__(self, path: str | Path, fresh: bool = True):
        self.path = Path(path)
        if fresh or not self.path.exists():
            from easyhoi.io.atomic import atomic_write_bytes

            atomic_write_bytes(self.path, b"")
        else:
            _drop_partial_line(self.path)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def append(self, record: dict) -> None:
        """Write one JSON object as one line and make it durable."""
        data = (json.dumps(record, ensure_ascii=False, sort_keys=True) + "\n").encode("utf-8")
        end = os.lseek(self._fd, 0, os.SEEK_END)
        try:
            view = memoryview(data)
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
            os.fsync(self._fd)
        except BaseException:  # a full disk mid-line: cut the partial line off again
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, end)
            raise

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> ManifestWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _drop_partial_line(path: Path) -> None:
    size = path.stat().st_size
    if size == 0:
        return
    with open(path, "rb+") as f:
        f.seek(size - 1)
        if f.read(1) == b"\n":
            return
        f.seek(0)
        data = f.read()
        keep = data.rfind(b"\n") + 1
        logger.warning("dropping a partial last line of %s (%d bytes)", path, len(data) - keep)
        f.truncate(keep)
        f.flush()
        os.fsync(f.fileno())


def read_manifest(path: str | Path) -> list[dict]:
    """All valid lines of a ``manifest.jsonl`` (unreadable lines are skipped with a warning).

    Returns an empty list when the file does not exist.
    """
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            logger.warning("%s line %d is not JSON; ignored", path, i)
            continue
        if isinstance(rec, dict) and "path" in rec and "status" in rec:
            out.append(rec)
    return out


def latest_outcomes(records: list[dict]) -> dict[str, dict]:
    """Latest ok/failed record per path (``skipped`` lines carry no new outcome)."""
    latest: dict[str, dict] = {}
    for rec in records:
        if rec.get("status") in ("ok", "failed"):
            latest[rec["path"]] = rec
    return latest


def write_manifest_csv(path: str | Path, records: Iterable[ItemRecord]) -> Path:
    """Write ``records`` (sorted by path) as CSV atomically."""
    from easyhoi.io.atomic import atomic_write_text

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=_CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for rec in sorted(records, key=lambda r: r.path):
        w.writerow(rec.to_dict())
    return atomic_write_text(path, buf.getvalue())
