"""Batch runs: discovery, manifest contents, resume, local pool determinism, CLI exit codes."""

from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from easyhoi.batch import (
    MANIFEST_CSV,
    MANIFEST_JSONL,
    discover_images,
    item_seed,
    plan_tasks,
    read_manifest,
    run_batch,
    sniff_image_format,
    summarize_photo,
)
from easyhoi.cli import main
from easyhoi.distributed import EXIT_INTERNAL, Task, execute, threads_per_worker
from easyhoi.errors import InvalidInputError, MissingDependencyError

# ----------------------------------------------------------------------------------------------
# workers (module level: picklable, importable by spawned processes)
# ----------------------------------------------------------------------------------------------


class CountingWorker:
    """summarize_photo that appends the key of every call to a log file (works across processes)."""

    def __init__(self, log: str):
        self.log = log

    def __call__(self, task: Task) -> dict:
        with open(self.log, "a") as f:
            f.write(task.key + "\n")
        return summarize_photo(task)


def buggy_worker(task: Task) -> dict:
    if "boom" in task.key:
        raise RuntimeError("boom: not an easyhoi error")
    return summarize_photo(task)


def dying_worker(task: Task) -> dict:
    if "die" in task.key:
        os._exit(3)  # the process vanishes, as when killed for memory
    return summarize_photo(task)


def calls(log: Path) -> list[str]:
    return sorted(log.read_text().split()) if log.exists() else []


# ----------------------------------------------------------------------------------------------
# fixtures
# ----------------------------------------------------------------------------------------------


def _photo(path: Path, seed: int, fmt: str | None = None, size=(48, 64)) -> Path:
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 256, (*size, 3), dtype=np.uint8)).save(path, format=fmt)
    return path


@pytest.fixture
def photos(tmp_path) -> Path:
    """4 good photos, a zero-byte one and a corrupt one."""
    d = tmp_path / "photos"
    d.mkdir()
    for i in range(4):
        _photo(d / f"good{i}.png", i)
    (d / "empty.jpg").write_bytes(b"")
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00garbage" * 4)
    return d


def _outputs(out: Path) -> dict[str, dict]:
    return {
        p.parent.relative_to(out).as_posix(): json.loads(p.read_text())
        for p in sorted(out.rglob("summary.json"))
    }


def _statuses(summary) -> dict[str, str]:
    return {r.path: r.status for r in summary.records}


# ----------------------------------------------------------------------------------------------
# discovery and planning
# ----------------------------------------------------------------------------------------------


def test_discover_by_extension_and_content(tmp_path):
    d = tmp_path / "in"
    (d / "sub" / "deeper").mkdir(parents=True)
    (d / ".hidden").mkdir()
    _photo(d / "b.png", 0)
    _photo(d / "A.JPG", 1, "JPEG")
    _photo(d / "scan_0001", 2, "PNG")  # no extension: sniffed
    _photo(d / "photo.image", 3, "WEBP")  # unknown extension: sniffed
    (d / "notes.dat").write_bytes(b"not an image at all")  # unknown extension, not an image
    _photo(d / "fake.txt", 4, "PNG")  # known other extension: never opened
    (d / "zero.jpg").write_bytes(b"")  # photo extension: taken, fails later
    _photo(d / ".dot.png", 5)
    _photo(d / ".hidden" / "h.png", 6)
    _photo(d / "sub" / "s.bmp", 7)
    _photo(d / "sub" / "deeper" / "t.tif", 8)
    (d / MANIFEST_JSONL).write_text("{}\n")

    flat = [p.relative_to(d).as_posix() for p in discover_images(d)]
    assert flat == ["A.JPG", "b.png", "photo.image", "scan_0001", "zero.jpg"]
    deep = [p.relative_to(d).as_posix() for p in discover_images(d, recursive=True)]
    assert deep == flat[:4] + ["sub/deeper/t.tif", "sub/s.bmp", "zero.jpg"]
    excl = discover_images(d, recursive=True, exclude=[d / "sub" / "deeper"])
    assert [p.relative_to(d).as_posix() for p in excl] == flat[:4] + ["sub/s.bmp", "zero.jpg"]


