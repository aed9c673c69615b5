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
from easyhoi.testing.mano_synth import dump_py2, fake_chumpy


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


def _shared_lists(depth: int) -> list:
    a: list = []
    for _ in range(depth):
        a = [a, a]  # each level references the previous one twice: 2**depth leaves as a tree
    return a


def test_expansion_is_counted_through_shared_references():
    from easyhoi.hand.safe_pickle import check_expansion

    # naive reference: walk the tree, counting every container and leaf value once per reference
    def naive(o):
        if isinstance(o, dict):
            return 1 + sum(naive(v) for v in o.values())
        if isinstance(o, list | tuple):
            return 1 + sum(naive(v) for v in o)
        return 1

    for value in (_shared_lists(6), {"a": [1, 2, (3, 4)], "b": [[], {"c": 5}]}, [np.zeros(3)]):
        assert check_expansion(value) == naive(value)
    assert check_expansion(_shared_lists(12), limit=2**13) == 2**13 - 1


@pytest.mark.parametrize("loader", ["mano", "hand_params"])
def test_reference_bomb_and_cycles_are_refused_quickly(tmp_path, loader):
    import time

    from easyhoi.hand.safe_pickle import load_mano_pickle
    from easyhoi.perception.importers import _read_file

    load = load_mano_pickle if loader == "mano" else _read_file
    bomb = tmp_path / "bomb.pkl"
    bomb.write_bytes(pickle.dumps({"v_template": _shared_lists(40)}, protocol=2))
    assert bomb.stat().st_size < 1000
    t0 = time.perf_counter()
    with pytest.raises(UnsafeFileError, match="expands to more than"):
        load(bomb)
    assert time.perf_counter() - t0 < 5.0  # the tree walk would never end (2**40 values)
    cyc: list = []
    cyc.append(cyc)
    looped = tmp_path / "cycle.pkl"
    looped.write_bytes(pickle.dumps({"v_template": cyc}, protocol=2))
    with pytest.raises(UnsafeFileError, match="contains itself"):
        load(looped)


def test_oversized_pickle_is_refused_before_reading(tmp_path, monkeypatch):
    import easyhoi.hand.safe_pickle as sp_mod

    path = tmp_path / "big.pkl"
    path.write_bytes(pickle.dumps({"v_template": np.zeros(1000)}, protocol=2))
    monkeypatch.setattr(sp_mod, "MAX_PICKLE_BYTES", 100)
    with pytest.raises(InvalidInputError, match="larger than"):
        sp_mod.load_mano_pickle(path)
