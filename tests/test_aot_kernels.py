"""The kernels built ahead of time (easyhoi.aot): the same bits as the numba functions, the
right export per call, the numba function for other argument types, and no use of a module
built for other sources."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from easyhoi import aot

pytest.importorskip("numba")
needs_cc = pytest.mark.skipif(
    shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler"
)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The kernels compiled into a temporary folder (not the package's own build)."""
    out = tmp_path_factory.mktemp("aot")
    path = aot.build(out)
    spec = importlib.util.spec_from_file_location(aot.MODULE, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _soft_inputs(rng, dtype, h=24, w=28, faces=40):
    """Faces over the image (some past its edges) of one image (offsets 0), a 3 px margin."""
    tri = (rng.random((faces, 6)) * [w, h, w, h, w, h] * 1.2 - 2).astype(dtype)
    return tri, np.zeros(faces, np.int64), h, w, 3.0


def _cases(rng):
    """(module, name, argument types, args) for every export, with inputs of its types."""
    out = []
    for module, name, _ret, types in aot.EXPORTS:
        dtype = np.float32 if "f4" in types[0] else np.float64
        if name in ("soft_logsum_forward", "soft_logsum_backward"):
            tri, base, h, w, margin = _soft_inputs(rng, dtype)
            if name == "soft_logsum_forward":
                args = (tri, base, h, w, 1.7, margin, h * w, np.zeros(h * w, dtype))
            else:
                g = rng.normal(size=h * w).astype(dtype)
                args = (tri, base, h, w, 1.7, margin, g, np.zeros((len(tri), 6), dtype))
        elif name == "zbuffer":
            h, w = 30, 26
            tri = (rng.random((60, 6)) * [w, h, w, h, w, h]).astype(dtype)
            z = (0.5 + rng.random((60, 3))).astype(dtype)
            args = (tri, z, h, w, np.full(h * w, np.inf, dtype))
            if len(types) == 6:
                args = (*args, np.full(h * w, -1, np.int64))
        elif name == "min_filter":
            z = rng.random((17, 23)).astype(dtype)
            args = (z, 2, np.zeros_like(z))
        elif name == "hull_weight_sums":
            import cv2

            from easyhoi.perception.shapes.cuboid import row_prefix_sums

            pts = (rng.random((12, 2)) * 40).astype(np.float32)
            hull = np.ascontiguousarray(cv2.convexHull(pts)[:, 0])
            qa = row_prefix_sums(rng.integers(0, 5, (44, 44)).astype(np.int64))
            qb = row_prefix_sums(rng.integers(0, 5, (44, 44)).astype(np.int64))
            args = (hull, qa, qb)
        elif name == "corner_sums":
            nv = 30
            faces = rng.integers(0, nv, (50, 3)).astype(np.int64)
            cross = rng.normal(size=(50, 3))
            unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
            args = (faces, nv, cross, unit, 0.5)
        else:  # pragma: no cover - a new export needs inputs here
            raise AssertionError(f"no inputs for {name}")
        out.append((module, name, types, args))
    return out


def _copy(args):
    return tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)


def _equal(a, b) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    return a == b


@needs_cc
def test_every_export_gives_the_numba_functions_bits(built):
    rng = np.random.default_rng(3)
    cases = _cases(rng)
    assert len(cases) == len(aot.EXPORTS)
    for module, name, _types, args in cases:
        k = aot.kernel(module, name, built=built)
        assert k is not None
        key = aot._call_key(args)
        assert key in k.exports, (name, key)  # the call goes to the built export
        a1, a2 = _copy(args), _copy(args)
        r1 = k.exports[key](*a1)
        r2 = k.jit()(*a2)
        assert _equal(r1, r2), name
        # the outputs written in place (and every input) are the same bits too
        for x, y in zip(a1, a2, strict=True):
            assert _equal(x, y), name
        written = [x for x, y in zip(a1, args, strict=True) if isinstance(x, np.ndarray)
                   and not _equal(x, y)]  # fmt: skip
        assert written or r1 is not None, f"{name}: the inputs exercise nothing"


