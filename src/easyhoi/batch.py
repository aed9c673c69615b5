"""Many photos: discovery, per-photo output folders, a crash-safe manifest, and resume.

``run_batch(discover_images("photos"), "out", worker)`` runs ``worker`` once per photo (see
:mod:`easyhoi.distributed` for the engines) and records every outcome in ``out/manifest.jsonl``,
one JSON object per line, appended and fsync'ed as each photo finishes, so a killed batch leaves
a valid file (:mod:`easyhoi.batch_manifest` writes and reads it). The fields of a line::

    path        photo name inside the batch (relative POSIX path; the resume key)
    image       the photo file as given
    status      "ok" | "failed" | "skipped" (resume: finished by an earlier run)
    error_type  exception class name ("WorkerDied" when the process died), null when ok
    error       exception message, null when ok
    exit_code   0 ok; the EasyHOIError's exit code (2 invalid input, 5 no hand...); 70 internal
    internal    true when the failure was not an EasyHOIError (a bug or a crash)
    seconds     worker wall time
    output      the photo's output folder, relative to the batch output folder
    seed        the photo's seed: derived from the batch seed and ``path`` (see :func:`item_seed`)
    info        what the worker returned (small, JSON)

``manifest.csv`` (the same fields but ``info``, sorted by ``path``) is written at the end. A run
without ``resume`` starts a new manifest; with ``resume`` a photo is skipped when its latest ok
or failed line says ok *and* its output folder exists, redone when its folder vanished, and
recorded as ok (``info.recovered``) without running when its folder exists but no line names it
(a run killed between the two). One run at a time holds the output folder (``wait`` queues
behind another), and the temporaries of a killed run are swept first (:mod:`easyhoi.batch_lock`).

Output folders mirror the input tree: ``photos/a/IMG_1.jpg`` -> ``out/a/IMG_1/``. Photos of one
folder that share a stem (``x.jpg``, ``x.png``) get the extension appended (``x_jpg``, ``x_png``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from easyhoi.batch_manifest import (
    MANIFEST_CSV,
    MANIFEST_JSONL,
    ItemRecord,
    ManifestWriter,
    latest_outcomes,
    read_manifest,
    write_manifest_csv,
)
from easyhoi.distributed import Task, execute
from easyhoi.errors import ExitCode, InvalidInputError

__all__ = [
    "IMAGE_EXTENSIONS",
    "MANIFEST_CSV",
    "MANIFEST_JSONL",
    "BatchSummary",
    "ItemRecord",
    "ReconstructWorker",
    "discover_images",
    "item_seed",
    "plan_tasks",
    "read_manifest",
    "run_batch",
    "sniff_image_format",
    "summarize_photo",
]

logger = logging.getLogger(__name__)

#: Extensions taken as photos without looking inside (a corrupt one then fails in its worker).
IMAGE_EXTENSIONS = frozenset(
    {".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".webp", ".bmp", ".dib", ".tif", ".tiff", ".gif",
     ".ppm", ".pgm", ".pbm", ".pnm"}
)  # fmt: skip

#: Extensions never taken as photos (results, meshes, notes), not even opened.
OTHER_EXTENSIONS = frozenset(
    {".json", ".jsonl", ".csv", ".txt", ".md", ".html", ".htm", ".ply", ".obj", ".glb", ".gltf",
     ".stl", ".npz", ".npy", ".pkl", ".pt", ".pth", ".py", ".log", ".yaml", ".yml", ".toml",
     ".xml", ".zip", ".tar", ".gz", ".mp4", ".mov", ".avi", ".pdf", ".tmp"}
)  # fmt: skip

_RESERVED = {MANIFEST_JSONL, MANIFEST_CSV}


# ----------------------------------------------------------------------------------------------
# discovery
# ----------------------------------------------------------------------------------------------


def sniff_image_format(path: str | Path) -> str | None:
    """Image container format from a file's first bytes (``"JPEG"``, ``"PNG"``...), or None."""
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    if head.startswith(b"\xff\xd8\xff"):
        return "JPEG"
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "PNG"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WEBP"
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return "GIF"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "TIFF"
    if head[:2] == b"BM" and len(head) >= 14:
        return "BMP"
    if len(head) >= 3 and head[:1] == b"P" and head[1:2] in b"123456" and head[2:3].isspace():
        return "PNM"
    return None


