"""Batch executors: run one picklable worker over many photos, locally or on Ray.

A *worker* is any picklable callable ``worker(task: Task) -> dict | None`` (a module-level
function, a :func:`functools.partial` of one, or an instance of a module-level class with
``__call__``). It processes one photo, writes into ``task.output`` and returns a small JSON-ready
dict (or None). :func:`run_task` wraps every call: it times it and turns *any* exception into a
failed :class:`TaskResult` (an :class:`~easyhoi.errors.EasyHOIError` keeps its exit code, anything
else is recorded as an internal error, exit code 70), so one bad photo never stops a batch.

Engines (:func:`execute` yields results in completion order):

``"local"`` (default)
    A :class:`concurrent.futures.ProcessPoolExecutor` with ``workers`` processes, started with
    ``"forkserver"`` where the platform has it (a server process imports easyhoi and torch
    once, then every worker is forked from it in milliseconds; pools restarted after a crash
    reuse it) and ``"spawn"`` elsewhere. Each process uses one torch thread (see
    :data:`DEFAULT_THREADS`) and stays alive for the whole batch, so imports, compiled kernels
    and the hand model are loaded once per process, not once per photo. At most ``workers``
    tasks are in flight, so a process that dies (killed for memory, a segfault in native code)
    can be pinned down: the tasks that were running are retried one at a time in a fresh pool,
    and a task that kills its process again is recorded as failed.
``"ray"``
    Ray tasks (the ``[distributed]`` extra). ``ray.init(address=...)`` joins an existing cluster;
    without an address a local cluster bound to 127.0.0.1 with ``num_cpus=workers`` and no
    dashboard is started (and shut down afterwards); all its processes listen on the loopback
    interface only. Results are collected with ``ray.wait`` as they finish. A Ray session that
    is already initialised is reused and left running. A worker whose ``device`` attribute
    names a CUDA device asks Ray for GPUs (:func:`gpu_share`): one each when the cluster has
    as many GPUs as workers, else an equal share of them, so the workers share the GPUs.
``"inline"``
    Sequentially in the calling process (debugging; no isolation, no thread change).

Seeds are part of each :class:`Task` (derived by the caller from the batch seed and the photo's
name), so results do not depend on the engine, the number of workers or the completion order.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import multiprocessing
import os
import pickle
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

from easyhoi.errors import (
    EasyHOIError,
    ExitCode,
    InvalidInputError,
    MissingDependencyError,
    as_resource_error,
)

__all__ = [
    "DEFAULT_THREADS",
    "ENGINES",
    "EXIT_INTERNAL",
    "Task",
    "TaskResult",
    "available_cores",
    "execute",
    "gpu_share",
    "run_task",
    "threads_per_worker",
]

logger = logging.getLogger(__name__)

#: Engine names accepted by :func:`execute`.
ENGINES = ("local", "ray", "inline")

#: Exit code recorded for exceptions that are not :class:`EasyHOIError` (a bug), as in the CLI.
EXIT_INTERNAL = ExitCode.INTERNAL

#: Error type recorded when a worker process dies while running a task.
WORKER_DIED = "WorkerDied"

Worker = Callable[["Task"], "dict | None"]


@dataclass(frozen=True)
class Task:
    """One photo of a batch.

    Attributes:
        key (str): The photo's name inside the batch (relative POSIX path); unique per batch.
        image (str): Path of the photo file.
        output (str): Folder the worker writes this photo's results into.
        seed (int): Random seed of this photo (derived from the batch seed and ``key``).
    """

    key: str
    image: str
    output: str
    seed: int


@dataclass(frozen=True)
class TaskResult:
    """Outcome of one :class:`Task`.

    Attributes:
        key (str): :attr:`Task.key`.
        status (str): ``"ok"`` or ``"failed"``.
        seconds (float): Wall time of the worker call (0 when the process died).
        error_type (str or None): Exception class name (or ``"WorkerDied"``) when failed.
        error (str or None): Exception message when failed.
        exit_code (int): 0 when ok; the error's ``exit_code`` for an EasyHOIError; 70 otherwise.
        internal (bool): True when the failure was not an EasyHOIError (a bug or a crash).
        info (dict): The worker's return value (JSON-ready), empty when failed or None.
    """

    key: str
    status: str
    seconds: float
    error_type: str | None = None
    error: str | None = None
    exit_code: int = 0
    internal: bool = False
    info: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when the worker returned normally."""
        return self.status == "ok"


