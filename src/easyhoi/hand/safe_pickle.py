"""A restricted unpickler for MANO model files (Python-2 pickles of numpy, scipy and chumpy).

MANO files are Python-2 pickles that contain numpy arrays, a ``scipy.sparse`` joint regressor
and ``chumpy`` objects (``chumpy.ch.Ch`` holds its value in its state under ``'x'``; lazy
expressions such as ``chumpy.reordering.Select`` hold their operands). ``chumpy`` does not
import on modern NumPy, and a plain ``pickle.load`` would execute whatever callable a file
names. :func:`load_mano_pickle` uses an unpickler whose ``find_class`` resolves only a short
allow-list:

- numpy array and dtype reconstruction (``numpy.core`` and ``numpy._core`` spellings);
- ``scipy.sparse`` csc / csr matrices (mapped to stand-ins rebuilt from their arrays);
- ``copy_reg._reconstructor`` / ``copyreg._reconstructor`` restricted to the classes above;
- ``builtins`` ``set``, ``frozenset`` and ``object``; ``_codecs.encode`` for latin-1 only;
- chumpy classes, mapped to stand-ins that record their pickled state and are evaluated to
  plain numpy arrays once loading is done.

Everything else (``os.system``, ``builtins.eval``, ``subprocess.Popen``...) raises
:class:`~easyhoi.errors.UnsafeFileError` naming the refused global, before anything runs.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from easyhoi.errors import InputTooLargeError, InvalidInputError, UnsafeFileError

__all__ = ["load_mano_pickle", "RestrictedUnpickler", "ChumpyStandIn"]


# ----------------------------------------------------------------------------------------------
# Stand-in classes
# ----------------------------------------------------------------------------------------------


class _StateHolder:
    """Base of the stand-ins: records the pickled state and nothing else.

    ``__setstate__`` is defined so that pickle's BUILD opcode always goes through it (it never
    falls back to setting attributes, not even on the class object itself).
    """

    __slots__ = ("state", "args")

    def __new__(cls, *args):
        obj = object.__new__(cls)
        obj.args = args
        obj.state = None
        return obj

    def __setstate__(self, state):
        self.state = state

    def __reduce__(self):  # never re-pickle a stand-in by accident
        raise TypeError(f"{type(self).__name__} is a loading stand-in and cannot be pickled")


class ChumpyStandIn(_StateHolder):
    """A chumpy object (``chumpy.<module>.<name>``) seen in a pickle; see :func:`to_plain`."""

    __slots__ = ()
    chumpy_name: str = "Ch"


class _SparseStandIn(_StateHolder):
    __slots__ = ()
    sparse_format: str = "csc"


def _chumpy_class(name: str) -> type[ChumpyStandIn]:
    return type(f"Chumpy_{name}", (ChumpyStandIn,), {"__slots__": (), "chumpy_name": name})


def _sparse_class(fmt: str) -> type[_SparseStandIn]:
    return type(f"Sparse_{fmt}", (_SparseStandIn,), {"__slots__": (), "sparse_format": fmt})


# chumpy class name -> (operand names, evaluation on the evaluated operands and the state)
def _binary(fn):
    return lambda ops, st: fn(ops["a"], ops["b"])


_CHUMPY_EVAL: dict[str, tuple[tuple[str, ...], Any]] = {
    "Ch": (("x",), lambda ops, st: ops["x"]),
    "Select": (
        ("a",),
        lambda ops, st: _select(ops["a"], st),
    ),
    "Reshape": (("a",), lambda ops, st: ops["a"].reshape(_plain_shape(st.get("newshape")))),
    "transpose": (("a",), lambda ops, st: np.transpose(ops["a"], st.get("axes"))),
    "add": (("a", "b"), _binary(np.add)),
    "subtract": (("a", "b"), _binary(np.subtract)),
    "multiply": (("a", "b"), _binary(np.multiply)),
    "divide": (("x1", "x2"), lambda ops, st: np.divide(ops["x1"], ops["x2"])),
    "negative": (("x",), lambda ops, st: np.negative(ops["x"])),
    "MatVecMult": (("mtx", "vec"), lambda ops, st: _matvec(ops["mtx"], ops["vec"])),
}

#: module -> chumpy class names the unpickler accepts from it
_CHUMPY_MODULES: dict[str, tuple[str, ...]] = {
    "chumpy": ("Ch",),
    "chumpy.ch": ("Ch", "MatVecMult"),
    "chumpy.reordering": ("Select", "Reshape", "transpose"),
    "chumpy.ch_ops": ("add", "subtract", "multiply", "divide", "negative"),
}


def _plain_shape(shape) -> tuple[int, ...]:
    if isinstance(shape, int | np.integer):
        return (int(shape),)
    if isinstance(shape, tuple | list) and all(isinstance(s, int | np.integer) for s in shape):
        return tuple(int(s) for s in shape)
    raise UnsafeFileError(f"malformed chumpy shape {shape!r} in the pickle")


def _select(a: np.ndarray, state: dict) -> np.ndarray:
    idxs = np.asarray(_plain(state.get("idxs"), 0))
    if idxs.dtype.kind not in "iu":
        raise UnsafeFileError("malformed chumpy Select: its indices are not integers")
    out = a.ravel()[idxs.ravel()]
    if "preferred_shape" in state and state["preferred_shape"] is not None:
        out = out.reshape(_plain_shape(state["preferred_shape"]))
    return out


def _matvec(mtx, vec) -> np.ndarray:
    return np.asarray(mtx @ np.asarray(vec).ravel()).reshape(-1, 1)


def _chumpy_value(obj: ChumpyStandIn, depth: int) -> np.ndarray:
    state = obj.state
    if not isinstance(state, dict):
        raise UnsafeFileError(f"chumpy {obj.chumpy_name} object without a state dictionary")
    operands, fn = _CHUMPY_EVAL[obj.chumpy_name]
    ops = {}
    for name in operands:
        if name not in state:
            raise UnsafeFileError(f"chumpy {obj.chumpy_name} object lacks its operand {name!r}")
        value = _plain(state[name], depth + 1)
        ops[name] = value if sp.issparse(value) else np.asarray(value)
    return np.asarray(fn(ops, state))


def _sparse_value(obj: _SparseStandIn) -> sp.spmatrix:
    st = obj.state
    if not isinstance(st, dict):
        raise UnsafeFileError("scipy.sparse matrix without a state dictionary in the pickle")
    try:
        shape = st["_shape"] if "_shape" in st else st["shape"]
        arrays = tuple(np.asarray(st[k]) for k in ("data", "indices", "indptr"))
    except KeyError as exc:
        raise UnsafeFileError(f"scipy.sparse matrix in the pickle lacks {exc}") from None
    cls = sp.csc_matrix if obj.sparse_format == "csc" else sp.csr_matrix
    return cls(arrays, shape=_plain_shape(shape))


#: Largest pickle read (bytes). A MANO model file is about 4 MB and a hand-parameter file a few
#: kB; the unpickler allocates in proportion to the file, so this bounds its memory too.
MAX_PICKLE_BYTES = 256 * 1024 * 1024

#: Largest number of values the loaded content may expand to when every reference to a shared
#: list, tuple, dict or chumpy object is counted as a copy. A MANO file expands to a few hundred;
#: a few hundred bytes of lists that each reference the previous one twice expand to 2**depth.
MAX_EXPANDED_VALUES = 1_000_000


def _children(obj) -> list:
    if isinstance(obj, _StateHolder):
        return [obj.state] if isinstance(obj.state, dict | list | tuple) else []
    if isinstance(obj, dict):
        return list(obj.values())
    if isinstance(obj, list | tuple):
        return list(obj)
    return []


def check_expansion(obj, limit: int = MAX_EXPANDED_VALUES) -> int:
    """Number of values ``obj`` holds with shared references counted once per reference.

    Refuses (:class:`~easyhoi.errors.UnsafeFileError`) a container that contains itself and
    content that expands beyond ``limit`` values, in time linear in the distinct containers
    (each one's expanded size is computed once), before anything walks the content as a tree.
    """
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[object, bool]] = [(obj, False)]
    keep = []  # keeps visited objects alive so their ids stay unique
    while stack:
        node, done = stack.pop()
        kids = _children(node)
        if not kids and not isinstance(node, dict | list | tuple | _StateHolder):
            continue
        key = id(node)
        if done:
            on_path.discard(key)
            total = 1 + sum(sizes.get(id(k), 1) for k in _children(node))
            if total > limit:
                raise UnsafeFileError(
                    f"refused the pickle: its containers reference each other so often that "
                    f"it expands to more than {limit:,} values"
                )
            sizes[key] = total
            continue
        if key in sizes:
            continue
        if key in on_path:
            raise UnsafeFileError("refused the pickle: a container in it contains itself")
        on_path.add(key)
        keep.append(node)
        stack.append((node, True))
        for k in kids:
            if isinstance(k, dict | list | tuple | _StateHolder) and id(k) not in sizes:
                if id(k) in on_path:
                    raise UnsafeFileError("refused the pickle: a container in it contains itself")
                stack.append((k, False))
    return sizes.get(id(obj), 1)


def to_plain(obj):
    """Replace every stand-in inside ``obj`` (recursively) by a numpy array / sparse matrix,
    after bounding the work (:func:`check_expansion`)."""
    check_expansion(obj)
    return _plain(obj, 0)


def _plain(obj, depth: int):
    """:func:`to_plain` on content whose expansion is already checked."""
    if depth > 64:
        raise UnsafeFileError("chumpy expression nested too deeply")
    if isinstance(obj, ChumpyStandIn):
        return _chumpy_value(obj, depth)
    if isinstance(obj, _SparseStandIn):
        return _sparse_value(obj)
    if isinstance(obj, dict):
        return {k: _plain(v, depth + 1) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_plain(v, depth + 1) for v in obj)
    return obj


def read_pickle_bytes(path: Path, what: str = "pickle") -> bytes:
    """The bytes of ``path``, refusing files over :data:`MAX_PICKLE_BYTES` before reading."""
    try:
        size = path.stat().st_size
        if size > MAX_PICKLE_BYTES:
            raise InputTooLargeError(
                f"{path} is {size / 2**20:.0f} MiB; a {what} larger than "
                f"{MAX_PICKLE_BYTES // 2**20} MiB is refused"
            )
        return path.read_bytes()
    except OSError as exc:
        raise InvalidInputError(f"cannot read the {what} {path}: {exc}") from None


def load_restricted(path: Path, what: str = "pickle"):
    """Unpickle ``path`` with :class:`RestrictedUnpickler` after the size check (no stand-in
    evaluation; see :func:`to_plain`)."""
    import io

    data = read_pickle_bytes(path, what)
    return RestrictedUnpickler(io.BytesIO(data)).load()


# ----------------------------------------------------------------------------------------------
# The unpickler
# ----------------------------------------------------------------------------------------------


def _numpy_function(modules: tuple[str, ...], name: str):
    """The first ``modules[i].name`` that imports (numpy 2 moved ``numpy.core`` to ``_core``)."""
    import importlib
    import warnings

    for mod in modules:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                fn = getattr(importlib.import_module(mod), name, None)
        except ImportError:
            continue
        if fn is not None:
            return fn
    raise ImportError(f"numpy provides none of {modules} .{name}")  # pragma: no cover


def _numpy_globals() -> dict[tuple[str, str], Any]:
    multiarray = ("numpy._core.multiarray", "numpy.core.multiarray")
    numeric = ("numpy._core.numeric", "numpy.core.numeric")
    out: dict[tuple[str, str], Any] = {}
    for name in ("_reconstruct", "scalar"):
        fn = _numpy_function(multiarray, name)
        out.update({(mod, name): fn for mod in multiarray})
    frombuffer = _numpy_function(numeric, "_frombuffer")
    out.update({(mod, "_frombuffer"): frombuffer for mod in numeric})
    out[("numpy", "ndarray")] = np.ndarray
    out[("numpy", "dtype")] = np.dtype
    return out


def _latin1_encode(text, encoding="latin1"):
    """``_codecs.encode`` as Python 3 writes bytes in protocol-2 pickles; latin-1 only."""
    if not isinstance(text, str) or str(encoding).lower().replace("_", "-") not in (
        "latin1",
        "latin-1",
        "iso-8859-1",
    ):
        raise UnsafeFileError(f"refused _codecs.encode with encoding {encoding!r}")
    return text.encode("latin1")


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that resolves only the globals a MANO file needs (see module docs)."""

    def __init__(self, file, **kw):
        kw.setdefault("encoding", "latin1")
        super().__init__(file, **kw)
        self._globals = _numpy_globals()
        self._stand_ins: dict[tuple[str, str], type] = {}
        self._reconstructable: set[type] = {object}

    def _stand_in(self, key: tuple[str, str], make) -> type:
        if key not in self._stand_ins:
            cls = make()
            self._stand_ins[key] = cls
            self._reconstructable.add(cls)
        return self._stand_ins[key]

    def _reconstructor(self, cls, base, state):
        if cls not in self._reconstructable or base is not object:
            raise UnsafeFileError(
                f"refused copy_reg._reconstructor({getattr(cls, '__name__', cls)!r}, "
                f"{getattr(base, '__name__', base)!r}) in the pickle"
            )
        return cls.__new__(cls) if cls is not object else object()

    def find_class(self, module: str, name: str):
        key = (module, name)
        if key in self._globals:
            return self._globals[key]
        if module in ("__builtin__", "builtins") and name in ("set", "frozenset", "object"):
            return {"set": set, "frozenset": frozenset, "object": object}[name]
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return self._reconstructor
        if module == "_codecs" and name == "encode":
            return _latin1_encode
        if name in _CHUMPY_MODULES.get(module, ()):
            return self._stand_in(("chumpy", name), lambda: _chumpy_class(name))
        sparse_mods = ("scipy.sparse", "scipy.sparse.csc", "scipy.sparse.csr")
        if module in sparse_mods + ("scipy.sparse._csc", "scipy.sparse._csr"):
            if name in ("csc_matrix", "csr_matrix"):
                fmt = name[:3]
                return self._stand_in(("sparse", fmt), lambda: _sparse_class(fmt))
        raise UnsafeFileError(
            f"refused to load '{module}.{name}' from the pickle: a MANO file only contains "
            "numpy arrays, scipy sparse matrices and chumpy arrays"
        )

    def persistent_load(self, pid):
        raise UnsafeFileError("refused a persistent id in the pickle")


def load_mano_pickle(path: str | Path) -> dict[str, Any]:
    """Read a MANO ``.pkl`` safely and return its content with plain numpy / scipy values.

    Args:
        path (str or Path): The pickle file (Python-2 pickles are read with ``encoding="latin1"``).

    Returns:
        dict: Keys of the file (``v_template`` (778, 3), ``shapedirs`` (778, 3, 10), ``J_regressor``
            (16, 778) sparse, ...); chumpy objects become ``np.ndarray``, sparse matrices become
            ``scipy.sparse`` csc / csr matrices.

    Raises:
        UnsafeFileError: The file names a global outside the allow-list (nothing it names is ever
            called).
        InvalidInputError: The file cannot be read, is not a pickle, or does not hold a dictionary.
    """
    path = Path(path)
    try:
        data = load_restricted(path, "MANO file")
    except (UnsafeFileError, InvalidInputError):
        raise
    except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt file
        raise InvalidInputError(
            f"{path} is not a readable MANO pickle ({type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(data, dict):
        raise InvalidInputError(
            f"{path} does not hold a dictionary (got {type(data).__name__}); is it a MANO file?"
        )
    check_expansion(data)
    return {str(k): _plain(v, 0) for k, v in data.items()}
