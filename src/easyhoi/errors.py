"""Exception hierarchy and exit codes.

Every public boundary raises one of these errors, never a bare assert. Each error class carries
the exit code the command line returns for it; :class:`ExitCode` is the one table of those codes
(the CLI, the batch manifest and ``docs/bad_input.md`` all use it).
"""

from __future__ import annotations

import errno
import os
from enum import IntEnum

__all__ = [
    "EXIT_CODE_MEANINGS",
    "BackendError",
    "EasyHOIError",
    "ExitCode",
    "InputTooLargeError",
    "InvalidInputError",
    "LowConfidenceError",
    "MissingDependencyError",
    "NO_OBJECT_HINT",
    "NoHandError",
    "NoObjectError",
    "OptimizationError",
    "OutputBusyError",
    "ResourceError",
    "UnsafeFileError",
    "as_resource_error",
    "exit_code_of",
    "require",
]


class ExitCode(IntEnum):
    """Process exit codes of the ``easyhoi`` command (also recorded per photo by ``batch``)."""

    OK = 0
    ERROR = 1
    INVALID_INPUT = 2
    MISSING_DEPENDENCY = 3
    BACKEND = 4
    NO_HAND = 5
    NO_OBJECT = 6
    OPTIMIZATION = 7
    BATCH_PARTIAL = 8
    LOW_CONFIDENCE = 9
    RESOURCE = 10
    OUTPUT_BUSY = 11
    INTERNAL = 70  # EX_SOFTWARE of sysexits.h
    INTERRUPTED = 130  # 128 + SIGINT, as shells report a Ctrl-C


#: What each exit code means, in the words ``easyhoi --help`` prints.
EXIT_CODE_MEANINGS: dict[ExitCode, str] = {
    ExitCode.OK: "success",
    ExitCode.ERROR: "other easyhoi error",
    ExitCode.INVALID_INPUT: "invalid input (bad file, wrong size, bad option or value)",
    ExitCode.MISSING_DEPENDENCY: "missing optional dependency (the message names the install)",
    ExitCode.BACKEND: "a perception or geometry backend failed",
    ExitCode.NO_HAND: "no hand found in the photo",
    ExitCode.NO_OBJECT: "a hand but no held object found",
    ExitCode.OPTIMIZATION: "the optimizer could not produce a valid result",
    ExitCode.BATCH_PARTIAL: "some photos of a batch failed (see its manifest)",
    ExitCode.LOW_CONFIDENCE: "--strict and a mask or the keypoints scored low (nothing written)",
    ExitCode.RESOURCE: "out of a resource: disk full, out of memory, or an input too large",
    ExitCode.OUTPUT_BUSY: "the output folder is in use by another easyhoi run",
    ExitCode.INTERNAL: "internal error, a bug: please report it with the --verbose output",
    ExitCode.INTERRUPTED: "interrupted (Ctrl-C)",
}


def exit_code_of(exc: BaseException) -> ExitCode:
    """The exit code for an exception: its own for an :class:`EasyHOIError`, else INTERNAL."""
    if isinstance(exc, EasyHOIError):
        return ExitCode(exc.exit_code)
    if isinstance(exc, KeyboardInterrupt):
        return ExitCode.INTERRUPTED
    if as_resource_error(exc) is not None:
        return ExitCode.RESOURCE
    return ExitCode.INTERNAL


#: errno values that mean the machine ran out of something, not that the input is wrong.
_RESOURCE_ERRNOS = frozenset(
    getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EFBIG", "ENOMEM") if hasattr(errno, name)
)


