"""Atomic writes: a file or a whole folder appears complete under its final name, or not at all.

Files are written to a temporary name in the same folder, then ``os.replace``-d: a reader (or a
run killed mid-write) sees either the old complete file or the new complete file, never a
half-written one. The temporary file lives in the destination's folder so the final rename stays
on one file system (where ``os.replace`` is atomic). :func:`publish_folder` does the same for a
folder of files.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from easyhoi.errors import InvalidInputError

__all__ = ["atomic_write_bytes", "atomic_write_text", "publish_folder"]

_CHUNK = 1 << 20


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; the parent folder must exist.

    Args:
        path (path-like): Destination file; replaced if it exists.
        data (bytes): The complete content.

    Returns:
        Path: ``path`` as a :class:`~pathlib.Path`.
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


def publish_folder(
    folder: str | os.PathLike, fill: Callable[[Path], None], required: Sequence[str] = ()
) -> Path:
    """Build a folder in a hidden temporary sibling and rename it to ``folder`` once complete.

    ``fill(tmp)`` writes every file into the temporary folder ``folder.parent /
    ".<name>.tmp-*"``. Only when it returns and every name of ``required`` is a file there is
    the folder renamed into place, so a killed run leaves no half folder under the final name.
    An existing ``folder`` is replaced only then: it is renamed aside, the new folder renamed
    in, and the old one deleted (if the second rename fails the old folder is put back).

    Args:
        folder: The final folder; its parent is created if needed.
        fill: Writes the content into the folder it is given.
        required: File names that must exist after ``fill``.

    Returns:
        ``folder`` as a :class:`~pathlib.Path`.

    Raises:
        InvalidInputError: ``folder`` has no usable name, exists as a file, or ``fill`` left a
            required file out.
        Any error of ``fill`` propagates after the temporary folder is removed; an existing
        folder is then left untouched.
    """
    final = Path(folder)
    name = final.name
    if not name or name in (".", "..") or name.startswith(".") or "\0" in name:
        raise InvalidInputError(f"result folder must have a plain name, got {str(folder)!r}")
    if final.exists() and not final.is_dir():
        raise InvalidInputError(f"{final} exists and is not a folder")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.tmp-", dir=final.parent))
    try:
        fill(tmp)
        missing = [f for f in required if not (tmp / f).is_file()]
        if missing:
            raise InvalidInputError(f"folder {final} incomplete, missing {missing}")
        tmp.chmod(0o755)
        _swap_into_place(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _swap_into_place(tmp: Path, final: Path) -> None:
    """Rename ``tmp`` to ``final``, replacing an existing ``final`` only once ``tmp`` is whole."""
    if not final.exists():
        tmp.rename(final)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
    old.rmdir()
    final.rename(old)
    try:
        tmp.rename(final)
    except BaseException:
        with contextlib.suppress(OSError):
            old.rename(final)
        raise
    if old.is_symlink():  # a link replaced by the new folder: remove the link, not its target
        old.unlink()
    else:
        shutil.rmtree(old, ignore_errors=True)
