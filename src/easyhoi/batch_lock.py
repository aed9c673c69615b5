"""One run per output folder: a lock file, stale temporaries swept, symbolic links refused.

:class:`OutputLock` holds ``OUT/.easyhoi.lock`` for the whole batch. The lock is an
``flock`` on that file, so the kernel releases it when its holder dies in any way (``kill
-9`` included): a lock file left by a dead run is taken over without any guessing from pids.
The file holds the holder's pid, host and start time, for the message a second run prints
when it refuses (or, with ``wait``, while it waits). The file is removed on release.

:func:`sweep_temporaries` removes what a killed run leaves under the output folder (only
while holding the lock, so never another live run's work): the hidden folders
``.NAME.tmp-*`` of :func:`easyhoi.io.atomic.publish_folder` that were never renamed into
place, the files ``.NAME.*.tmp`` of :func:`easyhoi.io.atomic.atomic_write_bytes`, and the
``.NAME.old-*`` folders of a replacement cut short (put back as ``NAME`` when ``NAME`` is
missing: it is the previous complete result).

:func:`check_no_links` refuses output paths that pass through a symbolic link inside the
output folder: writing through one would put results (or replace folders) outside it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import re
import shutil
import socket
import stat
import time
from collections.abc import Iterable
from pathlib import Path

from easyhoi.errors import InvalidInputError, OutputBusyError

__all__ = ["LOCK_NAME", "OutputLock", "check_no_links", "sweep_temporaries"]

logger = logging.getLogger(__name__)

LOCK_NAME = ".easyhoi.lock"

_TMP_DIR = re.compile(r"^\..+\.tmp-[^/]+$")
_OLD_DIR = re.compile(r"^\.(.+)\.old-[^/]+$")
_TMP_FILE = re.compile(r"^\..+\.tmp$")


class OutputLock:
    """Exclusive lock of an output folder (a context manager).

    Args:
        folder: The output folder (created if missing).
        wait: Wait for another holder to finish instead of refusing.
        poll: Seconds between two attempts while waiting.
        timeout: Give up waiting after this many seconds (None: wait as long as it takes).
    """

    def __init__(
        self, folder: str | os.PathLike, wait: bool = False, poll: float = 0.2,
        timeout: float | None = None,
    ):  # fmt: skip
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.wait = wait
        self.poll = poll
        self.timeout = timeout
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        """Take the lock; see the class for ``wait``.

        Raises:
            OutputBusyError: Another live process holds it (and ``wait`` is off, or the
                timeout passed).
            InvalidInputError: The lock path is a symbolic link or not a file.
        """
        self.folder.mkdir(parents=True, exist_ok=True)
        start = time.monotonic()
        told = False
        while True:
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_holder(fd)
                os.close(fd)
                waited = time.monotonic() - start
                if not self.wait or (self.timeout is not None and waited >= self.timeout):
                    raise OutputBusyError(
                        f"output folder {self.folder} is in use by another easyhoi run "
                        f"({holder}); wait for it to finish, pass --wait to start when it "
                        "does, or choose another --out"
                    ) from None
                if not told:
                    logger.warning("waiting for the other run on %s (%s)", self.folder, holder)
                    told = True
                time.sleep(self.poll)
                continue
            # the file may have been removed (by its last holder's release) between our open
            # and our lock: then this lock guards nothing; try again on the current file
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(self.path, follow_symlinks=False))
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            previous = _read_holder(fd)
            if previous != "unknown holder":
                logger.warning("taking over the lock of a run that is gone (%s)", previous)
            os.ftruncate(fd, 0)
            info = f"pid {os.getpid()} on {socket.gethostname()} since {time.ctime()}\n"
            os.pwrite(fd, info.encode(), 0)
            os.fsync(fd)
            self._fd = fd
            return self

    def _open(self) -> int:
        flags = os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | getattr(os, "O_NOFOLLOW", 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise InvalidInputError(
                    f"{self.path} is a symbolic link; refusing to use it as the lock file"
                ) from exc
            raise
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise InvalidInputError(f"{self.path} is not a file; refusing to use it as the lock")
        return fd

    def release(self) -> None:
        """Remove the lock file and release the lock (idempotent)."""
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        os.close(self._fd)
        self._fd = None

    @property
    def held(self) -> bool:
        """Whether this object holds the lock."""
        return self._fd is not None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read_holder(fd: int) -> str:
    try:
        text = os.pread(fd, 256, 0).decode("utf-8", "replace").strip()
    except OSError:
        text = ""
    return text or "unknown holder"


def sweep_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporaries a killed run left under ``folder``; returns what was removed.

    Call it only while holding the folder's :class:`OutputLock`. Symbolic links are never
    followed (a link with a temporary's name is removed itself, not its target).
    """
    root = Path(folder)
    removed: list[Path] = []
    if not root.is_dir():
        return removed
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        here = Path(dirpath)
        keep = []
        for d in dirnames:
            p = here / d
            if _TMP_DIR.match(d):
                _remove(p)
                removed.append(p)
            elif (m := _OLD_DIR.match(d)) is not None:
                final = here / m.group(1)
                if not os.path.lexists(final) and not p.is_symlink():
                    p.rename(final)  # the previous complete result, replaced only halfway
                    logger.warning("restored %s from an interrupted replacement", final)
                else:
                    _remove(p)
                    removed.append(p)
            else:
                keep.append(d)
        dirnames[:] = keep
        for f in filenames:
            if _TMP_FILE.match(f):
                p = here / f
                _remove(p)
                removed.append(p)
    if removed:
        logger.warning("removed %d temporaries left by an interrupted run in %s", len(removed),
                       root)  # fmt: skip
    return removed


def _remove(p: Path) -> None:
    if p.is_symlink() or not p.is_dir():
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
    else:
        shutil.rmtree(p, ignore_errors=True)


def check_no_links(folder: str | os.PathLike, paths: Iterable[str | os.PathLike]) -> None:
    """Refuse any of ``paths`` (inside ``folder``) that passes through a symbolic link there.

    ``folder`` itself may be a link (the user chose it); every component below it must be a
    real folder or not exist yet, and the final component must not be a link.

    Raises:
        InvalidInputError: Naming the link and where it points.
    """
    root = Path(folder)
    seen: set[Path] = set()
    for path in paths:
        rel = Path(os.path.relpath(Path(path), root))
        if rel.parts and rel.parts[0] == "..":
            raise InvalidInputError(f"output path {path} is not inside {root}")
        p = root
        for part in rel.parts:
            p = p / part
            if p in seen:
                continue
            seen.add(p)
            if p.is_symlink():
                raise InvalidInputError(
                    f"{p} is a symbolic link (to {os.readlink(p)}) inside the output folder; "
                    "results are never written through links: remove it or choose another --out"
                )
            if not p.exists():
                break