def available_cores() -> int:
    """CPU cores this process may run on (affinity-aware where the platform tells)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


#: Torch threads per worker process unless told otherwise. easyhoi's tensors are small (a few
#: thousand vertices, masks of at most 256 px): a second intra-op thread costs more in
#: synchronisation than it saves (one worker with 2 threads ran 2.5x slower than with 1 on a
#: 2-core machine), so parallelism comes from worker processes, one per core.
DEFAULT_THREADS = 1


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Threads that spread ``cores`` over ``workers`` processes: ``max(1, cores // workers)``.

    Not the default (:data:`DEFAULT_THREADS`); pass it as ``threads`` to :func:`execute` for
    workloads with large tensors.
    """
    cores = available_cores() if cores is None else cores
    return max(1, cores // max(1, workers))


def _set_threads(threads: int | None) -> None:
    if threads is None:
        return
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(threads)
    import torch

    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


def gpu_share(total_gpus: float, workers: int) -> float:
    """GPUs each Ray task asks for: one each when there are enough, else an equal share.

    ``min(1, total_gpus / workers)``: 4 workers on 1 GPU take 0.25 each (Ray runs all four on
    it at once), 4 workers on 8 GPUs take one each.

    Raises:
        InvalidInputError: the cluster has no GPU (tasks asking for one would never start).
    """
    if not total_gpus > 0:
        raise InvalidInputError(
            "the run's device is cuda but the Ray cluster has no GPU; use --device cpu or a "
            "cluster with GPUs"
        )
    return min(1.0, float(total_gpus) / max(1, int(workers)))


def _uses_gpu(worker) -> bool:
    """True when the worker runs on a CUDA device (its ``device`` attribute, if any)."""
    return str(getattr(worker, "device", "cpu")).startswith("cuda")


def _failure(key: str, exc: BaseException, seconds: float) -> TaskResult:
    exc = as_resource_error(exc) or exc  # a full disk or no memory is not a bug
    if isinstance(exc, EasyHOIError):
        return TaskResult(key, "failed", seconds, type(exc).__name__, str(exc), exc.exit_code)
    return TaskResult(
        key, "failed", seconds, type(exc).__name__, str(exc), EXIT_INTERNAL, internal=True
    )


def _json_ready(info) -> dict:
    import json

    if info is None:
        return {}
    if not isinstance(info, dict):
        info = {"value": info}
    return json.loads(json.dumps(info, default=str))


def run_task(worker: Worker, task: Task, threads: int | None = None) -> TaskResult:
    """Run ``worker(task)`` and record its outcome; never raises for a failing photo.

    Args:
        worker (callable): ``worker(task) -> dict | None``.
        task (Task): The photo.
        threads (int or None): Torch threads to use in this process (None: leave as is).

    Returns:
        TaskResult: ``status="ok"`` with the worker's dict in ``info``, or ``"failed"`` with the
            error. KeyboardInterrupt still propagates.
    """
    _set_threads(threads)
    t0 = time.perf_counter()
    try:
        info = _json_ready(worker(task))
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - every failure becomes a record
        logger.debug("task %s failed", task.key, exc_info=True)
        return _failure(task.key, exc, time.perf_counter() - t0)
    return TaskResult(task.key, "ok", time.perf_counter() - t0, info=info)


def execute(
    tasks: Iterable[Task],
    worker: Worker,
    *,
    engine: str = "local",
    workers: int = 1,
    threads: int | None = None,
    ray_address: str | None = None,
    mp_context: str | None = None,
) -> Iterator[TaskResult]:
    """Run ``worker`` on every task; yield one :class:`TaskResult` per task as each finishes.

    Args:
        tasks (iterable of Task): The photos (keys must be unique).
        worker (callable): Picklable ``worker(task) -> dict | None`` (see the module docstring).
        engine ({"local", "ray", "inline"}): Where to run (see the module docstring).
        workers (int): Parallel worker processes (local) or Ray CPUs of the local cluster; >= 1.
        threads (int or None): Torch threads per worker (None: :data:`DEFAULT_THREADS`);
            ignored inline.
        ray_address (str or None): Address of an existing Ray cluster (``"auto"``,
            ``"127.0.0.1:6379"``...); None starts a local one.
        mp_context (str or None): Start method of the local pool: ``"forkserver"`` or ``"spawn"``
            (None: forkserver where available).

    Yields:
        TaskResult: In completion order (sort by ``key`` for a deterministic order).

    Raises:
        InvalidInputError: Unknown engine, ``workers < 1``, duplicate keys or a worker that cannot
            be pickled.
        MissingDependencyError: ``engine="ray"`` without Ray installed.
    """
    if engine not in ENGINES:
        raise InvalidInputError(f"unknown batch engine {engine!r}; available: {', '.join(ENGINES)}")
    if not isinstance(workers, int) or workers < 1:
        raise InvalidInputError(f"workers must be an integer >= 1, got {workers!r}")
    if mp_context is None:
        mp_context = _default_start_method()
    if mp_context not in ("spawn", "forkserver"):
        raise InvalidInputError(f"mp_context must be 'spawn' or 'forkserver', got {mp_context!r}")
    tasks = list(tasks)
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise InvalidInputError("task keys must be unique within a batch")
    threads = DEFAULT_THREADS if threads is None else max(1, int(threads))
    if engine == "inline":
        return (run_task(worker, t) for t in tasks)
    _check_picklable(worker)
    if engine == "ray":
        ray = _import_ray()
        return _iter_ray(ray, tasks, worker, workers, threads, ray_address)
    return _iter_local(tasks, worker, workers, threads, mp_context)


def _check_picklable(worker) -> None:
    try:
        pickle.dumps(worker)
    except Exception as exc:  # noqa: BLE001 - any pickling failure means the same thing
        raise InvalidInputError(
            f"the batch worker {worker!r} cannot be sent to worker processes ({exc}); use a "
            "module-level function, a functools.partial of one, or a module-level class instance"
        ) from exc


# ----------------------------------------------------------------------------------------------
# local process pool
# ----------------------------------------------------------------------------------------------


def _default_start_method() -> str:
    """The local pool's start method when none is given: the fork server where the platform
    has it, else spawn."""
    return "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"


def _context(mp_context: str, preload: tuple[str, ...] = ()):
    """The multiprocessing context of the local pool. For the fork server, ``preload`` is
    imported once by the server (only applies when it starts), so every worker forked from it
    starts with them: the worker's modules (torch and the pipeline for the reconstruction
    worker) cost their import CPU once per batch instead of once per worker process. A module
    that fails to import is skipped there."""
    ctx = multiprocessing.get_context(mp_context)
    if mp_context == "forkserver":
        ctx.set_forkserver_preload(["easyhoi.distributed", *preload])
    return ctx


def _new_pool(
    workers: int, threads: int, mp_context: str, preload: tuple[str, ...] = ()
) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(
        max_workers=workers, mp_context=_context(mp_context, preload), initializer=_init_worker,
        initargs=(threads, os.getpid()),
    )  # fmt: skip


def start_fork_server(preload: tuple[str, ...] = ()) -> bool:
    """Start the local engine's fork server now, importing ``preload`` (as :func:`_new_pool`
    would at the first worker); True when there is one (False where only spawn exists).

    A batch calls this before its own set-up (the run's settings, the hand model: torch in the
    batch process), so that the fork server's imports run on the other core meanwhile instead
    of after it: the first photo starts about a second earlier. The pool created later finds
    the server running with the same preload.
    """
    if _default_start_method() != "forkserver":
        return False
    from multiprocessing import forkserver

    _context("forkserver", preload)
    forkserver.ensure_running()
    return True


def _preload(worker) -> tuple[str, ...]:
    """Modules a worker asks the fork server to import (its ``preload`` attribute, if any)."""
    names = getattr(worker, "preload", ())
    return tuple(n for n in names if isinstance(n, str))


def _init_worker(threads: int | None, batch_pid: int) -> None:
    """Worker start: end with the batch process (see :mod:`easyhoi.process_guard`), threads."""
    from easyhoi.process_guard import die_with

    die_with(batch_pid)
    _set_threads(threads)


def _iter_local(
    tasks: list[Task], worker: Worker, workers: int, threads: int, mp_context: str
) -> Iterator[TaskResult]:
    pending = deque(tasks)
    suspects: deque[Task] = deque()  # in flight when a process died: retried one at a time
    deaths: dict[str, int] = {}
    inflight: dict[Future, Task] = {}
    pool: ProcessPoolExecutor | None = None
    try:
        while pending or suspects or inflight:
            if pool is None:
                pool = _new_pool(workers, threads, mp_context, _preload(worker))
            source, limit = (suspects, 1) if suspects else (pending, workers)
            broken_on_submit = False
            while source and len(inflight) < limit:
                task = source.popleft()
                try:
                    inflight[pool.submit(run_task, worker, task, threads)] = task
                except BrokenProcessPool:
                    # a process died between two submissions: the task never started; the
                    # futures in flight resolve as broken below (or there are none)
                    source.appendleft(task)
                    broken_on_submit = True
                    break
            if broken_on_submit and not inflight:
                logger.warning("a batch worker process died; restarting the pool")
                pool.shutdown(wait=False, cancel_futures=True)
                pool = None
                continue
            done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
            if any(isinstance(f.exception(), BrokenProcessPool) for f in done):
                # every other future of a broken pool resolves too (result or broken)
                done, _ = wait(list(inflight))
            broken = False
            for fut in sorted(done, key=lambda f: inflight[f].key):
                task = inflight.pop(fut)
                exc = fut.exception()
                if exc is None:
                    yield fut.result()
                elif isinstance(exc, BrokenProcessPool):
                    broken = True
                    deaths[task.key] = deaths.get(task.key, 0) + 1
                    if deaths[task.key] >= 2:
                        yield TaskResult(
                            task.key, "failed", 0.0, WORKER_DIED,
                            "the worker process died while processing this photo (twice; "
                            "out of memory or a crash in native code)",
                            EXIT_INTERNAL, internal=True,
                        )  # fmt: skip
                    else:
                        suspects.append(task)
                else:  # the result could not be sent back (e.g. not picklable)
                    yield _failure(task.key, exc, 0.0)
            if broken:
                logger.warning("a batch worker process died; retrying its photos one at a time")
                pool.shutdown(wait=False, cancel_futures=True)
                pool = None
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


# ----------------------------------------------------------------------------------------------
# Ray
# ----------------------------------------------------------------------------------------------


def _import_ray():
    try:
        import ray
    except ImportError as exc:
        raise MissingDependencyError("ray", extra="distributed", purpose="--engine ray") from exc
    return ray


@contextlib.contextmanager
def _loopback_only(ray):
    """Make a local Ray node advertise and bind 127.0.0.1 instead of the machine's address.

    Ray replaces ``_node_ip_address="127.0.0.1"`` by a "remotely reachable" address unless its
    multi-node support is off (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, read into
    ``ray_constants.ENABLE_RAY_CLUSTER`` at import); both are switched off while the node starts
    (the processes it starts inherit the variable) and restored afterwards.
    """
    var = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    old_env = os.environ.get(var)
    os.environ[var] = "0"
    try:
        constants = importlib.import_module("ray._private.ray_constants")
    except ImportError:  # pragma: no cover - layout of another Ray version
        constants = None
    old_flag = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    if old_flag is not None:
        constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        if old_flag is not None:
            constants.ENABLE_RAY_CLUSTER = old_flag
        if old_env is None:
            os.environ.pop(var, None)
        else:
            os.environ[var] = old_env


def _ray_init(ray, workers: int, address: str | None) -> bool:
    """Connect to (or start) Ray; return True when this call started the session.

    Without ``address`` a local node with ``num_cpus=workers`` and no dashboard is started,
    listening on 127.0.0.1 only.
    """
    if ray.is_initialized():
        return False
    # Never send usage statistics (the only network traffic of a local cluster besides loopback).
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address:
        ray.init(address=address, log_to_driver=False)
        return True
    with _loopback_only(ray):
        ray.init(
            num_cpus=workers,
            include_dashboard=False,
            log_to_driver=False,
            _node_ip_address="127.0.0.1",
        )
    return True


def _iter_ray(
    ray, tasks: list[Task], worker: Worker, workers: int, threads: int, address: str | None
) -> Iterator[TaskResult]:
    started = _ray_init(ray, workers, address)
    try:
        gpus = gpu_share(ray.cluster_resources().get("GPU", 0), workers) if _uses_gpu(worker) else 0
        remote = ray.remote(num_cpus=1, num_gpus=gpus, max_retries=1)(run_task)
        worker_ref = ray.put(worker)
        refs = {remote.remote(worker_ref, t, threads): t for t in tasks}
        waiting = list(refs)
        while waiting:
            done, waiting = ray.wait(waiting, num_returns=1)
            for ref in done:
                task = refs.pop(ref)
                try:
                    yield ray.get(ref)
                except ray.exceptions.WorkerCrashedError as exc:
                    yield TaskResult(
                        task.key, "failed", 0.0, WORKER_DIED, str(exc).splitlines()[0],
                        EXIT_INTERNAL, internal=True,
                    )  # fmt: skip
                except ray.exceptions.RayError as exc:
                    yield _failure(task.key, exc, 0.0)
    finally:
        if started:
            ray.shutdown()
