"""Limits every input is checked against before any work, and the output-folder check.

Each limit is a size no ordinary use comes near and past which the work would exhaust the
machine (memory, minutes) rather than fail cleanly. An input over a limit is refused with
:class:`~easyhoi.errors.InputTooLargeError` (exit code ``RESOURCE``) naming the limit, before
the expensive step starts: a photo's pixel count is read from its header, never by decoding it.

Other limits live next to the loader they guard: pickles in :mod:`easyhoi.hand.safe_pickle`,
object meshes in :mod:`easyhoi.perception.importers`, the seed and config values in
:mod:`easyhoi.config`.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path

from easyhoi.errors import InputTooLargeError, InvalidInputError, ResourceError

__all__ = [
    "MAX_IMAGE_FILE_BYTES",
    "MAX_IMAGE_PIXELS",
    "MIN_FREE_BYTES",
    "check_image_header",
    "check_output_folder",
    "declared_face_count",
    "image_size_error",
]

#: Largest photo accepted, in pixels (width x height): 120 MP holds every phone and most
#: camera sensors at full resolution (108 MP phones, 100 MP medium format). Decoding one takes
#: ~360 MB as 8-bit RGB, and conversions need a few copies; photos are downscaled to a 1600 px
#: side right after decoding, so more pixels only cost memory and time.
MAX_IMAGE_PIXELS = 120_000_000

#: Largest photo file accepted, in bytes (an uncompressed 16-bit RGB TIFF of 120 MP is 720 MB;
#: compressed photos of that size are far smaller).
MAX_IMAGE_FILE_BYTES = 768 * 1024 * 1024

#: Free space an output folder needs before a run starts: a result folder is a few MB
#: (meshes, pictures, report); less than this means the disk is as good as full.
MIN_FREE_BYTES = 64 * 1024 * 1024


def image_size_error(path, width: int, height: int) -> InputTooLargeError:
    """The error for a photo of ``width`` x ``height`` pixels over :data:`MAX_IMAGE_PIXELS`."""
    return InputTooLargeError(
        f"image {path} is too large: {width}x{height} = {width * height / 1e6:.0f} MP; at most "
        f"{MAX_IMAGE_PIXELS / 1e6:.0f} MP are accepted (downscale the photo first)"
    )


def check_image_header(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from an image file's header, refusing files over the limits.

    Only the header is read (Pillow opens lazily), so a decompression bomb (a small file that
    declares billions of pixels) is refused in milliseconds and without allocating its pixels.

    Raises:
        InvalidInputError: Missing or empty file, or not an image.
        InputTooLargeError: More than :data:`MAX_IMAGE_FILE_BYTES` bytes or
            :data:`MAX_IMAGE_PIXELS` pixels.
    """
    from PIL import Image

    p = Path(path)
    if not p.exists():
        raise InvalidInputError(f"image file not found: {p}")
    if not p.is_file():
        raise InvalidInputError(f"image path is not a file: {p}")
    size = p.stat().st_size
    if size == 0:
        raise InvalidInputError(f"image file is empty (0 bytes): {p}")
    if size > MAX_IMAGE_FILE_BYTES:
        raise InputTooLargeError(
            f"image file {p} is too large: {size / 2**20:.0f} MiB; at most "
            f"{MAX_IMAGE_FILE_BYTES // 2**20} MiB are accepted"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as img:
                w, h = img.size
    except Image.DecompressionBombError as exc:  # Pillow's own limit, far above ours
        m = re.search(r"\((\d+) pixels\)", str(exc))
        count = f"{int(m.group(1)) / 1e6:.0f} MP" if m else "beyond Pillow's limit"
        raise InputTooLargeError(
            f"image {p} is too large: {count}; at most {MAX_IMAGE_PIXELS / 1e6:.0f} MP are "
            "accepted (downscale the photo first)"
        ) from exc
    except (OSError, SyntaxError, ValueError) as exc:
        raise unreadable_image_error(p, exc) from exc
    if w * h > MAX_IMAGE_PIXELS:
        raise image_size_error(p, w, h)
    return int(w), int(h)


def check_output_folder(out: str | os.PathLike, what: str = "--out") -> Path:
    """Refuse an output folder that cannot be written, before any work is done.

    The check writes: a probe folder is created (and removed) in ``out``, or in its nearest
    existing ancestor when ``out`` does not exist yet, so read-only and pseudo file systems
    (``/proc``, ``/sys``) and missing permissions are found even when running as root, where
    ``os.access`` answers yes. Nothing is left behind.

    Returns:
        ``out`` as a :class:`~pathlib.Path`.

    Raises:
        InvalidInputError: ``out`` or an ancestor is a file, or the folder cannot be written.
        ResourceError: Less than :data:`MIN_FREE_BYTES` free on its file system.
    """
    out = Path(out)
    p = out
    while not os.path.lexists(p) and p != p.parent:
        p = p.parent
    if not p.is_dir():
        raise InvalidInputError(f"cannot write to {what} {out}: {p} exists and is not a folder")
    try:
        probe = tempfile.mkdtemp(prefix=".easyhoi-probe-", dir=p)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise ResourceError(f"cannot write to {what} {out}: disk full ({p})") from exc
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            why = "read-only file system" if exc.errno == errno.EROFS else "no write permission"
            raise InvalidInputError(f"cannot write to {what} {out}: {why} on {p}") from exc
        raise InvalidInputError(
            f"cannot write to {what} {out}: cannot create files in {p} "
            f"({os.strerror(exc.errno) if exc.errno else exc})"
        ) from exc
    shutil.rmtree(probe, ignore_errors=True)
    try:
        st = os.statvfs(p)
    except OSError:  # pragma: no cover - statvfs exists on every POSIX file system
        return out
    free = st.f_bavail * st.f_frsize
    if st.f_blocks and free < MIN_FREE_BYTES:
        raise ResourceError(
            f"cannot write to {what} {out}: only {free / 2**20:.0f} MiB free on its disk; "
            f"at least {MIN_FREE_BYTES // 2**20} MiB are needed"
        )
    return out


def declared_face_count(path: str | os.PathLike) -> int | None:
    """A mesh file's face count read without parsing the mesh, or None when it cannot be told.

    PLY and OFF declare it in their header, a binary STL at byte 80; an OBJ's ``f`` lines are
    counted in one pass over the bytes (about 0.1 s per 100 MB). Lets a mesh with millions of
    faces be refused before a parser spends minutes and gigabytes on it.
    """
    p = Path(path)
    ext = p.suffix.lower()
    try:
        with open(p, "rb") as f:
            if ext == ".ply":
                head = f.read(4096).split(b"end_header", 1)[0]
                m = re.search(rb"element\s+face\s+(\d+)", head)
                return int(m.group(1)) if m else None
            if ext == ".off":
                for line in f.read(4096).splitlines()[:8]:
                    parts = line.split(b"#", 1)[0].split()
                    if len(parts) == 3 and all(x.isdigit() for x in parts):
                        return int(parts[1])
                return None
            if ext == ".stl":
                head = f.read(84)
                if len(head) == 84 and not head.lstrip().lower().startswith(b"solid"):
                    return int.from_bytes(head[80:84], "little")
                return None
            if ext == ".obj":
                count, tail = 0, b"\n"
                while chunk := f.read(1 << 24):
                    data = tail + chunk
                    count += data.count(b"\nf ") + data.count(b"\nf\t")
                    tail = data[-2:]  # a match across the boundary starts in these 2 bytes
                return count
    except OSError:
        return None
    return None


def unreadable_image_error(path, exc: Exception) -> InvalidInputError:
    """The error for a file Pillow cannot identify (not an image) or cannot decode (corrupt)."""
    from PIL import UnidentifiedImageError

    if isinstance(exc, UnidentifiedImageError):
        return InvalidInputError(
            f"cannot read {path}: not an image in a supported format (JPEG, PNG, WebP, BMP, "
            "TIFF...)"
        )
    return InvalidInputError(f"cannot decode image {path}: corrupt or truncated ({exc})")
