"""Synthetic MANO files: the schema and pickled classes of a real MANO_RIGHT.pkl, fake content.

A real MANO file is a Python-2 pickle (protocol 2) of a dictionary holding numpy arrays, a
``scipy.sparse.csc.csc_matrix`` joint regressor and ``chumpy`` objects. This module writes a
file with the same layout: Python-2 byte strings (``BINSTRING``), the same global names
(``numpy.core.multiarray._reconstruct``, ``scipy.sparse.csc.csc_matrix``, ``chumpy.ch.Ch``,
``chumpy.reordering.Select``, ``__builtin__.set``) and chumpy-like object states. The fake
``chumpy`` modules exist only while the file is written.

The geometry is NOT a hand: a closed genus-0 tube with 778 vertices and 1552 faces whose
16-vertex "wrist" end is closed by a 14-face fan; the fan is removed, leaving 1538 faces and
one 16-vertex opening. Vertices and faces are shuffled so nothing relies on MANO's ordering.
"""

from __future__ import annotations

import pickle
import struct
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay

PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
RING = 16
NUM_RINGS = 48
CAP_INTERIOR = 10  # 16 * 48 + 10 = 778 vertices


# ----------------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------------


def tube_mesh(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed, consistently outward-wound tube (778 vertices, 1552 faces).

    Returns:
        vertices: (778, 3) float64, metres, the tube runs along +y from y = 0.
        faces: (1552, 3) int64.
        wrist_faces: (14,) bool mask of the fan closing ring 0 (the future opening).
    """
    import trimesh

    rng = np.random.default_rng(seed)
    ang = 2 * np.pi * np.arange(RING) / RING
    ys = np.linspace(0.0, 0.15, NUM_RINGS)
    verts = []
    for k, y in enumerate(ys):
        rx = 0.035 * (1.0 + 0.15 * np.sin(3 * y / 0.15))
        rz = 0.014 * (1.0 + 0.1 * np.cos(2 * y / 0.15))
        shift = 0.2 * k / RING * (2 * np.pi / RING)  # slight twist
        verts.append(
            np.stack([rx * np.cos(ang + shift), np.full(RING, y), rz * np.sin(ang + shift)], 1)
        )
    verts = np.concatenate(verts)
    faces = []
    for k in range(NUM_RINGS - 1):
        for i in range(RING):
            a, b = k * RING + i, k * RING + (i + 1) % RING
            c, d = a + RING, b + RING
            faces += [(a, c, b), (b, c, d)]
    # top cap: Delaunay of the last ring (unit circle) and CAP_INTERIOR interior points
    top = (NUM_RINGS - 1) * RING
    inner_r = np.r_[np.full(7, 0.6), np.full(3, 0.25)]
    inner_a = np.r_[2 * np.pi * np.arange(7) / 7 + 0.1, 2 * np.pi * np.arange(3) / 3 + 0.4]
    disk = np.concatenate(
        [
            np.stack([np.cos(ang), np.sin(ang)], 1),
            np.stack([inner_r * np.cos(inner_a), inner_r * np.sin(inner_a)], 1),
        ]
    )
    tri = Delaunay(disk).simplices
    local_to_global = np.r_[top + np.arange(RING), len(verts) + np.arange(CAP_INTERIOR)]
    last = verts[top:]
    centre_scale = np.array([np.abs(last[:, 0]).max(), np.abs(last[:, 2]).max()])
    r2 = (disk[RING:] ** 2).sum(1)
    cap = np.stack(
        [
            disk[RING:, 0] * centre_scale[0],
            ys[-1] + 0.02 * (1 - r2) + 1e-4 * rng.standard_normal(CAP_INTERIOR),
            disk[RING:, 1] * centre_scale[1],
        ],
        1,
    )
    verts = np.concatenate([verts, cap])
    faces += [tuple(local_to_global[t]) for t in tri]
    # wrist fan over ring 0 (no new vertex): 14 faces
    wrist = [(0, i + 1, i) for i in range(1, RING - 1)]
    faces = np.array(faces + wrist, dtype=np.int64)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    trimesh.repair.fix_winding(mesh)
    if mesh.volume < 0:
        mesh.invert()
    faces = np.asarray(mesh.faces, dtype=np.int64)
    is_wrist = np.zeros(len(faces), bool)
    is_wrist[-(RING - 2) :] = True
    return verts, faces, is_wrist


def joint_locations(seed: int = 0) -> np.ndarray:
    """(16, 3) joints inside the tube: a wrist and five 3-joint chains going up +y."""
    rng = np.random.default_rng(seed + 1)
    xs = {1: -0.012, 4: 0.0, 7: 0.024, 10: 0.012, 13: -0.026}  # index, middle, pinky, ring, thumb
    J = np.zeros((16, 3))
    J[0] = (0.0, 0.012, 0.0)
    for first, x in xs.items():
        for k in range(3):
            J[first + k] = (x, 0.06 + 0.03 * k, 0.0)
    return J + 0.002 * rng.standard_normal((16, 3)) * np.array([1, 1, 0.3])


# ----------------------------------------------------------------------------------------------
# Python-2 style pickling with fake chumpy classes
# ----------------------------------------------------------------------------------------------


@contextmanager
def fake_chumpy():
    """Temporarily install modules ``chumpy``, ``chumpy.ch``, ``chumpy.reordering``.

    Yields a namespace with ``Ch(x)`` and ``Select(a, idxs, preferred_shape)`` whose pickled
    form names ``chumpy.ch.Ch`` / ``chumpy.reordering.Select`` with chumpy-like states.
    """
    names = ("chumpy", "chumpy.ch", "chumpy.reordering", "chumpy.ch_ops")
    saved = {n: sys.modules.get(n) for n in names}
    mods = {n: types.ModuleType(n) for n in names}

    def base_state():
        return {
            "_dirty_vars": set(),
            "_itr": None,
            "_depends_on_deps": {},
            "_make_dense": False,
            "_make_sparse": False,
        }

    class Ch:
        def __init__(self, x):
            self.__dict__.update(base_state(), x=np.asarray(x, np.float64))

    class Select(Ch):
        def __init__(self, a, idxs, preferred_shape):
            self.__dict__.update(base_state(), a=a, idxs=idxs, preferred_shape=preferred_shape)

    class add(Ch):  # noqa: N801 - chumpy's spelling
        def __init__(self, a, b):
            self.__dict__.update(base_state(), a=a, b=b)

    for cls, mod in ((Ch, "chumpy.ch"), (Select, "chumpy.reordering"), (add, "chumpy.ch_ops")):
        cls.__module__ = mod
        cls.__qualname__ = cls.__name__
        setattr(mods[mod], cls.__name__, cls)
    mods["chumpy"].Ch = Ch
    for n, m in mods.items():
        sys.modules[n] = m
    try:
        yield types.SimpleNamespace(Ch=Ch, Select=Select, add=add)
    finally:
        for n, old in saved.items():
            if old is None:
                sys.modules.pop(n, None)
            else:  # pragma: no cover - chumpy is never installed here
                sys.modules[n] = old


class Py2Pickler(pickle._Pickler):
    """Protocol-2 pickler writing str and bytes as Python-2 byte strings (``BINSTRING``)."""

    dispatch = dict(pickle._Pickler.dispatch)

    def __init__(self, file):
        super().__init__(file, protocol=2, fix_imports=True)

    def save_py2_str(self, obj):
        data = obj if isinstance(obj, bytes) else obj.encode("latin1")
        if len(data) < 256:
            self.write(pickle.SHORT_BINSTRING + bytes([len(data)]) + data)
        else:
            self.write(pickle.BINSTRING + struct.pack("<i", len(data)) + data)
        self.memoize(obj)

    dispatch[bytes] = save_py2_str
    dispatch[str] = save_py2_str

    def save_global(self, obj, name=None):
        legacy = {sp.csc_matrix: ("scipy.sparse.csc", "csc_matrix")}
        if obj in legacy:
            mod, nm = legacy[obj]
            self.write(pickle.GLOBAL + f"{mod}\n{nm}\n".encode())
            self.memoize(obj)
            return
        super().save_global(obj, name)

    dispatch[type] = save_global


def dump_py2(obj, path: str | Path) -> None:
    """Write ``obj`` as a Python-2 style protocol-2 pickle."""
    with open(path, "wb") as fh:
        Py2Pickler(fh).dump(obj)


def synthetic_mano_dict(
    seed: int = 0, template_vertices: np.ndarray | None = None, faces: np.ndarray | None = None
) -> dict:
    """The plain-numpy content of a synthetic MANO_RIGHT file (before chumpy wrapping)."""
    rng = np.random.default_rng(seed)
    if template_vertices is None or faces is None:
        v, f, wrist = tube_mesh(seed)
        f = f[~wrist]
        perm = rng.permutation(len(v))  # new index of old vertex i is inv[i]
        inv = np.empty_like(perm)
        inv[perm] = np.arange(len(v))
        v = v[perm]
        f = inv[f][rng.permutation(len(f))]
        template_vertices = v if template_vertices is None else template_vertices
        faces = f if faces is None else faces
    v = np.asarray(template_vertices, np.float64)
    J = joint_locations(seed)
    d = np.linalg.norm(v[:, None] - J[None], axis=-1)
    logits = -d / 0.008
    w = np.exp(logits - logits.max(1, keepdims=True))
    w /= w.sum(1, keepdims=True)
    rows, cols = [], []
    for j in range(16):
        near = np.argsort(d[:, j])[:8]
        rows += [j] * 8
        cols += list(near)
    Jreg = sp.csc_matrix((np.full(len(rows), 1 / 8), (rows, cols)), shape=(16, len(v)))
    comps = np.linalg.qr(rng.standard_normal((45, 45)))[0] * rng.uniform(0.5, 1.5, (45, 1))
    kintree = np.array([[2**32 - 1] + list(PARENTS[1:]), list(range(16))], dtype=np.int64)
    return {
        "v_template": v,
        "shapedirs": 2e-3 * rng.standard_normal((len(v), 3, 10)),
        "posedirs": 2e-3 * rng.standard_normal((len(v), 3, 135)),
        "J_regressor": Jreg,
        "J": np.asarray(Jreg @ v),
        "weights": w,
        "kintree_table": kintree,
        "f": np.asarray(faces, dtype=np.uint32),
        "hands_components": comps,
        "hands_mean": 0.2 * rng.standard_normal(45),
        "hands_coeffs": rng.standard_normal((20, 45)),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }


def write_mano_dict(data: dict, path: str | Path) -> Path:
    """Pickle a MANO dictionary like the real files: shapedirs as ``chumpy.ch.Ch`` and J as a
    ``chumpy.reordering.Select`` of a ``Ch`` (the loader must cope with both)."""
    path = Path(path)
    out = dict(data)
    with fake_chumpy() as ch:
        if "shapedirs" in out:
            out["shapedirs"] = ch.Ch(out["shapedirs"])
        if "J" in out:
            J = np.asarray(out["J"])
            out["J"] = ch.Select(ch.Ch(J.ravel()), np.arange(J.size), J.shape)
        dump_py2(out, path)
    return path


def write_synthetic_mano(
    path: str | Path,
    seed: int = 0,
    template_vertices: np.ndarray | None = None,
    faces: np.ndarray | None = None,
) -> Path:
    """Write a synthetic MANO_RIGHT-schema pickle to ``path`` (a file, or a directory that gets
    ``MANO_RIGHT.pkl``) and return the file's path."""
    path = Path(path)
    if path.is_dir():
        path = path / "MANO_RIGHT.pkl"
    return write_mano_dict(synthetic_mano_dict(seed, template_vertices, faces), path)
