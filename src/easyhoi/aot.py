"""The compiled kernels built ahead of time, so that a fresh process does not start numba.

The kernels of :mod:`easyhoi.render._numba_kernels`, :mod:`easyhoi.perception.shapes._hull_kernel`
and :mod:`easyhoi.viz._normals_kernel` are numba functions. Even with numba's on-disk cache, the
first call in a process imports numba and builds its typing and lowering tables: about 0.6 s of
CPU, a tenth of a cold reconstruction. ``python -m easyhoi.aot`` (run by ``make``) compiles the
same functions, for the argument types the pipeline passes, into one extension module
(``easyhoi/_aot_kernels*.so``, numba's ahead-of-time compiler) for this machine's CPU. Loading it
costs a millisecond and no numba import. The functions are compiled from the same source by the
same compiler with the same options and CPU target, so they return the same bits as the numba
functions (``tests/test_aot_kernels.py`` checks every export against them).

:func:`kernel` returns a :class:`Kernel`: it calls the ahead-of-time export whose argument
types match the call exactly, and any other call (another dtype or memory layout) goes to the
numba function, imported on first need. The module is used only when its stamp
(``_aot_kernels.json``) matches the kernels' source files, this CPU's instruction-set flags and
the NumPy it was built against; otherwise (not built, sources edited since, copied to another
machine) the numba functions are used, as without it. ``EASYHOI_AOT=0`` turns it off.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import sys
from pathlib import Path

import numpy as np

__all__ = ["EXPORTS", "Kernel", "build", "kernel", "loaded"]

PACKAGE = Path(__file__).resolve().parent
MODULE = "_aot_kernels"
STAMP = PACKAGE / f"{MODULE}.json"
#: The modules whose numba functions are compiled, and the source files the stamp hashes.
SOURCES = {
    "easyhoi.render._numba_kernels": "render/_numba_kernels.py",
    "easyhoi.perception.shapes._hull_kernel": "perception/shapes/_hull_kernel.py",
    "easyhoi.viz._normals_kernel": "viz/_normals_kernel.py",
}
_R, _H, _N = SOURCES
#: (module, function, return type ("" for none, a tuple of types for a tuple), argument types):
#: one export per argument-type tuple, the types the pipeline passes (float32 renders of the
#: optimizer, float64 ones of the pictures and metrics, the z-buffer with and without face ids).
EXPORTS = (
    *(
        (_R, "soft_logsum_forward", "", (f"{t}[:,::1]", "i8[::1]", "i8", "i8", "f8", "f8", "i8",
                                         f"{t}[::1]"))
        for t in ("f4", "f8")
    ),
    *(
        (_R, "soft_logsum_backward", "", (f"{t}[:,::1]", "i8[::1]", "i8", "i8", "f8", "f8",
                                          f"{t}[::1]", f"{t}[:,::1]"))
        for t in ("f4", "f8")
    ),
    *((_R, "zbuffer", "", (f"{t}[:,::1]", f"{t}[:,::1]", "i8", "i8", f"{t}[::1]"))
      for t in ("f4", "f8")),
    *((_R, "zbuffer", "", (f"{t}[:,::1]", f"{t}[:,::1]", "i8", "i8", f"{t}[::1]", "i8[::1]"))
      for t in ("f4", "f8")),
    *((_R, "min_filter", "", (f"{t}[:,::1]", "i8", f"{t}[:,::1]")) for t in ("f4", "f8")),
    (_H, "hull_weight_sums", ("i8", "i8", "b1"), ("f4[:,::1]", "i8[:,::1]", "i8[:,::1]")),
    (_N, "corner_sums", "f8[:,::1]", ("i8[:,::1]", "i8", "f8[:,::1]", "f8[:,::1]", "f8")),
)  # fmt: skip


def _arg_key(spec: str):
    """The dispatch key of an argument type of :data:`EXPORTS` (what :func:`_call_key` gives)."""
    if "[" not in spec:
        return spec
    dtype, dims = spec.split("[")
    dims = dims.rstrip("]").split(",")
    layout = "C" if dims[-1] == "::1" else "F" if dims[0] == "::1" else "A"
    return (np.dtype(dtype).str, len(dims), layout)


def _call_key(args) -> tuple:
    """Argument types as numba would type them: arrays by dtype, rank and layout (C before F,
    as numba checks them), Python and NumPy scalars by their exact type."""
    key = []
    for a in args:
        if isinstance(a, np.ndarray):
            lay = "C" if a.flags.c_contiguous else "F" if a.flags.f_contiguous else "A"
            key.append((a.dtype.str, a.ndim, lay))
        elif isinstance(a, (bool, np.bool_)):
            key.append("b1")
        elif isinstance(a, (int, np.int64)):
            key.append("i8")
        elif isinstance(a, (float, np.float64)):
            key.append("f8")
        else:
            key.append(type(a).__name__)
    return tuple(key)


def _export_name(module: str, name: str, args: tuple) -> str:
    digest = hashlib.sha1(repr((module, name, args)).encode()).hexdigest()[:10]
    return f"{name}_{digest}"


def _cpu_flags() -> str:
    """This CPU's model name and instruction-set flags (Linux), or "" where unknown."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""
    lines = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("flags", "model name") and key not in lines:
            lines[key] = value.strip()
        if len(lines) == 2:
            break
    return json.dumps(lines, sort_keys=True) if "flags" in lines else ""