def as_resource_error(exc: BaseException) -> ResourceError | None:
    """A :class:`ResourceError` for a full disk, exhausted memory or a too large image, else None.

    ``OSError`` with errno ENOSPC/EDQUOT/EFBIG/ENOMEM, ``MemoryError`` and Pillow's
    ``DecompressionBombError`` are ordinary conditions of the machine or the input, not bugs;
    the CLI and the batch runner report them with :attr:`ExitCode.RESOURCE` instead of
    :attr:`ExitCode.INTERNAL`.
    """
    if isinstance(exc, ResourceError):
        return exc
    if type(exc).__name__ == "DecompressionBombError":  # Pillow's, from a path that skipped
        return InputTooLargeError(f"image too large: {exc}")  # easyhoi.limits' header check
    if isinstance(exc, MemoryError):
        return ResourceError(f"out of memory ({exc or 'MemoryError'})")
    if isinstance(exc, OSError) and exc.errno in _RESOURCE_ERRNOS:
        where = f": {exc.filename}" if exc.filename else ""
        what = "disk full" if exc.errno != getattr(errno, "ENOMEM", None) else "out of memory"
        return ResourceError(f"{what} ({os.strerror(exc.errno)}{where})")
    return None


class EasyHOIError(Exception):
    """Base class of every error easyhoi raises on purpose."""

    exit_code = ExitCode.ERROR


class InvalidInputError(EasyHOIError, ValueError):
    """The caller gave data of the wrong shape, type, range or content."""

    exit_code = ExitCode.INVALID_INPUT


class MissingDependencyError(EasyHOIError, ImportError):
    """An optional dependency is not installed; the message names the install that fixes it."""

    exit_code = ExitCode.MISSING_DEPENDENCY

    def __init__(self, package: str, extra: str | None = None, purpose: str = ""):
        fix = f"pip install 'easyhoi[{extra}]'" if extra else f"pip install {package}"
        what = f" (needed for {purpose})" if purpose else ""
        super().__init__(f"missing dependency '{package}'{what}; install it with: {fix}")
        self.package = package
        self.extra = extra


class BackendError(EasyHOIError, RuntimeError):
    """A perception or geometry backend failed on valid input."""

    exit_code = ExitCode.BACKEND


class UnsafeFileError(InvalidInputError):
    """A file (for example a pickle) contains content that is refused for safety."""


class NoHandError(EasyHOIError):
    """No hand was found in the photo."""

    exit_code = ExitCode.NO_HAND


class NoObjectError(EasyHOIError):
    """A hand was found but no held object."""

    exit_code = ExitCode.NO_OBJECT


#: What the automatic path's :class:`NoObjectError` suggests (the web demo words it its own
#: way, ``app_request``): a point inside the object makes the segmenter look there.
NO_OBJECT_HINT = (
    ": if a hand holds one, point inside it (--object-point X,Y or --object-box "
    "X0,Y0,X1,Y1; object_point or object_box rows in a batch's prompts file)"
)


class OptimizationError(EasyHOIError, RuntimeError):
    """The optimizer could not produce a valid result (for example NaN losses)."""

    exit_code = ExitCode.OPTIMIZATION


class LowConfidenceError(EasyHOIError):
    """Perception is unsure of a mask or of the hand's keypoints and the caller asked for
    certainty (``--strict``)."""

    exit_code = ExitCode.LOW_CONFIDENCE


class ResourceError(EasyHOIError, RuntimeError):
    """The machine ran out of something: disk space, memory, or the input exceeds a size limit."""

    exit_code = ExitCode.RESOURCE


class InputTooLargeError(ResourceError, InvalidInputError):
    """An input (photo pixels, file bytes, mesh faces) exceeds its documented limit.

    Exit code ``RESOURCE`` (the machine could not afford it); also an
    :class:`InvalidInputError`, so every handler of bad input reports it as one.
    """


class OutputBusyError(EasyHOIError):
    """Another easyhoi run holds the lock of the output folder."""

    exit_code = ExitCode.OUTPUT_BUSY


def require(module: str, extra: str | None = None, purpose: str = ""):
    """Import an optional module or raise :class:`MissingDependencyError` naming the fix."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(module.split(".")[0], extra, purpose) from exc
