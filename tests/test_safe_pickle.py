"""The restricted unpickler: MANO-like content loads, anything that could run code is refused
before it runs."""

from __future__ import annotations

import builtins
import codecs
import copyreg
import os
import pickle
import subprocess

import numpy as np
import pytest
import scipy.sparse as sp

from easyhoi.errors import InvalidInputError, UnsafeFileError
from easyhoi.hand.safe_pickle import load_mano_pickle
from tests.mano_synth import dump_py2, fake_chumpy


class _Reducer:
    """An object whose pickle calls ``fn(*args)`` when loaded by a plain unpickler."""

    def __init__(self, fn, *args):
        self.fn, self.args = fn, args

    def __reduce__(self):
        return self.fn, self.args


def _write(path, obj, protocol=2):
    path.write_bytes(pickle.dumps(obj, protocol=protocol))
    return path


@pytest.mark.parametrize(
    "make, refused",
    [
        (lambda t: _Reducer(os.system, f"touch {t}"), "system"),
        (lambda t: _Reducer(builtins.eval, f"open({str(t)!r}, 'w').close()"), "eval"),
        (lambda t: _Reducer(subprocess.Popen, ["touch", str(t)]), "Popen"),
        (lambda t: _Reducer(builtins.exec, f"open({str(t)!r}, 'w').close()"), "exec"),
    ],
)
@pytest.mark.parametrize("protocol", [0, 2, 5])
def test_malicious_pickle_is_refused_without_side_effect(tmp_path, make, refused, protocol):
    target = tmp_path / "pwned"
    payload = {"v_template": np.zeros((2, 3)), "evil": make(target)}
    path = _write(tmp_path / "MANO_RIGHT.pkl", payload, protocol)
    with pytest.raises(UnsafeFileError, match=refused):
        load_mano_pickle(path)
    assert not target.exists()


def test_malicious_object_inside_chumpy_state(tmp_path):
    target = tmp_path / "pwned"
    with fake_chumpy() as ch:
        evil = ch.Ch(np.zeros(3))
        evil.__dict__["x"] = _Reducer(os.system, f"touch {target}")
        dump_py2({"shapedirs": evil}, tmp_path / "m.pkl")
    with pytest.raises(UnsafeFileError, match="system"):
        load_mano_pickle(tmp_path / "m.pkl")
    assert not target.exists()


def test_reconstructor_and_codecs_are_restricted(tmp_path):
    p = _write(tmp_path / "a.pkl", {"x": _Reducer(copyreg._reconstructor, set, object, None)})
    with pytest.raises(UnsafeFileError, match="_reconstructor"):
        load_mano_pickle(p)
    p = _write(tmp_path / "b.pkl", {"x": _Reducer(codecs.encode, "abc", "rot13")})
    with pytest.raises(UnsafeFileError, match="rot13"):
        load_mano_pickle(p)


def test_persistent_ids_are_refused(tmp_path):
    class P(pickle.Pickler):
        def persistent_id(self, obj):
            return "pid" if isinstance(obj, str) and obj == "ref" else None

    path = tmp_path / "p.pkl"
    with path.open("wb") as fh:
        P(fh, protocol=2).dump({"a": "ref"})
    with pytest.raises(UnsafeFileError, match="persistent"):
        load_mano_pickle(path)


def test_not_a_dict_or_not_a_pickle(tmp_path):
    with pytest.raises(InvalidInputError, match="dictionary"):
        load_mano_pickle(_write(tmp_path / "l.pkl", [1, 2]))
    (tmp_path / "g.pkl").write_bytes(b"\x80\x02garbage")
    with pytest.raises(InvalidInputError):
        load_mano_pickle(tmp_path / "g.pkl")
    with pytest.raises(InvalidInputError, match="cannot read"):
        load_mano_pickle(tmp_path / "missing.pkl")


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
def test_plain_numpy_and_sparse_content_loads(tmp_path, protocol):
    rng = np.random.default_rng(0)
    data = {
        "a": rng.standard_normal((4, 3)),
        "i": np.arange(6, dtype=np.uint32).reshape(2, 3),
        "csc": sp.csc_matrix(rng.standard_normal((3, 5)) * (rng.random((3, 5)) > 0.5)),
        "csr": sp.csr_matrix(np.eye(3)),
        "s": "lbs",
        "n": 3,
    }
    out = load_mano_pickle(_write(tmp_path / "n.pkl", data, protocol))
    np.testing.assert_array_equal(out["a"], data["a"])
    np.testing.assert_array_equal(out["i"], data["i"])
    assert out["i"].dtype == np.uint32
    assert out["csc"].format == "csc" and out["csr"].format == "csr"
    np.testing.assert_array_equal(out["csc"].toarray(), data["csc"].toarray())
    np.testing.assert_array_equal(out["csr"].toarray(), np.eye(3))
    assert out["s"] == "lbs" and out["n"] == 3


@pytest.mark.parametrize("protocol", [0, 2])
def test_chumpy_objects_become_arrays(tmp_path, protocol):
    x = np.arange(12.0)
    with fake_chumpy() as ch:
        a = ch.Ch(x)
        obj = {
            "ch": a,
            "sel": ch.Select(a, np.array([3, 1, 4, 1, 5, 9]), (2, 3)),
            "sum": ch.add(a, ch.Ch(np.ones(12))),
        }
        if protocol == 2:
            dump_py2(obj, tmp_path / "c.pkl")
        else:
            _write(tmp_path / "c.pkl", obj, protocol)
    out = load_mano_pickle(tmp_path / "c.pkl")
    np.testing.assert_array_equal(out["ch"], x)
    np.testing.assert_array_equal(out["sel"], x[[3, 1, 4, 1, 5, 9]].reshape(2, 3))
    np.testing.assert_array_equal(out["sum"], x + 1)


def test_unknown_chumpy_class_is_refused(tmp_path):
    with fake_chumpy() as ch:
        ch.Ch.__qualname__ = ch.Ch.__name__ = "Evaluate"
        import sys

        sys.modules["chumpy.ch"].Evaluate = ch.Ch
        dump_py2({"x": ch.Ch(np.zeros(2))}, tmp_path / "u.pkl")
    with pytest.raises(UnsafeFileError, match="chumpy.ch.Evaluate"):
        load_mano_pickle(tmp_path / "u.pkl")


def test_the_payload_is_real(tmp_path):
    """Control: a plain unpickler does run the payload the tests above refuse."""
    target = tmp_path / "pwned"
    path = _write(tmp_path / "x.pkl", {"evil": _Reducer(os.system, f"touch {target}")})
    pickle.loads(path.read_bytes())
    assert target.exists()


def test_numpy2_module_spelling_loads(tmp_path):
    """numpy 2 writes ``numpy._core.multiarray``; the GLOBAL opcode is a text line."""
    raw = pickle.dumps({"a": np.arange(5.0)}, protocol=2)
    assert b"numpy.core.multiarray" in raw
    path = tmp_path / "np2.pkl"
    path.write_bytes(raw.replace(b"numpy.core.multiarray", b"numpy._core.multiarray"))
    np.testing.assert_array_equal(load_mano_pickle(path)["a"], np.arange(5.0))