def _stamp() -> dict | None:
    """What the built module must match here: sources, CPU, NumPy, Python."""
    cpu = _cpu_flags()
    if not cpu:
        return None
    h = hashlib.sha256()
    for rel in SOURCES.values():
        h.update((PACKAGE / rel).read_bytes())
    h.update(repr(EXPORTS).encode())
    return {
        "sources": h.hexdigest(),
        "cpu": hashlib.sha256(cpu.encode()).hexdigest(),
        "numpy": np.__version__,
        "python": list(sys.version_info[:2]),
    }


_STATE: dict = {}


def loaded():
    """The built extension module when it is valid here (module docs), else None; checked once
    per process."""
    if "mod" not in _STATE:
        _STATE["mod"] = _load()
    return _STATE["mod"]


def _load():
    if os.environ.get("EASYHOI_AOT", "1") == "0":
        return None
    try:
        built = json.loads(STAMP.read_text())
        want = _stamp()
    except (OSError, ValueError):
        return None
    if want is None or built != want:
        return None
    try:
        return importlib.import_module(f"easyhoi.{MODULE}")
    except ImportError:
        return None


class Kernel:
    """A kernel by name: the ahead-of-time export matching a call's argument types, else the
    numba function (imported on first need)."""

    __slots__ = ("module", "name", "exports", "_jit")

    def __init__(self, module: str, name: str, exports: dict):
        self.module, self.name, self.exports, self._jit = module, name, exports, None

    def jit(self):
        """The numba function itself."""
        if self._jit is None:
            self._jit = getattr(importlib.import_module(self.module), self.name)
        return self._jit

    def __call__(self, *args):
        fn = self.exports.get(_call_key(args))
        if fn is None:
            fn = self.jit()
        return fn(*args)


def kernel(module: str, name: str, built=None) -> Kernel | None:
    """:class:`Kernel` ``name`` of ``module`` when the built module (``built``, default
    :func:`loaded`) is valid here and exports it, else None (the caller imports the numba
    function itself)."""
    mod = loaded() if built is None else built
    if mod is None:
        return None
    exports = {
        tuple(_arg_key(a) for a in args): getattr(mod, _export_name(m, n, args))
        for m, n, _, args in EXPORTS
        if (m, n) == (module, name)
    }
    return Kernel(module, name, exports) if exports else None


def _wrapper(fn, n: int, returns: bool):
    """A fixed-arity function calling ``fn`` (numba's compiler exports fixed signatures)."""
    args = ", ".join(f"a{i}" for i in range(n))
    body = f"return fn({args})" if returns else f"fn({args})"
    scope = {"fn": fn}
    exec(f"def wrapper({args}):\n    {body}\n", scope)  # noqa: S102 - generated arity only
    return scope["wrapper"]


def build(out_dir: Path = PACKAGE, verbose: bool = False) -> Path:
    """Compile :data:`EXPORTS` into ``out_dir/_aot_kernels*.so`` and write its stamp; returns the
    module's path. The module is compiled in a temporary folder and renamed into place, so a
    failed build leaves the previous one (a process never sees half a file). Raises RuntimeError
    when this machine cannot (no C compiler, no /proc/cpuinfo, no numba).
    """
    import shutil
    import tempfile
    import warnings

    stamp = _stamp()
    if stamp is None:
        raise RuntimeError("the CPU's flags cannot be read (/proc/cpuinfo); nothing built")
    out_dir = Path(out_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc announces its own deprecation
        try:
            import llvmlite.binding as ll
            from numba.pycc import CC
        except ImportError as exc:
            raise RuntimeError(f"numba's ahead-of-time compiler is not available ({exc})") from exc

        tmp_dir = Path(tempfile.mkdtemp(prefix=f".{MODULE}-", dir=out_dir))
        try:
            cc = CC(MODULE)
            cc.output_dir = str(tmp_dir)
            cc.target_cpu = ll.get_host_cpu_name()
            cc.verbose = verbose
            for module, name, ret, args in EXPORTS:
                fn = getattr(importlib.import_module(module), name)
                res = ret or "void"
                if isinstance(ret, tuple):
                    res = f"Tuple(({', '.join(ret)}))"
                sig = f"{res}({', '.join(args)})"
                wrapper = _wrapper(fn, len(args), bool(ret))
                cc.export(_export_name(module, name, args), sig)(wrapper)
            try:
                cc.compile()
            except Exception as exc:  # noqa: BLE001 - compiler failures have no common type
                raise RuntimeError(
                    f"compiling the kernels failed: {type(exc).__name__}: {exc}"
                ) from exc
            built = sorted(tmp_dir.glob(f"{MODULE}*.so"))
            if not built:
                raise RuntimeError("the compiler wrote no module")
            target = out_dir / built[0].name
            built[0].replace(target)
        finally:
            shutil.rmtree(tmp_dir, ignore_errors=True)
    if out_dir.resolve() == PACKAGE:
        from easyhoi.io.atomic import atomic_write_text

        atomic_write_text(STAMP, json.dumps(stamp, indent=1) + "\n")
    _STATE.clear()
    return target


def main(argv: list[str] | None = None) -> int:
    import argparse
    import time

    ap = argparse.ArgumentParser(
        prog="python -m easyhoi.aot",
        description="Compile easyhoi's numba kernels ahead of time for this machine "
        "(faster start of every reconstruction; optional).",
    )
    ap.add_argument("--verbose", action="store_true", help="show the compiler's commands")
    ns = ap.parse_args(argv)
    t0 = time.perf_counter()
    try:
        path = build(verbose=ns.verbose)
    except RuntimeError as exc:
        sys.stdout.write(f"easyhoi.aot: not built ({exc}); the numba kernels are used instead\n")
        return 1
    took = time.perf_counter() - t0
    sys.stdout.write(f"easyhoi.aot: built {path.name} ({len(EXPORTS)} kernels) in {took:.1f} s\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
