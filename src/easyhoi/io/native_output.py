"""Silence what native libraries write straight to the process's file descriptors.

MediaPipe's TFLite and absl logs, V-HACD's progress and MeshFix's warnings are written by C/C++
code to file descriptor 1 or 2, past Python's ``sys.stdout`` / ``sys.stderr`` and logging, so
they would reach the user's terminal on every run (even with ``--quiet``). :func:`silenced`
points the descriptor at the null device for the duration of a call and restores it after.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator

logger = logging.getLogger("easyhoi")


@contextlib.contextmanager
def silenced(fd: int = 2, keep_when_debug: bool = True) -> Iterator[None]:
    """Send native writes to ``fd`` (1: stdout, 2: stderr) to the null device inside the block.

    Kept as they are when easyhoi's debug log is on (``--verbose``) and ``keep_when_debug``,
    or when the descriptor cannot be duplicated (a stream captured without one, as in tests).
    """
    if keep_when_debug and logger.isEnabledFor(logging.DEBUG):
        yield
        return
    stream = sys.stdout if fd == 1 else sys.stderr
    try:
        stream.flush()
        saved = os.dup(fd)
    except (OSError, ValueError, AttributeError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)