def _is_photo(path: Path) -> bool:
    ext = path.suffix.lower()
    if ext in IMAGE_EXTENSIONS:
        return True
    if ext in OTHER_EXTENSIONS:
        return False
    return sniff_image_format(path) is not None  # no or unknown extension: decide by content


def discover_images(
    folder: str | Path, recursive: bool = False, exclude: Iterable[str | Path] = ()
) -> list[Path]:
    """Photos in a folder, sorted by their path relative to it.

    A file is taken when its extension is a photo extension (:data:`IMAGE_EXTENSIONS`, any
    case; such a file is taken even when empty or corrupt, so that the batch records it as
    failed), or when its extension is neither that nor a known other kind and its first bytes
    are an image signature (``scan_0001``, ``photo.image``). Hidden files and folders (leading
    ``.``) and the manifests are ignored.

    Args:
        folder (str or Path): Folder to scan.
        recursive (bool): Also scan subfolders (symbolic links to folders are not followed).
        exclude (iterable of path-like): Folders to leave out (for example the batch output folder
            when it lies inside).

    Returns:
        list of Path: Sorted by relative POSIX path (deterministic across runs and file systems).

    Raises:
        InvalidInputError: ``folder`` does not exist or is not a folder.
    """
    root = Path(folder)
    if not root.exists():
        raise InvalidInputError(f"photo folder not found: {root}")
    if not root.is_dir():
        raise InvalidInputError(f"not a folder: {root}")
    skip = {Path(p).resolve() for p in exclude}
    found: list[tuple[str, Path]] = []
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = sorted(
            d for d in dirnames if not d.startswith(".") and (here / d).resolve() not in skip
        )
        if not recursive:
            dirnames[:] = []
        for name in filenames:
            p = here / name
            if name.startswith(".") or name in _RESERVED or not p.is_file():
                continue
            if _is_photo(p):
                found.append((p.relative_to(root).as_posix(), p))
    return [p for _, p in sorted(found)]


# ----------------------------------------------------------------------------------------------
# planning
# ----------------------------------------------------------------------------------------------