@needs_cc
def test_other_argument_types_go_to_the_numba_function(built):
    k = aot.kernel("easyhoi.render._numba_kernels", "min_filter", built=built)
    z = np.random.default_rng(0).random((9, 7))
    zf = np.asfortranarray(z)
    assert aot._call_key((zf, 1, np.zeros_like(zf))) not in k.exports
    calls = []
    jit = k.jit()
    k._jit = lambda *a: calls.append(1) or jit(*a)
    out_f = np.zeros_like(zf)
    k(zf, 1, out_f)  # Fortran order: not exported
    out_c = np.zeros_like(z)
    k(z, 1, out_c)  # exported
    assert calls == [1]
    want = np.minimum.reduce(
        [np.pad(z, 1, constant_values=np.inf)[i : i + 9, j : j + 7] for i in range(3)
         for j in range(3)]
    )  # fmt: skip
    np.testing.assert_array_equal(out_c, want)
    np.testing.assert_array_equal(out_f, want)
    # a NumPy float32 scalar is typed float32 by numba: not the float64 export
    assert aot._call_key((np.float32(1.0),)) == ("float32",)
    assert aot._call_key((1.0, 2, True)) == ("f8", "i8", "b1")


def test_a_module_built_for_other_sources_or_turned_off_is_not_used(tmp_path, monkeypatch):
    stamp = aot._stamp()
    if stamp is None:
        pytest.skip("no /proc/cpuinfo: nothing is ever built here")
    fake = tmp_path / "stamp.json"
    monkeypatch.setattr(aot, "STAMP", fake)
    assert aot._load() is None  # not built
    fake.write_text(json.dumps({**stamp, "sources": "0" * 64}))
    assert aot._load() is None  # the kernels' sources changed since
    fake.write_text(json.dumps({**stamp, "cpu": "0" * 64}))
    assert aot._load() is None  # another CPU
    fake.write_text(json.dumps(stamp))
    monkeypatch.setenv("EASYHOI_AOT", "0")
    assert aot._load() is None
    # the stamp covers every kernel source and the export list
    for rel in aot.SOURCES.values():
        assert (aot.PACKAGE / rel).is_file()


def test_a_fresh_process_with_the_built_kernels_does_not_import_numba():
    """The renderer, the box fit and the pictures' corner normals all run on the built module."""
    if aot.loaded() is None:
        pytest.skip("the package's kernels are not built here (python -m easyhoi.aot)")
    code = textwrap.dedent(
        """
        import sys
        import numpy as np
        import torch
        from easyhoi.render import depth_map, soft_silhouette, get_backend
        from easyhoi.structures import Camera
        from easyhoi.perception.shapes import cuboid
        from easyhoi.perception.shapes.common import work_frame
        v = torch.tensor([[0., 0, 1], [0.1, 0, 1], [0, 0.1, 1], [0.1, 0.1, 1.2]])
        f = torch.tensor([[0, 1, 2], [1, 3, 2]])
        cam = Camera.from_fov(40.0, 32, 32)
        soft_silhouette(v, f, cam).sum()
        depth_map(v, f, cam)
        m = np.zeros((60, 60), bool); m[15:45, 10:50] = True
        cuboid.fit(work_frame(m))
        from easyhoi.viz.shade import corner_normals
        corner_normals(v.numpy().astype(np.float64), f.numpy())
        assert get_backend() == "numba"
        print("numba" in sys.modules)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_the_renderers_kernels_fall_back_to_numba_by_name():
    """A renderer kernel name the built module does not export is numba's function."""
    from easyhoi.render import _common, _numba_kernels

    k = _common._BuiltKernels()
    assert k.pair_count is _numba_kernels.pair_count  # a plain function: never exported
    if aot.loaded() is not None:
        assert isinstance(k.zbuffer, aot.Kernel)
    with pytest.raises(AttributeError):
        k._private  # noqa: B018


def test_doctor_says_which_kernels_are_in_use(monkeypatch):
    from easyhoi import doctor

    monkeypatch.setitem(aot._STATE, "mod", None)
    assert "python -m easyhoi.aot" in doctor._kernels_line()
    monkeypatch.setitem(aot._STATE, "mod", object())
    assert "ahead of time for this machine" in doctor._kernels_line()