def test_discover_missing_or_file_is_invalid_input(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        discover_images(tmp_path / "nope")
    f = _photo(tmp_path / "x.png", 0)
    with pytest.raises(InvalidInputError, match="not a folder"):
        discover_images(f)
    assert discover_images(tmp_path / ".") == [tmp_path / "./x.png"]


@pytest.mark.parametrize(
    "fmt, ext", [("JPEG", "jpg"), ("PNG", "png"), ("WEBP", "webp"), ("BMP", "bmp"),
                 ("GIF", "gif"), ("TIFF", "tif"), ("PPM", "ppm")]
)  # fmt: skip
def test_sniff_matches_pillow(tmp_path, fmt, ext):
    p = _photo(tmp_path / f"x.{ext}", 0, fmt)
    expected = {"PPM": "PNM"}.get(fmt, fmt)
    assert sniff_image_format(p) == expected
    assert Image.open(p).format == fmt
    (tmp_path / "t").write_bytes(b"hello world, not an image")
    assert sniff_image_format(tmp_path / "t") is None


def test_plan_names_seeds_and_collisions(tmp_path):
    d = tmp_path / "in"
    (d / "sub").mkdir(parents=True)
    names = ["x.jpg", "x.png", "y.png", "manifest.csv.png"]
    files = [_photo(d / n, i) for i, n in enumerate(names)]
    files.append(_photo(d / "sub" / "x.jpg", 9))
    tasks = plan_tasks(files + [files[0]], tmp_path / "out", seed=7, root=d)
    assert [t.key for t in tasks] == ["manifest.csv.png", "sub/x.jpg", "x.jpg", "x.png", "y.png"]
    out = [Path(t.output).relative_to(tmp_path / "out").as_posix() for t in tasks]
    assert out == ["manifest.csv_photo", "sub/x", "x_jpg", "x_png", "y"]
    assert [t.seed for t in tasks] == [item_seed(7, t.key) for t in tasks]
    assert len({t.seed for t in tasks}) == 5 and all(0 <= t.seed < 2**31 for t in tasks)
    # seeds depend on the batch seed and the name only
    assert item_seed(7, "x.jpg") == item_seed(7, "x.jpg") != item_seed(8, "x.jpg")
    with pytest.raises(InvalidInputError, match="not inside"):
        plan_tasks(files, tmp_path / "out", root=d / "sub")


def test_plan_names_linked_photos_by_their_place_in_the_folder(tmp_path):
    """A folder of symbolic links to photos kept elsewhere (a common way to pick a subset of a
    data set) is a batch like any other: each photo is named by its link."""
    store = tmp_path / "store"
    store.mkdir()
    a, b = _photo(store / "a.jpg", 1), _photo(store / "b.png", 2)
    d = tmp_path / "picked"
    (d / "sub").mkdir(parents=True)
    (d / "first.jpg").symlink_to(a)
    (d / "sub" / "second.png").symlink_to(b)
    photos = discover_images(d, recursive=True)
    assert [p.relative_to(d).as_posix() for p in photos] == ["first.jpg", "sub/second.png"]
    for root in (d, None):
        tasks = plan_tasks(photos, tmp_path / "out", seed=3, root=root)
        assert [t.key for t in tasks] == ["first.jpg", "sub/second.png"]
        assert [t.image for t in tasks] == [str(p) for p in photos]
    # photos named through a link to their folder, against the folder's real path
    (store / "sub").mkdir()
    c = _photo(store / "sub" / "c.jpg", 3)
    (tmp_path / "storelink").symlink_to(store, target_is_directory=True)
    named = [tmp_path / "storelink" / "sub" / "c.jpg"]
    assert [t.key for t in plan_tasks(named, tmp_path / "out", root=store)] == ["sub/c.jpg"]
    assert [t.key for t in plan_tasks([c], tmp_path / "out", root=tmp_path / "storelink")] == [
        "sub/c.jpg"
    ]
    # a photo outside the root is still refused
    with pytest.raises(InvalidInputError, match="not inside"):
        plan_tasks([a], tmp_path / "out", root=d)


def test_threads_per_worker():
    assert [threads_per_worker(w, cores=8) for w in (1, 2, 3, 8, 16)] == [8, 4, 2, 1, 1]


# ----------------------------------------------------------------------------------------------
# manifest
# ----------------------------------------------------------------------------------------------


def test_manifest_records_failures_and_successes(photos, tmp_path):
    out = tmp_path / "out"
    seen = []
    summary = run_batch(
        discover_images(photos), out, summarize_photo, engine="inline", seed=3,
        progress=lambda rec, done, total: seen.append((rec.path, done, total)),
    )  # fmt: skip
    assert (summary.total, summary.ok, summary.failed, summary.skipped) == (6, 4, 2, 0)
    assert summary.exit_code == 8
    assert [s[1:] for s in seen] == [(i, 6) for i in range(1, 7)]

    lines = [json.loads(x) for x in (out / MANIFEST_JSONL).read_text().splitlines()]
    assert len(lines) == 6
    by = {rec["path"]: rec for rec in lines}
    assert set(by) == {"corrupt.png", "empty.jpg", "good0.png", "good1.png", "good2.png",
                       "good3.png"}  # fmt: skip
    assert by["empty.jpg"]["status"] == "failed"
    assert by["empty.jpg"]["error_type"] == "InvalidInputError"
    assert "0 bytes" in by["empty.jpg"]["error"] and by["empty.jpg"]["exit_code"] == 2
    assert by["corrupt.png"]["status"] == "failed" and by["corrupt.png"]["exit_code"] == 2
    assert "corrupt" in by["corrupt.png"]["error"] and by["corrupt.png"]["internal"] is False
    for i in range(4):
        rec = by[f"good{i}.png"]
        assert rec["status"] == "ok" and rec["error"] is None and rec["exit_code"] == 0
        assert rec["output"] == f"good{i}" and rec["seed"] == item_seed(3, f"good{i}.png")
        assert rec["info"] == {"format": "PNG", "width": 64, "height": 48}
        assert rec["seconds"] >= 0
        s = json.loads((out / f"good{i}" / "summary.json").read_text())
        img = np.asarray(Image.open(photos / f"good{i}.png"))
        assert s["seed"] == rec["seed"]
        np.testing.assert_allclose(s["mean_rgb"], img.reshape(-1, 3).mean(0), atol=1e-4)
        rng = np.random.default_rng(rec["seed"])
        ys, xs = rng.integers(0, 48, 16), rng.integers(0, 64, 16)
        assert s["probe"] == img[ys, xs].tolist()
    assert not (out / "empty").exists() and not (out / "corrupt").exists()

    with open(out / MANIFEST_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["path"] for r in rows] == sorted(by)
    assert [r["status"] for r in rows] == ["failed", "failed", "ok", "ok", "ok", "ok"]
    assert rows[1]["exit_code"] == "2" and rows[1]["error_type"] == "InvalidInputError"


def test_non_easyhoi_exception_is_internal_and_batch_continues(photos, tmp_path):
    _photo(photos / "boom.png", 11)
    summary = run_batch(discover_images(photos), tmp_path / "o", buggy_worker, engine="inline")
    rec = {r.path: r for r in summary.records}["boom.png"]
    assert (rec.status, rec.error_type, rec.exit_code, rec.internal) == (
        "failed", "RuntimeError", EXIT_INTERNAL, True,
    )  # fmt: skip
    assert rec.error == "boom: not an easyhoi error"
    assert (summary.ok, summary.failed) == (4, 3)


def test_resume_skips_finished_photos(photos, tmp_path):
    out, log = tmp_path / "out", tmp_path / "calls.txt"
    images = discover_images(photos)
    worker = CountingWorker(str(log))
    run_batch(images, out, worker, engine="inline")
    assert len(calls(log)) == 6

    log.unlink()
    s2 = run_batch(images, out, worker, engine="inline", resume=True)
    assert calls(log) == ["corrupt.png", "empty.jpg"]  # only the failed ones run again
    assert _statuses(s2) == {"corrupt.png": "failed", "empty.jpg": "failed", "good0.png": "skipped",
                             "good1.png": "skipped", "good2.png": "skipped",
                             "good3.png": "skipped"}  # fmt: skip
    assert s2.exit_code == 8 and len(read_manifest(out / MANIFEST_JSONL)) == 12

    # fix a photo, delete an output folder: both run again; "skipped" lines do not hide "ok"
    _photo(photos / "empty.jpg", 5, "JPEG")
    import shutil

    shutil.rmtree(out / "good2")
    log.unlink()
    s3 = run_batch(images, out, worker, engine="inline", resume=True)
    assert calls(log) == ["corrupt.png", "empty.jpg", "good2.png"]
    assert (s3.ok, s3.failed, s3.skipped) == (2, 1, 3)

    # without --resume everything runs and the manifest starts again
    log.unlink()
    s4 = run_batch(images, out, worker, engine="inline")
    assert len(calls(log)) == 6 and len(read_manifest(out / MANIFEST_JSONL)) == 6
    assert s4.skipped == 0


def test_resume_repairs_a_partial_last_line(photos, tmp_path):
    out, log = tmp_path / "out", tmp_path / "calls.txt"
    images = [p for p in discover_images(photos) if p.name.startswith("good")]
    run_batch(images, out, CountingWorker(str(log)), engine="inline")
    text = (out / MANIFEST_JSONL).read_text().splitlines(keepends=True)
    last = json.loads(text[-1])["path"]
    # a crash in the middle of the last write
    (out / MANIFEST_JSONL).write_text("".join(text[:-1]) + text[-1][: len(text[-1]) // 2])
    log.unlink()
    summary = run_batch(images, out, CountingWorker(str(log)), engine="inline", resume=True)
    # its folder is complete (folders appear whole): recorded as ok without running it again
    assert not log.exists()
    lines = (out / MANIFEST_JSONL).read_text().splitlines()
    assert len(lines) == 3 + 4 and all(json.loads(x) for x in lines)
    assert (summary.ok, summary.skipped) == (1, 3)
    (rec,) = [r for r in summary.records if r.status == "ok"]
    assert rec.path == last and "recovered" in rec.info


# ----------------------------------------------------------------------------------------------
# engines
# ----------------------------------------------------------------------------------------------


def test_local_pool_two_workers_same_as_one_and_inline(photos, tmp_path):
    images = discover_images(photos)
    runs = {}
    for name, engine, n in (("inline", "inline", 1), ("one", "local", 1), ("two", "local", 2)):
        s = run_batch(images, tmp_path / name, summarize_photo, engine=engine, workers=n, seed=5)
        runs[name] = (_statuses(s), _outputs(tmp_path / name), s)
    assert runs["one"][0] == runs["two"][0] == runs["inline"][0]
    assert runs["one"][1] == runs["two"][1] == runs["inline"][1]
    assert len(runs["two"][1]) == 4
    assert runs["two"][2].workers == 2 and runs["two"][2].engine == "local"
    # the seed written by every process is the planned one
    assert {k: v["seed"] for k, v in runs["two"][1].items()} == {
        f"good{i}": item_seed(5, f"good{i}.png") for i in range(4)
    }


def test_local_pool_survives_a_dying_worker_process(photos, tmp_path):
    _photo(photos / "die.png", 12)
    images = [p for p in discover_images(photos) if p.name != "corrupt.png"]
    summary = run_batch(images, tmp_path / "o", dying_worker, engine="local", workers=2)
    st = _statuses(summary)
    assert st.pop("die.png") == "failed" and st.pop("empty.jpg") == "failed"
    assert set(st.values()) == {"ok"} and len(st) == 4
    rec = {r.path: r for r in summary.records}["die.png"]
    assert (rec.error_type, rec.exit_code, rec.internal) == ("WorkerDied", 70, True)
    assert len(_outputs(tmp_path / "o")) == 4


def _echo_worker(task: Task) -> dict:
    return {"key": task.key}


def test_local_pool_recovers_when_the_pool_breaks_between_submissions(monkeypatch):
    # a worker process that dies while tasks are being submitted makes submit() itself raise
    # BrokenProcessPool; the batch must restart the pool and still run every task exactly once
    from concurrent.futures import Future
    from concurrent.futures.process import BrokenProcessPool

    import easyhoi.distributed as dist

    pools = []

    class FlakyPool:  # runs tasks inline; its third submit finds the pool broken
        def __init__(self):
            self.submits = 0
            pools.append(self)

        def submit(self, fn, *args):
            self.submits += 1
            if len(pools) == 1 and self.submits == 3:
                raise BrokenProcessPool("A child process terminated abruptly")
            fut = Future()
            fut.set_result(fn(*args))
            return fut

        def shutdown(self, wait=True, cancel_futures=False):
            pass

    monkeypatch.setattr(dist, "_new_pool", lambda workers, threads, ctx, preload=(): FlakyPool())
    tasks = [Task(f"p{i}.png", f"p{i}.png", "out", i) for i in range(5)]
    results = list(dist.execute(tasks, _echo_worker, engine="local", workers=2, threads=1))
    assert sorted(r.key for r in results) == [t.key for t in tasks]
    assert all(r.status == "ok" for r in results)
    assert len(pools) == 2  # the broken pool was replaced once


def test_engine_argument_errors(photos, tmp_path):
    images = discover_images(photos)
    with pytest.raises(InvalidInputError, match="engine"):
        run_batch(images, tmp_path / "o", summarize_photo, engine="spark")
    with pytest.raises(InvalidInputError, match="workers"):
        run_batch(images, tmp_path / "o", summarize_photo, workers=0)
    with pytest.raises(InvalidInputError, match="cannot be sent"):
        run_batch(images, tmp_path / "o", lambda t: None, engine="local", workers=2)
    with pytest.raises(InvalidInputError, match="unique"):
        list(execute([Task("a", "x", "y", 1)] * 2, summarize_photo, engine="inline"))
    (tmp_path / "file").write_text("x")
    with pytest.raises(InvalidInputError, match="not a folder"):
        run_batch(images, tmp_path / "file", summarize_photo)


def test_ray_missing_names_the_extra(photos, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(MissingDependencyError, match=r"easyhoi\[distributed\]"):
        run_batch(discover_images(photos), tmp_path / "o", summarize_photo, engine="ray")


# ----------------------------------------------------------------------------------------------
# CLI
# ----------------------------------------------------------------------------------------------


def test_cli_batch_missing_and_empty_folder_exit_2(tmp_path, capsys):
    assert main(["batch", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "photo folder not found" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no photos here")
    assert main(["batch", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no photos found" in err and "--recursive" in err and "Traceback" not in err


def test_cli_batch_exit_8_when_photos_fail(photos, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    for name in ("corrupt.png", "empty.jpg"):
        (bad / name).write_bytes((photos / name).read_bytes())
    out = tmp_path / "o"
    rc = main(["batch", str(bad), "--out", str(out), "--engine", "inline"])
    assert rc == 8
    io = capsys.readouterr()
    assert "2 photos: 0 ok, 2 failed, 0 skipped" in io.out
    assert "empty.jpg: InvalidInputError" in io.err and "Traceback" not in io.err
    assert [r["status"] for r in read_manifest(out / MANIFEST_JSONL)] == ["failed", "failed"]


def _fake_pipeline(monkeypatch, perception=None, prompts_seen=None):
    """Stand-ins for the reconstruction and the result writer (fast, no optimizer needed).

    ``perception`` is the perception report every photo gets; ``prompts_seen`` (a dict) records
    the prompts and the strict flag each photo got.
    """
    import easyhoi.pipeline as pipeline
    from easyhoi.io.image import load_image

    seen = {}

    def reconstruct_photo(image, folder, settings, seed=None, prompts=None, strict=False, **kw):
        load_image(image)
        seen[Path(image).name] = (seed, settings.config.hand_model)
        if prompts_seen is not None:
            prompts_seen[Path(image).name] = (prompts, strict)
        Path(folder).mkdir(parents=True)
        (Path(folder) / "result.json").write_text(json.dumps({"result": "R"}))
        return SimpleNamespace(files=[Path(folder) / "result.json"], seconds=0.01,
                               perception=perception or {})  # fmt: skip

    monkeypatch.setattr(pipeline, "reconstruct_photo", reconstruct_photo)
    return seen


def test_cli_batch_exit_0_and_resume(tmp_path, capsys, monkeypatch):
    seen = _fake_pipeline(monkeypatch)
    d = tmp_path / "in"
    (d / "sub").mkdir(parents=True)
    _photo(d / "a.jpg", 0, "JPEG")
    _photo(d / "a.png", 1)
    _photo(d / "sub" / "b.png", 2)
    out = d / "results"  # inside the input folder: never taken as input
    args = ["batch", str(d), "--out", str(out), "--engine", "inline", "--recursive", "--seed", "4"]
    assert main(args) == 0
    assert "3 photos: 3 ok, 0 failed, 0 skipped" in capsys.readouterr().out
    assert seen == {"a.jpg": (item_seed(4, "a.jpg"), "open"), "a.png": (item_seed(4, "a.png"),
                    "open"), "b.png": (item_seed(4, "sub/b.png"), "open")}  # fmt: skip
    for folder in ("a_jpg", "a_png", "sub/b"):
        assert json.loads((out / folder / "result.json").read_text()) == {"result": "R"}
    seen.clear()
    assert main(args + ["--resume"]) == 0
    assert seen == {} and "3 photos: 0 ok, 0 failed, 3 skipped" in capsys.readouterr().out
