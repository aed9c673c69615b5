"""Fault injection: killed batches, concurrent runs, full disks and hostile files.

Each case ends in the documented exit code and message (``docs/bad_input.md``), leaves nothing
half-written behind, and loses nothing: a batch killed with ``kill -9`` at any point and then
resumed has every photo done exactly once.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from easyhoi.batch import MANIFEST_JSONL, read_manifest, run_batch, summarize_photo
from easyhoi.batch_lock import LOCK_NAME, OutputLock
from easyhoi.cli import main
from easyhoi.errors import ExitCode, OutputBusyError
from tests.fault_workers import SlowWorker, log_lines

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT)])
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = "1"
    return env


def _photos(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        rng = np.random.default_rng(i)
        p = folder / f"p{i}.png"
        Image.fromarray(rng.integers(0, 256, (40, 48, 3), dtype=np.uint8)).save(p)
        out.append(p)
    return out


def _leftovers(out: Path) -> list[str]:
    """Hidden temporaries (folders or files) anywhere under ``out``."""
    return sorted(
        p.relative_to(out).as_posix()
        for p in out.rglob(".*")
        if ".tmp" in p.name or ".old-" in p.name or p.name == LOCK_NAME
    )


def _descendants(pid: int) -> set[int]:
    """Live descendants of ``pid`` (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            if c not in found:
                found.add(c)
                todo.append(c)
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def _wait_for(cond, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _kill_and_check_workers_die(proc: subprocess.Popen, timeout: float = 5.0) -> set[int]:
    kids = _descendants(proc.pid)
    assert kids, "the batch started no worker process"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    try:
        _wait_for(lambda: not any(_alive(k) for k in kids), timeout, "workers to die")
    finally:
        for k in kids:  # never leave a process behind, even when the check fails
            if _alive(k):
                os.kill(k, signal.SIGKILL)
    return kids


# ----------------------------------------------------------------------------------------------
# kill -9, then resume
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("kill_after", [1, 3, 5])
def test_kill_9_then_resume_does_every_photo_once(tmp_path, kill_after):
    photos, out, log = tmp_path / "photos", tmp_path / "out", tmp_path / "log.txt"
    images = _photos(photos, 6)
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.fault_workers", str(photos), str(out), str(log), "0.4", "2"],
        env=_env(), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        _wait_for(lambda: len(log_lines(log, "start")) >= kill_after, 60, "the workers to start")
    except AssertionError:
        proc.kill()
        raise
    _kill_and_check_workers_die(proc)
    # what the killed run finished: complete folders (with or without a manifest line)
    finished = {p.parent.name for p in out.glob("*/summary.json")}
    assert len(finished) < 6, "the batch finished before it was killed; kill it earlier"
    recorded = {r["path"] for r in read_manifest(out / MANIFEST_JSONL) if r["status"] == "ok"}
    assert {Path(k).stem for k in recorded} <= finished  # a line only for a complete folder

    log2 = tmp_path / "log2.txt"
    summary = run_batch(images, out, SlowWorker(str(log2)), engine="inline", resume=True,
                        root=photos)  # fmt: skip
    assert summary.failed == 0 and summary.total == 6
    rerun = {Path(k).stem for k in log_lines(log2, "start")}
    assert rerun == {f"p{i}" for i in range(6)} - finished  # nothing done twice, nothing lost
    assert sorted(p.parent.name for p in out.glob("*/summary.json")) == [f"p{i}" for i in
                                                                          range(6)]  # fmt: skip
    assert _leftovers(out) == []
    # the manifest has one ok line per photo (recovered folders recorded, not redone)
    lines = read_manifest(out / MANIFEST_JSONL)
    ok = [r["path"] for r in lines if r["status"] == "ok"]
    assert sorted(set(ok)) == [f"p{i}.png" for i in range(6)]
    latest = {r["path"]: r for r in lines if r["status"] in ("ok", "failed")}
    assert all(r["status"] == "ok" for r in latest.values())


@pytest.mark.slow
def test_kill_9_of_easyhoi_batch_leaves_no_worker(tmp_path):
    """The real command line with the real worker: no process survives its batch."""
    photos, out = tmp_path / "photos", tmp_path / "out"
    _photos(photos, 3)
    proc = subprocess.Popen(
        [sys.executable, "-m", "easyhoi.cli", "batch", str(photos), "--out", str(out),
         "--workers", "1", "-q"],
        env=_env(), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:  # the fork server, the resource tracker and a worker
        _wait_for(lambda: len(_descendants(proc.pid)) >= 3 or proc.poll() is not None, 120,
                  "the worker process")  # fmt: skip
    except AssertionError:
        proc.kill()
        raise
    assert proc.poll() is None, "the batch ended before it could be killed"
    time.sleep(1.0)  # the worker is now inside a photo
    _kill_and_check_workers_die(proc)
    # what the killed run left (a lock file, hidden temporaries) goes on the next start
    assert main(["batch", str(photos), "--out", str(out), "--resume", "--engine", "inline",
                 "--set", "optim.camera.max_iters=1", "-q"]) in (0, 8)  # fmt: skip
    assert _leftovers(out) == []


# ----------------------------------------------------------------------------------------------
# concurrent runs on one --out
# ----------------------------------------------------------------------------------------------


def test_second_run_on_the_same_out_refuses_or_waits(tmp_path, capsys):
    photos, out, log = tmp_path / "photos", tmp_path / "out", tmp_path / "log.txt"
    images = _photos(photos, 2)
    first = OutputLock(out).acquire()  # another run holds the folder
    with pytest.raises(OutputBusyError, match=r"in use by another easyhoi run \(pid \d+"):
        run_batch(images, out, SlowWorker(str(log)), engine="inline")
    assert not log.exists() and not (out / MANIFEST_JSONL).exists()
    args = ["batch", str(photos), "--out", str(out), "--engine", "inline", "-q"]
    assert main(args) == ExitCode.OUTPUT_BUSY == 11
    err = capsys.readouterr().err
    assert "error: OutputBusyError: output folder" in err and "--wait" in err
    # --wait: starts when the first run lets go
    threading.Timer(0.5, first.release).start()
    t0 = time.monotonic()
    summary = run_batch(images, out, SlowWorker(str(log)), engine="inline", wait=True)
    assert time.monotonic() - t0 >= 0.4 and summary.ok == 2
    assert not (out / LOCK_NAME).exists()


@pytest.mark.slow
def test_two_concurrent_processes_one_refused_nothing_lost(tmp_path):
    photos, out = tmp_path / "photos", tmp_path / "out"
    _photos(photos, 4)
    cmd = [sys.executable, "-m", "tests.fault_workers", str(photos), str(out)]
    a = subprocess.Popen(cmd + [str(tmp_path / "a.txt"), "0.3", "1"], env=_env(), cwd=ROOT,
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
    _wait_for(lambda: (out / LOCK_NAME).exists(), 60, "the first run's lock")
    b = subprocess.run(cmd + [str(tmp_path / "b.txt"), "0.3", "1"], env=_env(), cwd=ROOT,
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert b.returncode != 0 and "OutputBusyError" in b.stderr
    assert a.wait(timeout=120) == 0
    assert not (tmp_path / "b.txt").exists()
    lines = read_manifest(out / MANIFEST_JSONL)
    assert sorted(r["path"] for r in lines) == [f"p{i}.png" for i in range(4)]
    assert _leftovers(out) == []


def test_stale_lock_of_a_dead_process_is_taken_over(tmp_path):
    photos, out = tmp_path / "photos", tmp_path / "out"
    images = _photos(photos, 1)
    out.mkdir()
    (out / LOCK_NAME).write_text("pid 999999999 on gone since then\n")  # no flock: holder dead
    summary = run_batch(images, out, summarize_photo, engine="inline")
    assert summary.ok == 1 and not (out / LOCK_NAME).exists()


# ----------------------------------------------------------------------------------------------
# temporaries, manifest reconciliation
# ----------------------------------------------------------------------------------------------


def test_stale_temporaries_swept_on_start_and_on_resume(tmp_path):
    photos, out = tmp_path / "photos", tmp_path / "out"
    images = _photos(photos, 2)
    for resume in (False, True):
        (out / ".p0.tmp-abc").mkdir(parents=True)
        (out / ".p0.tmp-abc" / "summary.json").write_text("half")
        (out / "sub" / ".p9.tmp-x").mkdir(parents=True)
        (out / ".manifest.jsonl.k2.tmp").write_text("x")
        outside = tmp_path / "keep"
        outside.mkdir(exist_ok=True)
        (outside / "file").write_text("mine")
        os.symlink(outside, out / ".link.tmp-zz")  # a link: removed itself, never its target
        run_batch(images, out, summarize_photo, engine="inline", resume=resume)
        assert _leftovers(out) == [], resume
        assert (outside / "file").read_text() == "mine"


def test_interrupted_replacement_restores_the_previous_result(tmp_path):
    photos, out = tmp_path / "photos", tmp_path / "out"
    images = _photos(photos, 2)
    run_batch(images, out, summarize_photo, engine="inline")
    before = (out / "p1" / "summary.json").read_text()
    (out / "p1").rename(out / ".p1.old-q1")  # killed between the two renames of a replacement
    (out / ".p1.tmp-q2").mkdir()
    log = tmp_path / "log.txt"
    summary = run_batch(images, out, SlowWorker(str(log)), engine="inline", resume=True)
    assert summary.skipped == 2 and not log.exists()
    assert (out / "p1" / "summary.json").read_text() == before and _leftovers(out) == []


def test_resume_redoes_a_vanished_folder_and_records_an_unrecorded_one(tmp_path):
    photos, out, log = tmp_path / "photos", tmp_path / "out", tmp_path / "log.txt"
    images = _photos(photos, 3)
    run_batch(images, out, summarize_photo, engine="inline")
    import shutil

    shutil.rmtree(out / "p0")  # recorded ok, folder gone: redone
    lines = (out / MANIFEST_JSONL).read_text().splitlines(keepends=True)
    (out / MANIFEST_JSONL).write_text("".join(ln for ln in lines if '"p2.png"' not in ln))
    summary = run_batch(images, out, SlowWorker(str(log)), engine="inline", resume=True)
    assert log_lines(log, "start") == ["p0.png"]
    by = {r.path: r for r in summary.records}
    assert by["p0.png"].status == "ok" and by["p1.png"].status == "skipped"
    assert by["p2.png"].status == "ok" and "recovered" in by["p2.png"].info
    assert (out / "p0" / "summary.json").exists()


# ----------------------------------------------------------------------------------------------
# a full disk
# ----------------------------------------------------------------------------------------------


class _FullDisk:
    """Stand-in for the ``os`` module of one writer: ``write``/``fsync`` fail with ENOSPC after
    ``allow`` successful calls (a disk that fills up mid-run)."""

    def __init__(self, allow: int, fail=("fsync",)):
        self._allow, self._fail = allow, fail

    def __getattr__(self, name):
        real = getattr(os, name)
        if name not in self._fail:
            return real

        def call(*args, **kwargs):
            if self._allow <= 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            self._allow -= 1
            return real(*args, **kwargs)

        return call


def test_disk_full_in_reconstruct_exits_10_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    import easyhoi.io.atomic as atomic
    import easyhoi.pipeline as pipeline

    def reconstruct_photo(image, folder, settings, **kw):
        def fill(tmp):
            for name in ("a.json", "b.json", "c.json"):
                atomic.atomic_write_bytes(tmp / name, b"{}" * 1000)

        atomic.publish_folder(folder, fill, ["a.json", "b.json", "c.json"])
        return SimpleNamespace(files=[], seconds=0.0, perception={})

    monkeypatch.setattr(pipeline, "reconstruct_photo", reconstruct_photo)
    monkeypatch.setattr(atomic, "os", _FullDisk(allow=1))
    (photo,) = _photos(tmp_path / "in", 1)
    out = tmp_path / "out"
    rc = main(["reconstruct", str(photo), "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert rc == ExitCode.RESOURCE == 10, err
    assert "error: ResourceError: disk full (No space left on device" in err
    assert "Traceback" not in err
    assert not out.exists() or list(out.iterdir()) == []


def test_disk_full_in_batch_worker_and_in_manifest(tmp_path, capsys, monkeypatch):
    import easyhoi.batch_manifest as manifest
    import easyhoi.io.atomic as atomic

    photos, out = tmp_path / "photos", tmp_path / "out"
    images = _photos(photos, 2)
    # the photos' writer fails: each photo is recorded with exit 10, no folder is left

    def full_disk_worker(task):
        with pytest.MonkeyPatch.context() as m:
            m.setattr(atomic, "os", _FullDisk(allow=0))
            return summarize_photo(task)

    summary = run_batch(images, out, full_disk_worker, engine="inline")
    assert [(r.exit_code, r.error_type, r.internal) for r in summary.records] == [
        (10, "ResourceError", False)
    ] * 2
    assert sorted(p.name for p in out.iterdir()) == ["manifest.csv", "manifest.jsonl"]
    # the manifest's own disk fills up: the CLI exits 10, the manifest keeps whole lines only
    monkeypatch.setattr(manifest, "os", _FullDisk(allow=1, fail=("fsync",)))
    rc = main(["batch", str(photos), "--out", str(out), "--engine", "inline", "-q",
               "--set", "optim.camera.max_iters=1"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 10 and "error: ResourceError: disk full" in err, err
    text = (out / MANIFEST_JSONL).read_text()
    assert text == "" or text.endswith("\n")
    assert all(json.loads(x) for x in text.splitlines())
    assert _leftovers(out) == []


# ----------------------------------------------------------------------------------------------
# hostile files
# ----------------------------------------------------------------------------------------------


def _png_header_only(path: Path, width: int, height: int) -> Path:
    """A valid PNG signature and IHDR declaring ``width`` x ``height``, with a tiny IDAT."""
    import struct

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF)  # fmt: skip

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 4096, 9)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
                     + chunk(b"IEND", b""))  # fmt: skip
    return path


def _jpeg_claiming(path: Path, width: int, height: int) -> Path:
    """A real small JPEG whose frame header is patched to claim ``width`` x ``height``."""
    import io
    import struct

    buf = io.BytesIO()
    Image.fromarray(np.zeros((40, 40, 3), np.uint8)).save(buf, format="JPEG")
    data = bytearray(buf.getvalue())
    i = data.index(b"\xff\xc0")
    data[i + 5 : i + 9] = struct.pack(">HH", height, width)
    path.write_bytes(bytes(data))
    return path


def _zip_named_jpg(path: Path) -> Path:
    import zipfile

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("inner.png", b"\x00" * 5_000_000)  # 5 MB of zeros in a few kB
    return path


def _truncated_png(path: Path) -> Path:
    import io

    buf = io.BytesIO()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)).save(buf, format="PNG")
    path.write_bytes(buf.getvalue()[: len(buf.getvalue()) // 2])
    return path


HOSTILE_PHOTOS = [
    # (maker, exit code, error type, message excerpt)
    (lambda p: _png_header_only(p / "bomb.png", 20000, 20000), 10, "InputTooLargeError",
     "is too large: 400 MP; at most 120 MP are accepted"),
    (lambda p: _png_header_only(p / "wide.png", 2**31 - 1, 64), 10, "InputTooLargeError",
     "is too large"),
    (lambda p: _jpeg_claiming(p / "bomb.jpg", 60000, 60000), 10, "InputTooLargeError",
     "is too large: 3600 MP; at most 120 MP"),
    (lambda p: _zip_named_jpg(p / "zip.jpg"), 2, "InvalidInputError",
     "not an image in a supported format"),
    (lambda p: _truncated_png(p / "half.png"), 2, "InvalidInputError",
     "corrupt or truncated"),
]  # fmt: skip


@pytest.mark.parametrize("case", range(len(HOSTILE_PHOTOS)))
def test_hostile_photos(tmp_path, capsys, case):
    make, code, error, excerpt = HOSTILE_PHOTOS[case]
    (tmp_path / "in").mkdir()
    photo = make(tmp_path / "in")
    out = tmp_path / "out"
    t0 = time.monotonic()
    rc = main(["reconstruct", str(photo), "--out", str(out), "-q"])
    seconds = time.monotonic() - t0
    err = capsys.readouterr().err
    assert rc == code, err
    assert f"error: {error}: " in err and excerpt in err and "Traceback" not in err, err
    assert seconds < 5.0, seconds  # a hang detector: the checks read headers only
    assert not out.exists() or list(out.iterdir()) == []


def test_hostile_photos_in_a_batch_are_recorded_not_fatal(tmp_path):
    photos = tmp_path / "in"
    photos.mkdir()
    for make, *_ in HOSTILE_PHOTOS:
        make(photos)
    images = sorted(photos.iterdir())
    summary = run_batch(images, tmp_path / "out", summarize_photo, engine="inline")
    got = {r.path: (r.exit_code, r.error_type) for r in summary.records}
    want = {make(tmp_path / "in").name: (code, error) for make, code, error, _ in HOSTILE_PHOTOS}
    assert got == want
    assert _leftovers(tmp_path / "out") == []


def test_nan_mesh_is_refused(tmp_path, capsys):
    (photo,) = _photos(tmp_path / "in", 1)
    mesh = tmp_path / "nan.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    out = tmp_path / "out"
    rc = main(["reconstruct", str(photo), "--out", str(out), "--object-mesh", str(mesh), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "NaN or infinite" in err and "Traceback" not in err, err
    assert not out.exists() or list(out.iterdir()) == []


def test_links_out_of_the_output_folder_are_refused(tmp_path, capsys):
    photos, out = tmp_path / "photos", tmp_path / "out"
    _photos(photos, 2)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious").write_text("keep")
    out.mkdir()
    os.symlink(elsewhere, out / "p0")  # a photo's result folder
    args = ["batch", str(photos), "--out", str(out), "--engine", "inline", "-q"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "error: InvalidInputError: " in err and "is a symbolic link" in err, err
    os.unlink(out / "p0")
    target = elsewhere / "victim.txt"
    target.write_text("keep")
    os.symlink(target, out / MANIFEST_JSONL)  # the manifest, with --resume appending to it
    assert main(args + ["--resume"]) == 2
    assert "is a symbolic link" in capsys.readouterr().err
    assert target.read_text() == "keep" and (elsewhere / "precious").read_text() == "keep"
    assert sorted(p.name for p in elsewhere.iterdir()) == ["precious", "victim.txt"]
    assert _leftovers(out) == []


@pytest.mark.slow
def test_disk_full_during_a_real_reconstruction(shared_data, tmp_path, capsys, monkeypatch):
    """The real pipeline and writers; the disk fills up after the third file of the folder."""
    import easyhoi.io.atomic as atomic

    photo = shared_data / "images" / "hort-can.png"
    out = tmp_path / "out"
    monkeypatch.setattr(atomic, "os", _FullDisk(allow=3))
    rc = main(["reconstruct", str(photo), "--out", str(out), "-q",
               "--set", "optim.camera.max_iters=10", "--set", "optim.contact.max_iters=10",
               "--set", "optim.refine.max_iters=5"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 10 and "error: ResourceError: disk full (No space left on device" in err, err
    assert "Traceback" not in err
    assert not out.exists() or list(out.iterdir()) == []


def test_reconstruct_replaces_a_link_in_out_without_touching_its_target(tmp_path, capsys,
                                                                        monkeypatch):  # fmt: skip
    import easyhoi.io.atomic as atomic
    import easyhoi.pipeline as pipeline

    def reconstruct_photo(image, folder, settings, **kw):
        atomic.publish_folder(folder, lambda tmp: (tmp / "r.json").write_text("{}"), ["r.json"])
        return SimpleNamespace(files=[], seconds=0.0, perception={})

    monkeypatch.setattr(pipeline, "reconstruct_photo", reconstruct_photo)
    (photo,) = _photos(tmp_path / "in", 1)
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious").write_text("keep")
    out.mkdir()
    os.symlink(elsewhere, out / photo.stem)
    assert main(["reconstruct", str(photo), "--out", str(out), "-q"]) == 2  # exists: refused
    assert (out / photo.stem).is_symlink()
    assert main(["reconstruct", str(photo), "--out", str(out), "-q", "--overwrite"]) == 0
    assert not (out / photo.stem).is_symlink() and (out / photo.stem / "r.json").is_file()
    assert sorted(p.name for p in elsewhere.iterdir()) == ["precious"]
    assert sorted(p.name for p in out.iterdir()) == [photo.stem]


def test_devices_and_fifos_named_as_photos_are_refused_at_once(tmp_path, capsys):
    fifo = tmp_path / "fifo.jpg"
    os.mkfifo(fifo)  # opening it for reading would block forever
    zero = tmp_path / "zero.png"
    os.symlink("/dev/zero", zero)  # reading it would never end
    for photo in (fifo, zero):
        rc = main(["reconstruct", str(photo), "--out", str(tmp_path / "out"), "-q"])
        err = capsys.readouterr().err
        assert rc == 2 and "error: InvalidInputError: image path is not a file" in err, err
    from easyhoi.batch import discover_images

    assert discover_images(tmp_path) == []  # never taken as photos of a batch


def test_lock_file_that_is_a_link_is_refused(tmp_path):
    from easyhoi.errors import InvalidInputError

    out = tmp_path / "out"
    out.mkdir()
    target = tmp_path / "victim"
    target.write_text("keep")
    os.symlink(target, out / LOCK_NAME)
    with pytest.raises(InvalidInputError, match="is a symbolic link"):
        OutputLock(out).acquire()
    assert target.read_text() == "keep"
    os.unlink(out / LOCK_NAME)
    with OutputLock(out) as lock:  # and a held lock times out for a waiting second run
        assert lock.held
        t0 = time.monotonic()
        with pytest.raises(OutputBusyError, match=f"pid {os.getpid()}"):
            OutputLock(out, wait=True, poll=0.05, timeout=0.3).acquire()
        assert time.monotonic() - t0 >= 0.3
    assert not (out / LOCK_NAME).exists()
