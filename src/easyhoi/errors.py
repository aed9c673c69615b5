"""Exception hierarchy: every public boundary raises one of these, never a bare assert."""

from __future__ import annotations


class EasyHOIError(Exception):
    """Base class of every error easyhoi raises on purpose."""

    exit_code = 1


class InvalidInputError(EasyHOIError, ValueError):
    """The caller gave data of the wrong shape, type, range or content."""

    exit_code = 2


class MissingDependencyError(EasyHOIError, ImportError):
    """An optional dependency is not installed; the message names the install that fixes it."""

    exit_code = 3

    def __init__(self, package: str, extra: str | None = None, purpose: str = ""):
        fix = f"pip install 'easyhoi[{extra}]'" if extra else f"pip install {package}"
        what = f" (needed for {purpose})" if purpose else ""
        super().__init__(f"missing dependency '{package}'{what}; install it with: {fix}")
        self.package = package
        self.extra = extra


class BackendError(EasyHOIError, RuntimeError):
    """A perception or geometry backend failed on valid input."""

    exit_code = 4


class UnsafeFileError(InvalidInputError):
    """A file (for example a pickle) contains content that is refused for safety."""


class NoHandError(EasyHOIError):
    """No hand was found in the photo."""

    exit_code = 5


class NoObjectError(EasyHOIError):
    """A hand was found but no held object."""

    exit_code = 6


class OptimizationError(EasyHOIError, RuntimeError):
    """The optimizer could not produce a valid result (for example NaN losses)."""

    exit_code = 7


class LowConfidenceError(EasyHOIError):
    """Perception is unsure of a mask and the caller asked for certainty (``--strict``)."""

    exit_code = 9


def require(module: str, extra: str | None = None, purpose: str = ""):
    """Import an optional module or raise :class:`MissingDependencyError` naming the fix."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(module.split(".")[0], extra, purpose) from exc
