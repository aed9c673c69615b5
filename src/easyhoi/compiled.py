"""Compiled (numba) kernels and their slower fallbacks: one rule for every kernel.

numba is optional, and LLVM can fail on a machine where numba imports. The rule:

* a kernel module that cannot be imported (numba missing or broken) means no kernel, silently:
  the fallback is the documented path without numba;
* a kernel that fails to compile or run with one of numba's own errors warns once, naming the
  kernel and its fallback, and is not tried again in this process (a failing compile is not
  repeated at every call);
* any other exception is a bug and propagates.

Callers: the renderer's kernels (:func:`easyhoi.render._common.numba_call`, which also turns
the renderer's backend to torch), the pictures' corner normals (:mod:`easyhoi.viz.shade`) and
the cuboid fit's hull sums (:mod:`easyhoi.perception.shapes.cuboid`).
"""

from __future__ import annotations

import importlib
import warnings

__all__ = ["kernel", "run"]

#: Names of the kernels that failed in this process.
_FAILED: set[str] = set()


def kernel(module: str, name: str):
    """The compiled function ``name`` of ``module`` (built ahead of time where
    :mod:`easyhoi.aot` has it for this machine); None when the module cannot be imported or the
    kernel failed in this process."""
    if name in _FAILED:
        return None
    from easyhoi import aot

    built = aot.kernel(module, name)
    if built is not None:
        return built
    try:
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return getattr(mod, name)


def _numba_error() -> type[Exception]:
    """numba's base error class (asked for only when a kernel raised: the ``except`` clause
    evaluates it then, so the happy path costs no import)."""
    from numba.core.errors import NumbaError

    return NumbaError


def run(name: str, fn, *args, fallback: str):
    """``(True, fn(*args))``, or ``(False, None)`` when numba raises: the kernel is then marked
    failed and a warning says so once, ending with ``fallback`` (what is used instead)."""
    try:
        return True, fn(*args)
    except _numba_error() as exc:
        if name not in _FAILED:
            _FAILED.add(name)
            warnings.warn(
                f"numba kernel {name} failed ({type(exc).__name__}: {str(exc)[:200]}); {fallback}",
                RuntimeWarning,
                stacklevel=3,
            )
        return False, None
