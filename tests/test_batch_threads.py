"""Batch workers: one torch thread each, one worker per core by default."""

from __future__ import annotations

import os

import pytest

from easyhoi.cli import _batch_workers, build_parser
from easyhoi.distributed import DEFAULT_THREADS, Task, available_cores, execute


def _threads_worker(task: Task) -> dict:
    import torch

    return {"threads": torch.get_num_threads(), "pid": os.getpid(),
            "omp": os.environ.get("OMP_NUM_THREADS")}  # fmt: skip


@pytest.mark.slow  # starts two worker processes that import torch (about 14 s when loaded)
def test_local_workers_use_one_torch_thread_each():
    tasks = [Task(f"p{i}", f"p{i}.jpg", f"out/p{i}", i) for i in range(4)]
    results = list(execute(tasks, _threads_worker, engine="local", workers=2))
    assert DEFAULT_THREADS == 1
    assert sorted(r.key for r in results) == ["p0", "p1", "p2", "p3"]
    assert all(r.ok for r in results), [r.error for r in results]
    assert {r.info["threads"] for r in results} == {1}
    assert {r.info["omp"] for r in results} == {"1"}
    # the processes stay for the whole batch: at most two of them served the four photos
    assert len({r.info["pid"] for r in results}) <= 2


def test_batch_workers_default_to_the_cores(tmp_path):
    parser = build_parser()
    args = parser.parse_args(["batch", str(tmp_path), "--out", str(tmp_path / "o")])
    assert args.workers is None
    assert _batch_workers(args) == available_cores()
    args = parser.parse_args(["batch", str(tmp_path), "--out", "o", "--workers", "3"])
    assert _batch_workers(args) == 3
    args = parser.parse_args(["batch", str(tmp_path), "--out", "o", "--engine", "inline"])
    assert _batch_workers(args) == 1
    # several photos given to reconstruct run inline in the one process
    args = parser.parse_args(["reconstruct", "a.jpg", "b.jpg", "--out", "o"])
    assert _batch_workers(args) == 1


_PRELOAD = """
import json, sys
from easyhoi.distributed import Task, execute
from tests.test_batch_threads import PreloadProbe
tasks = [Task(f"p{i}", f"p{i}.jpg", f"out/p{i}", i) for i in range(2)]
print(json.dumps([r.info for r in execute(tasks, PreloadProbe(), engine="local", workers=2)]))
"""


class PreloadProbe:
    """Reports whether the module it asks the fork server to preload was there before it ran."""

    preload = ("colorsys",)  # a standard module nothing else here imports

    def __call__(self, task: Task) -> dict:
        import sys

        return {"preloaded": "colorsys" in sys.modules, "pid": os.getpid()}


@pytest.mark.slow  # a fresh interpreter (its own fork server) and two workers: about 5 s
def test_workers_start_with_the_modules_their_worker_preloads():
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", _PRELOAD], capture_output=True, text=True,
                         cwd=root, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    infos = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(infos) == 2 and all(i["preloaded"] for i in infos)


def test_a_local_batch_starts_its_fork_server_before_its_own_set_up(tmp_path, monkeypatch):
    """The fork server's imports (torch, the pipeline) overlap the batch process's set-up
    (settings and hand model), and the batch process sets no torch threads of its own; the
    inline engine reconstructs in this process and starts no fork server."""
    import easyhoi.distributed as dist
    from easyhoi import cli

    (tmp_path / "a.jpg").write_bytes(b"not decoded here")
    calls = []
    monkeypatch.setattr(dist, "start_fork_server", lambda preload: calls.append(("fork", preload)))
    monkeypatch.setattr(cli, "run_from_args", lambda args: calls.append(("settings",)) or "run")
    monkeypatch.setattr(cli, "_run_batch", lambda *a, **k: calls.append(("run",)) or 0)
    parser = build_parser()
    for engine, want in (("local", ["fork", "settings", "run"]), ("inline", ["settings", "run"])):
        calls.clear()
        args = parser.parse_args(["batch", str(tmp_path), "--out", str(tmp_path / "o"),
                                  "--engine", engine])  # fmt: skip
        assert args.uses_torch(args) is (engine == "inline")
        assert cli.cmd_batch(args) == 0
        assert [c[0] for c in calls] == want
        if engine == "local":
            assert "torch" in calls[0][1]  # the preload the pool would give it


def test_the_fork_server_started_early_serves_the_pool(tmp_path):
    """A fork server started by start_fork_server is the one the pool's workers come from."""
    from easyhoi.distributed import start_fork_server

    if not start_fork_server(()):
        pytest.skip("no fork server on this platform")
    tasks = [Task(f"p{i}", f"p{i}.jpg", f"out/p{i}", i) for i in range(2)]
    results = list(execute(tasks, _pid_worker, engine="local", workers=1))
    assert all(r.ok for r in results), [r.error for r in results]
    from multiprocessing import forkserver

    # the workers' parent is the fork server that was already running
    assert {r.info["ppid"] for r in results} == {forkserver._forkserver._forkserver_pid}


def _pid_worker(task: Task) -> dict:
    return {"ppid": os.getppid()}