def item_seed(batch_seed: int, key: str) -> int:
    """Seed of one photo: a hash of the batch seed and the photo's batch name, in [0, 2**31).

    Independent of the engine, the worker count and the order the photos run in.
    """
    digest = hashlib.sha256(f"{int(batch_seed)}\0{key}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def _folder_names(keys: Sequence[str]) -> dict[str, str]:
    """Output folder (relative POSIX path) of each key; collisions resolved deterministically."""

    def plain(key: str) -> str:
        p = Path(key)
        return (p.parent / (p.stem or p.name)).as_posix()

    def with_ext(key: str) -> str:
        p = Path(key)
        ext = p.suffix[1:].lower() or "noext"
        return (p.parent / f"{p.stem}_{ext}").as_posix()

    names = {k: plain(k) for k in keys}
    for attempt in (with_ext, None):
        counts: dict[str, int] = {}
        for n in names.values():
            counts[n.lower()] = counts.get(n.lower(), 0) + 1  # case-insensitive file systems
        clash = [k for k, n in names.items() if counts[n.lower()] > 1]
        if not clash:
            break
        for k in clash:
            if attempt is not None:
                names[k] = attempt(k)
            else:
                names[k] = f"{names[k]}-{hashlib.sha1(k.encode()).hexdigest()[:8]}"
    for k, n in names.items():
        if n in _RESERVED:
            names[k] = f"{n}_photo"
    return names


def plan_tasks(
    images: Sequence[str | Path], out_dir: str | Path, seed: int = 0, root: str | Path | None = None
) -> list[Task]:
    """One :class:`~easyhoi.distributed.Task` per photo, sorted by key.

    Args:
        images (sequence of path-like): Photo files (duplicates are dropped).
        out_dir (path-like): Batch output folder.
        seed (int): Batch seed; each photo gets :func:`item_seed` ``(seed, key)``.
        root (path-like or None): Folder the keys are relative to (None: the deepest folder
            containing every photo).

    Returns:
        list of Task
    """
    paths = []
    seen = set()
    for p in images:
        r = Path(p).resolve()
        if r not in seen:
            seen.add(r)
            # names come from the path as given (absolute, symbolic links kept): a folder of
            # links to photos elsewhere names them by their place in the folder
            paths.append((Path(p), r, Path(os.path.abspath(p))))
    if not paths:
        return []
    if root is None:
        base = Path(os.path.commonpath([str(a.parent) for _, _, a in paths]))
        base_r = Path(os.path.commonpath([str(r.parent) for _, r, _ in paths]))
    else:
        base, base_r = Path(os.path.abspath(root)), Path(root).resolve()
    keys = {}
    for given, r, a in paths:
        try:
            key = a.relative_to(base)
        except ValueError:
            try:  # the same photo reached through a link to one of its folders
                key = r.relative_to(base_r)
            except ValueError as exc:
                raise InvalidInputError(
                    f"photo {given} is not inside the batch root {base}"
                ) from exc
        keys[key.as_posix()] = given
    folders = _folder_names(sorted(keys))
    out = Path(out_dir)
    return [
        Task(key=k, image=str(keys[k]), output=str(out / folders[k]), seed=item_seed(seed, k))
        for k in sorted(keys)
    ]


# ----------------------------------------------------------------------------------------------
# manifest
# ----------------------------------------------------------------------------------------------


def _lock_and_sweep(out: Path, outputs: list[str], wait: bool):
    """Take ``out``'s lock, refuse links in the output paths, sweep a killed run's temporaries."""
    from easyhoi.batch_lock import OutputLock, check_no_links, sweep_temporaries

    lock = OutputLock(out, wait=wait).acquire()
    try:
        check_no_links(out, [*outputs, out / MANIFEST_JSONL, out / MANIFEST_CSV])
        sweep_temporaries(out)
    except BaseException:
        lock.release()
        raise
    return lock


def _has_files(folder: str | Path) -> bool:
    """Whether ``folder`` is a folder holding anything (result folders appear only complete)."""
    p = Path(folder)
    return p.is_dir() and not p.is_symlink() and any(p.iterdir())


# ----------------------------------------------------------------------------------------------
# running
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchSummary:
    """Outcome of :func:`run_batch`.

    Attributes:
        records (tuple of ItemRecord): One per photo of this batch, sorted by path (photos not
            reached when interrupted are absent).
        seconds (float): Wall time of the batch.
        manifest (Path): ``manifest.jsonl``.
        manifest_csv (Path): ``manifest.csv``.
        engine (str): Engine used.
        workers (int): Worker count used.
    """

    records: tuple[ItemRecord, ...]
    seconds: float
    manifest: Path
    manifest_csv: Path
    engine: str
    workers: int

    def count(self, status: str) -> int:
        """Number of photos with this status."""
        return sum(r.status == status for r in self.records)

    @property
    def total(self) -> int:
        """Photos recorded."""
        return len(self.records)

    @property
    def ok(self) -> int:
        """Photos processed successfully in this run."""
        return self.count("ok")

    @property
    def failed(self) -> int:
        """Photos that failed in this run."""
        return self.count("failed")

    @property
    def skipped(self) -> int:
        """Photos skipped because an earlier run finished them."""
        return self.count("skipped")

    @property
    def failures(self) -> list[ItemRecord]:
        """The failed records."""
        return [r for r in self.records if r.status == "failed"]

    @property
    def photos_per_second(self) -> float:
        """Processed (not skipped) photos per second of wall time."""
        return (self.ok + self.failed) / self.seconds if self.seconds > 0 else 0.0

    @property
    def exit_code(self) -> int:
        """``ExitCode.OK`` when nothing failed, ``ExitCode.BATCH_PARTIAL`` otherwise."""
        return ExitCode.BATCH_PARTIAL if self.failed else ExitCode.OK

    def line(self) -> str:
        """One-line human summary."""
        return (
            f"{self.total} photos: {self.ok} ok, {self.failed} failed, {self.skipped} skipped "
            f"in {self.seconds:.1f} s ({self.photos_per_second:.2f} photos/s, {self.engine} "
            f"engine, {self.workers} worker{'s' if self.workers != 1 else ''})"
        )


ProgressFn = Callable[[ItemRecord, int, int], None]


def run_batch(
    images: Sequence[str | Path],
    out_dir: str | Path,
    worker: Callable[[Task], dict | None],
    *,
    engine: str = "local",
    workers: int = 1,
    resume: bool = False,
    seed: int = 0,
    ray_address: str | None = None,
    progress: ProgressFn | None = None,
    root: str | Path | None = None,
    threads: int | None = None,
    wait: bool = False,
) -> BatchSummary:
    """Run ``worker`` on every photo; one failing photo never stops the batch.

    Args:
        images (sequence of path-like): Photo files (see :func:`discover_images`).
        out_dir (path-like): Batch output folder (created): one folder per photo plus the manifests.
        worker (callable): Picklable ``worker(task) -> dict | None`` that writes into
            ``task.output``; its exceptions are recorded, not raised (see
            :mod:`easyhoi.distributed`).
        engine ({"local", "ray", "inline"}): Executor (see :func:`easyhoi.distributed.execute`).
        workers (int): Parallel workers.
        resume (bool): Keep the existing manifest and skip photos whose latest line says ok and
            whose output folder exists (recorded as ``skipped``).
        seed (int): Batch seed; each photo's seed is :func:`item_seed` ``(seed, path)``.
        ray_address (str or None): Existing Ray cluster for ``engine="ray"`` (None: a local one).
        progress (callable or None): ``progress(record, done, total)`` after each photo (skipped
            ones included), in the calling process.
        root (path-like or None): Folder the photo names are relative to (None: the deepest common
            folder).
        threads (int or None): Torch threads per worker (None:
            :data:`easyhoi.distributed.DEFAULT_THREADS`, one).
        wait (bool): When another run holds ``out_dir`` (see :mod:`easyhoi.batch_lock`), wait for it
            instead of refusing.

    Returns:
        BatchSummary

    Raises:
        InvalidInputError: Bad engine/worker count, unpicklable worker, ``out_dir`` is a file, or an
            output path passes through a symbolic link inside ``out_dir``.
        OutputBusyError: Another run holds ``out_dir`` (and ``wait`` is off).
        MissingDependencyError: ``engine="ray"`` without Ray.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidInputError(f"batch output path exists and is not a folder: {out}")
    tasks = plan_tasks(images, out, seed=seed, root=root)
    out.mkdir(parents=True, exist_ok=True)
    manifest = out / MANIFEST_JSONL
    lock = _lock_and_sweep(out, [t.output for t in tasks], wait)
    done_before = latest_outcomes(read_manifest(manifest)) if resume else {}

    todo, skipped, recovered = [], [], []
    for t in tasks:
        prev = done_before.get(t.key)
        if prev is not None and prev["status"] == "ok" and Path(t.output).is_dir():
            if prev.get("seed") != t.seed:
                logger.warning("%s: finished with seed %s, now %s; kept", t.key, prev.get("seed"),
                               t.seed)  # fmt: skip
            skipped.append(t)
        elif resume and prev is None and _has_files(t.output):
            recovered.append(t)  # finished by a run killed before its manifest line
        else:
            todo.append(t)

    by_key = {t.key: t for t in tasks}
    records: list[ItemRecord] = []
    total = len(tasks)
    # validate engine options before touching the manifest
    try:
        results = execute(todo, worker, engine=engine, workers=workers, threads=threads,
                          ray_address=ray_address)  # fmt: skip
    except BaseException:
        lock.release()
        raise
    with ManifestWriter(manifest, fresh=not resume) as writer:
        try:
            for t in skipped:
                records.append(ItemRecord.skipped(t, out))
                writer.append(records[-1].to_dict())
                if progress is not None:
                    progress(records[-1], len(records), total)
            for t in recovered:
                records.append(ItemRecord.recovered(t, out))
                writer.append(records[-1].to_dict())
                if progress is not None:
                    progress(records[-1], len(records), total)
            for res in results:
                records.append(ItemRecord.from_result(by_key[res.key], res, out))
                writer.append(records[-1].to_dict())
                if progress is not None:
                    progress(records[-1], len(records), total)
        finally:
            if hasattr(results, "close"):
                results.close()
            write_manifest_csv(out / MANIFEST_CSV, records)
            lock.release()
    return BatchSummary(
        records=tuple(sorted(records, key=lambda r: r.path)),
        seconds=time.perf_counter() - t0,
        manifest=manifest,
        manifest_csv=out / MANIFEST_CSV,
        engine=engine,
        workers=workers,
    )


# ----------------------------------------------------------------------------------------------
# workers
# ----------------------------------------------------------------------------------------------


def summarize_photo(task: Task) -> dict:
    """A light worker: decode the photo and write ``summary.json`` into ``task.output``.

    The summary holds the detected format, the size, the mean colour, and the colour of 16
    pixels drawn with ``task.seed`` (so a wrong or order-dependent seed shows in the output).
    Useful to check a folder before a long run, and as the test and benchmark worker.

    Raises:
        InvalidInputError: Missing, empty, corrupt or too small photos (from
            :func:`easyhoi.io.image.load_image`).
    """
    import numpy as np

    from easyhoi.io.atomic import atomic_write_text, publish_folder
    from easyhoi.io.image import load_image

    img = load_image(task.image)
    h, w = img.rgb.shape[:2]
    rng = np.random.default_rng(task.seed)
    ys, xs = rng.integers(0, h, 16), rng.integers(0, w, 16)
    summary = {
        "format": img.source_format,
        "width": int(w),
        "height": int(h),
        "mean_rgb": [round(float(v), 4) for v in img.rgb.reshape(-1, 3).mean(axis=0)],
        "probe": img.rgb[ys, xs].astype(int).tolist(),
        "seed": int(task.seed),
    }
    text = json.dumps(summary, indent=1, sort_keys=True)
    publish_folder(task.output, lambda tmp: atomic_write_text(tmp / "summary.json", text))
    return {"format": summary["format"], "width": summary["width"], "height": summary["height"]}


class ReconstructWorker:
    """The batch worker of ``easyhoi batch``: :func:`easyhoi.pipeline.reconstruct_photo`.

    Args:
        settings: The run's :class:`~easyhoi.settings.RunSettings`, or a configuration they are
            resolved from once per process (None: the "fast" preset). Picklable, so the worker
            can be sent to processes and Ray tasks. Each photo runs with its task's seed.
        prompts: Batch photo name (``task.key``) -> :class:`~easyhoi.perception.prompts.Prompts`
            (see :mod:`easyhoi.batch_prompts`).
        strict: A photo with a low-confidence mask fails (``LowConfidenceError``) and writes
            nothing.
    """

    #: Imported by the local engine's fork server before it forks the worker processes
    #: (:mod:`easyhoi.distributed`): torch, the pipeline's own modules and trimesh, about 2 s
    #: of CPU that every worker would otherwise spend on its own. The native perception and
    #: kernel libraries (MediaPipe, OpenCV, numba) are imported by each worker itself, after
    #: the fork, so that no native library state is shared between processes.
    preload = (
        "torch",
        "trimesh",
        "easyhoi.pipeline",
        "easyhoi.perception.chain",
        "easyhoi.optim.run",
        "easyhoi.result_folder",
        "easyhoi.viz.report",
    )

    def __init__(self, settings=None, prompts=None, strict: bool = False):
        self.settings = settings
        self.prompts = dict(prompts or {})
        self.strict = bool(strict)

    @property
    def device(self) -> str:
        """The device the photos run on ("cpu", "cuda", ...; Ray asks for GPUs by it)."""
        from easyhoi.config import get_preset
        from easyhoi.device import resolve_device
        from easyhoi.settings import RunSettings

        if isinstance(self.settings, RunSettings):
            return self.settings.device
        cfg = get_preset() if self.settings is None else self.settings
        return resolve_device(cfg.device)

    def __call__(self, task: Task) -> dict:
        """Reconstruct one photo into ``task.output``.

        Returns timing (``seconds`` of wall time, ``cpu_seconds`` of this process's CPU time,
        first-use imports included), file count, and what the user must hear about perception:
        ``notes`` (the hand used is not the first detected) and ``warnings`` (low confidence).
        """
        from easyhoi.perception.feedback import (
            contact_line,
            hand_choice_note,
            low_confidence_lines,
        )
        from easyhoi.pipeline import reconstruct_photo
        from easyhoi.settings import RunSettings, resolve_run

        cpu0 = time.process_time()
        if not isinstance(self.settings, RunSettings):
            self.settings = resolve_run(self.settings)
        prompts = self.prompts.get(task.key)
        rec = reconstruct_photo(task.image, task.output, self.settings, seed=task.seed,
                                prompts=prompts, strict=self.strict)  # fmt: skip
        note = hand_choice_note(rec.perception)
        prompted = prompts is not None and prompts.has_object_prompt
        plaus = getattr(getattr(rec, "result", None), "plausibility", None) or {}
        apart = contact_line(plaus, "batch", prompted)
        return {
            "seconds": round(float(rec.seconds), 3), "files": len(rec.files),
            "cpu_seconds": round(time.process_time() - cpu0, 3),
            "notes": [note] if note else [],
            "warnings": low_confidence_lines(rec.perception, "batch", prompted)
            + ([apart] if apart else []),
        }  # fmt: skip
