"""Batch worker processes that end with the batch: nothing keeps running after ``kill -9``.

The local engine's workers are forked from a fork server, not from the batch process itself,
and each holds the pipe that keeps the fork server alive; so when the batch process is killed
outright (no Python cleanup runs) nothing tells them, and they would finish their photo, write a
result nobody records, and idle. :func:`die_with` is called in each worker when it starts:

- on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` ends the worker when its direct parent (the
  fork server) dies;
- a daemon thread waits on the batch process itself: a pidfd on Linux >= 5.3 (``select``
  wakes when the process exits; no polling, and a reused pid cannot be mistaken for it), else
  a check every ``poll`` seconds that the pid still exists and is still our ancestor. When the
  batch process is gone the worker kills itself with SIGKILL at once (a result folder it was
  writing is a hidden temporary, swept by the next run; see :mod:`easyhoi.batch_lock`).

When the workers are gone the fork server sees its pipe close and exits too.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import sys
import threading

__all__ = ["die_with", "set_parent_death_signal"]

_PR_SET_PDEATHSIG = 1


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent dies (Linux only).

    Returns whether it was set.
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):  # pragma: no cover - no prctl in this libc
        return False


def _kill_self() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _watch_pidfd(fd: int) -> None:
    with contextlib.suppress(OSError, ValueError):
        select.select([fd], [], [])
    _kill_self()


def _watch_poll(pid: int, poll: float) -> None:
    import time

    while True:
        time.sleep(poll)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            _kill_self()
        except PermissionError:  # the pid was reused by another user's process
            _kill_self()


def die_with(pid: int, poll: float = 0.5) -> None:
    """End this process (SIGKILL) as soon as process ``pid`` ends; see the module docstring.

    Args:
        pid: The batch process (an ancestor of this worker).
        poll: Seconds between checks where no pidfd is available.
    """
    set_parent_death_signal()
    if pid == os.getpid():
        return
    fd = None
    if hasattr(os, "pidfd_open"):
        try:
            fd = os.pidfd_open(pid)
        except ProcessLookupError:  # already gone
            _kill_self()
        except OSError:  # pragma: no cover - kernel older than 5.3
            fd = None
    if fd is not None:
        target, args = _watch_pidfd, (fd,)
    else:  # pragma: no cover - not Linux
        target, args = _watch_poll, (pid, poll)
    threading.Thread(target=target, args=args, name="easyhoi-die-with", daemon=True).start()
