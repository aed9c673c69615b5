"""Atomic file writes: write to a temporary name in the same folder, then ``os.replace``.

A reader (or a run killed mid-write) sees either the old complete file or the new complete
file, never a half-written one. The temporary file lives in the destination's folder so the
final rename stays on one file system (where ``os.replace`` is atomic).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "atomic_write_text"]

_CHUNK = 1 << 20


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; the parent folder must exist.

    Parameters
    ----------
    path : path-like
        Destination file; replaced if it exists.
    data : bytes
        The complete content.

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path`.

    On any exception (full disk, interruption) the temporary file is removed, an existing
    ``path`` is left untouched, and the exception propagates.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            view = memoryview(data)
            for start in range(0, len(view), _CHUNK):
                f.write(view[start : start + _CHUNK])
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    return atomic_write_bytes(path, text.encode(encoding))
