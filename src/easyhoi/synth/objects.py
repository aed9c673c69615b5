"""Graspable objects for synthetic scenes: procedural shapes and scanned meshes.

Every object is a closed (watertight), outward-oriented triangle mesh in METRES, centred on its
bounding-box centre, with at most about 5k faces. Procedural kinds (sizes are sampled from the
``seed``; ranges in centimetres):

* ``"cylinder"``: a can (radius 3.0-4.0, height 9-13) or a bottle (radius 2.8-3.6, height
  16-22), axis along z.
* ``"box"``: a rounded box (thickness 2.5-4.5, width 5-8, length 10-16), longest side along z.
* ``"sphere"``: radius 3.0-4.5 (a ball or a fruit).
* ``"mug"``: a hollow cup (outer radius 3.6-4.4, height 8.5-11, wall 0.5) with a ring handle,
  built as the union of signed distance functions and meshed by marching cubes.
* ``"tool"``: a handle (radius 1.2-1.6, length 10-14) with a head: a hammer head, a spatula
  blade or a round knob; union of signed distance functions, marching cubes.

Scanned meshes (any file :func:`easyhoi.geometry.mesh.load_mesh` reads, for example the YCB
objects of ``/work/shared/data/objects``) are made watertight with
:func:`easyhoi.geometry.watertight.make_watertight`, decimated to ``max_faces`` and cached in
memory (a copy is returned each time).
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from easyhoi.errors import BackendError, InvalidInputError

logger = logging.getLogger(__name__)

#: Procedural object kinds accepted by :func:`make_object`.
OBJECT_KINDS = ("cylinder", "box", "sphere", "mug", "tool")
#: Face budget of every object.
MAX_FACES = 5000
#: Procedural textures :mod:`easyhoi.synth.photo` knows.
TEXTURES = ("plain", "stripes", "checker", "bands")

#: Saturated household colours (RGB in [0, 1]).
OBJECT_PALETTE = (
    (0.80, 0.12, 0.10),  # red
    (0.10, 0.35, 0.75),  # blue
    (0.95, 0.75, 0.10),  # yellow
    (0.15, 0.60, 0.25),  # green
    (0.92, 0.92, 0.88),  # white
    (0.20, 0.20, 0.22),  # black
    (0.95, 0.45, 0.10),  # orange
    (0.55, 0.25, 0.65),  # purple
    (0.10, 0.65, 0.70),  # teal
    (0.70, 0.55, 0.35),  # wood
)


@dataclass(frozen=True)
class SynthObject:
    """A graspable object.

    Attributes:
        mesh (trimesh.Trimesh): Watertight, outward-oriented, metres, centred on its bounding-box
            centre.
        color ((3,) tuple of float): Base RGB colour in [0, 1].
        secondary ((3,) tuple of float): Second colour of the procedural texture.
        texture (str): One of :data:`TEXTURES`.
        kind (str): A procedural kind or ``"scan"``.
        name (str): Human-readable name (the file stem for scans).
    """

    mesh: trimesh.Trimesh
    color: tuple[float, float, float]
    secondary: tuple[float, float, float]
    texture: str
    kind: str
    name: str


# ----------------------------------------------------------------------------------------------
# Signed distance primitives (numpy, (N, 3) -> (N,), negative inside)
# ----------------------------------------------------------------------------------------------


def _sd_capped_cylinder(p: np.ndarray, radius: float, half: float, axis: int = 2) -> np.ndarray:
    r = np.linalg.norm(np.delete(p, axis, axis=1), axis=1) - radius
    h = np.abs(p[:, axis]) - half
    outside = np.hypot(np.maximum(r, 0), np.maximum(h, 0))
    return outside + np.minimum(np.maximum(r, h), 0)


def _sd_round_box(p: np.ndarray, half: np.ndarray, rounding: float) -> np.ndarray:
    q = np.abs(p) - (np.asarray(half) - rounding)
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0) - rounding


def _sd_torus_xz(p: np.ndarray, major: float, minor: float) -> np.ndarray:
    """Torus in the x-z plane (ring around the y axis)."""
    q = np.hypot(p[:, 0], p[:, 2]) - major
    return np.hypot(q, p[:, 1]) - minor


def _sd_capsule(p: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1) - radius


def _smooth_union(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum (blend radius ``k``)."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def mesh_from_sdf(sdf, lo, hi, voxel: float, max_faces: int = MAX_FACES) -> trimesh.Trimesh:
    """Marching cubes of an implicit surface, decimated to ``max_faces``.

    Args:
        sdf (callable): (N, 3) points -> (N,) signed distances (negative inside).
        lo, hi ((3,) float): Box that strictly contains the surface.
        voxel (float): Grid spacing.
        max_faces (int): Face budget.

    Returns:
        trimesh.Trimesh: Watertight, outward-oriented.
    """
    from skimage.measure import marching_cubes

    from easyhoi.geometry.watertight import decimate

    # an irrational offset keeps flat faces of the shape off the node planes (a zero value at a
    # node makes marching cubes emit degenerate, non-manifold triangles)
    lo = np.asarray(lo, dtype=np.float64) - (2 + 0.5 * (5**0.5 - 1)) * voxel
    hi = np.asarray(hi, dtype=np.float64) + 2 * voxel
    n = np.ceil((hi - lo) / voxel).astype(int) + 1
    axes = [lo[i] + voxel * np.arange(n[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = sdf(grid).reshape(*n)
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(voxel,) * 3)
    mesh = trimesh.Trimesh(verts + lo, faces, process=True)
    if mesh.volume < 0:
        mesh.invert()
    if len(mesh.faces) > max_faces:
        mesh = decimate(mesh, max_faces, backend="pcu")
    if not mesh.is_watertight or mesh.volume <= 0:
        raise BackendError("implicit object did not mesh to a closed surface")
    return mesh


# ----------------------------------------------------------------------------------------------
# Procedural kinds
# ----------------------------------------------------------------------------------------------


def _arc(c: np.ndarray, r: float, a0: float, a1: float, n: int) -> np.ndarray:
    t = np.linspace(a0, a1, n)
    return c + r * np.stack([np.cos(t), np.sin(t)], axis=1)


def _revolved(profile: np.ndarray, sections: int = 48) -> trimesh.Trimesh:
    """Surface of revolution about z of a (radius, height) profile from axis to axis."""
    mesh = trimesh.creation.revolve(profile, sections=sections)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _cylinder(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    rim = 0.003
    if rng.random() < 0.5:
        r, h = rng.uniform(0.030, 0.040), rng.uniform(0.09, 0.13)
        bottom = _arc(np.array([r - rim, -h / 2 + rim]), rim, -np.pi / 2, 0, 5)
        top = _arc(np.array([r - rim, h / 2 - rim]), rim, 0, np.pi / 2, 5)
        side = np.stack([np.full(12, r), np.linspace(-h / 2 + rim, h / 2 - rim, 12)], 1)[1:-1]
        profile = np.concatenate([[[0, -h / 2]], bottom, side, top, [[0, h / 2]]])
        return _revolved(profile), "can"
    r, h = rng.uniform(0.028, 0.036), rng.uniform(0.16, 0.22)
    neck, body = 0.013, 0.62 * h
    bottom = _arc(np.array([r - rim, -h / 2 + rim]), rim, -np.pi / 2, 0, 5)
    side = np.stack([np.full(12, r), np.linspace(-h / 2 + rim, -h / 2 + body, 12)], 1)[1:]
    t = np.linspace(0, 1, 10)[1:]
    shoulder_h = 0.22 * h
    shoulder = np.stack(
        [neck + (r - neck) * 0.5 * (1 + np.cos(np.pi * t)), -h / 2 + body + shoulder_h * t], 1
    )
    top_y = h / 2
    neck_pts = np.stack([np.full(4, neck), np.linspace(shoulder[-1, 1], top_y - rim, 5)[1:]], 1)
    cap = _arc(np.array([neck - rim, top_y - rim]), rim, 0, np.pi / 2, 4)
    profile = np.concatenate([[[0, -h / 2]], bottom, side, shoulder, neck_pts, cap, [[0, top_y]]])
    return _revolved(profile), "bottle"


def _box(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    half = 0.5 * np.array(
        [rng.uniform(0.025, 0.045), rng.uniform(0.05, 0.08), rng.uniform(0.10, 0.16)]
    )
    rounding = 0.004
    mesh = mesh_from_sdf(lambda p: _sd_round_box(p, half, rounding), -half, half, voxel=0.003)
    return mesh, "box"


def _sphere(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    return trimesh.creation.icosphere(subdivisions=3, radius=rng.uniform(0.030, 0.045)), "ball"


def _mug(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    radius, height = rng.uniform(0.036, 0.044), rng.uniform(0.085, 0.11)
    wall, bottom = 0.005, 0.007
    half = height / 2
    major, minor = rng.uniform(0.022, 0.028), rng.uniform(0.0055, 0.007)
    centre = np.array([radius + 0.5 * major, 0.0, 0.0])  # handle on +x, axis along y

    def sdf(p):
        q = p[:, [0, 2, 1]]  # cup axis along y
        outer = _sd_capped_cylinder(q, radius, half)
        inner = _sd_capped_cylinder(q - [0, 0, bottom], radius - wall, half)
        cup = np.maximum(outer, -inner)
        ring = _sd_torus_xz((p - centre)[:, [0, 2, 1]], major, minor)
        ring = np.maximum(ring, radius - wall - np.hypot(p[:, 0], p[:, 2]))  # nothing inside
        return _smooth_union(cup, ring, 0.004)

    lo = np.array([-radius, -half, -radius])
    hi = np.array([centre[0] + major + minor, half, radius])
    mesh = mesh_from_sdf(sdf, lo, hi, voxel=0.0024)
    return mesh, "mug"


def _tool(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    r, length = rng.uniform(0.012, 0.016), rng.uniform(0.10, 0.14)
    a, b = np.array([0.0, 0.0, -length / 2]), np.array([0.0, 0.0, length / 2])
    head = rng.choice(["hammer", "spatula", "knob"])
    if head == "hammer":
        hh = np.array([0.016, 0.016, 0.055])[[2, 0, 1]]  # along x
        centre = b + [0, 0, 0.012]

        def head_sdf(p):
            return _sd_round_box(p - centre, hh, 0.004)

        extent = hh + 0.005
    elif head == "spatula":
        hh = np.array([0.035, 0.004, 0.045])
        centre = b + [0, 0, 0.04]

        def head_sdf(p):
            return _sd_round_box(p - centre, hh, 0.0035)

        extent = hh + 0.005
    else:
        rad = rng.uniform(0.022, 0.028)
        centre = b + [0, 0, 0.6 * rad]

        def head_sdf(p):
            return np.linalg.norm(p - centre, axis=1) - rad

        extent = np.full(3, rad + 0.005)

    def sdf(p):
        return _smooth_union(_sd_capsule(p, a, b, r), head_sdf(p), 0.006)

    lo = np.minimum(a - r - 0.005, centre - extent)
    hi = np.maximum(b + r + 0.005, centre + extent)
    return mesh_from_sdf(sdf, lo, hi, voxel=0.0025), str(head)


_BUILDERS = {"cylinder": _cylinder, "box": _box, "sphere": _sphere, "mug": _mug, "tool": _tool}


def _centred(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    lo, hi = mesh.bounds
    out = trimesh.Trimesh(mesh.vertices - 0.5 * (lo + hi), mesh.faces, process=False)
    if out.volume < 0:
        out.invert()
    return out


@functools.lru_cache(maxsize=64)
def _procedural(kind: str, seed: int) -> tuple[trimesh.Trimesh, str]:
    rng = np.random.default_rng([seed, OBJECT_KINDS.index(kind)])
    mesh, name = _BUILDERS[kind](rng)
    return _centred(mesh), name


@functools.lru_cache(maxsize=32)
def _scanned(path: str, max_faces: int) -> trimesh.Trimesh:
    from easyhoi.geometry.mesh import load_mesh
    from easyhoi.geometry.watertight import decimate, make_watertight

    raw = load_mesh(path, process=True)
    closed, report = make_watertight(raw)
    logger.debug("made %s watertight (%s) in %.2fs", path, report.method, report.seconds)
    mesh = decimate(closed, max_faces) if len(closed.faces) > max_faces else closed
    if not mesh.is_watertight:
        logger.debug("decimation opened %s; keeping the undecimated closed mesh", path)
        mesh = closed
    return _centred(mesh)


def list_objects(folder: str | Path) -> list[Path]:
    """Sorted mesh files (OBJ, PLY, GLB, STL, OFF) of a folder.

    Raises:
        InvalidInputError: The folder does not exist or holds no mesh file.
    """
    from easyhoi.geometry.mesh import MESH_SUFFIXES

    d = Path(folder)
    if not d.is_dir():
        raise InvalidInputError(f"object folder not found: '{d}'")
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if not files:
        raise InvalidInputError(f"object folder '{d}' holds no mesh file ({MESH_SUFFIXES})")
    return files


def _appearance(rng: np.random.Generator) -> tuple[tuple, tuple, str]:
    i, j = rng.choice(len(OBJECT_PALETTE), size=2, replace=False)
    texture = str(rng.choice(TEXTURES, p=[0.4, 0.25, 0.15, 0.2]))
    return OBJECT_PALETTE[i], OBJECT_PALETTE[j], texture


def make_object(kind: str | Path, seed: int = 0, max_faces: int = MAX_FACES) -> SynthObject:
    """Create a graspable object.

    Args:
        kind (str or Path): One of :data:`OBJECT_KINDS`, or the path of a mesh file (scanned object,
            metres).
        seed (int): Seeds the size and appearance (procedural) or the appearance (scans).
        max_faces (int): Face budget for scanned meshes (procedural ones use :data:`MAX_FACES`).

    Returns:
        SynthObject: Its mesh is a fresh copy (callers may modify it).

    Raises:
        InvalidInputError: Unknown kind or unreadable file.
    """
    rng = np.random.default_rng([seed, 7919])
    if isinstance(kind, str) and kind in OBJECT_KINDS:
        mesh, name = _procedural(kind, int(seed))
        color, secondary, texture = _appearance(rng)
        return SynthObject(mesh.copy(), color, secondary, texture, kind, name)
    path = Path(kind)
    if not path.suffix:
        raise InvalidInputError(
            f"unknown object kind {str(kind)!r}; choose one of {OBJECT_KINDS} or a mesh path"
        )
    mesh = _scanned(str(path.resolve()), int(max_faces))
    color, secondary, _ = _appearance(rng)
    return SynthObject(mesh.copy(), color, secondary, "plain", "scan", path.stem)


__all__ = [
    "MAX_FACES",
    "OBJECT_KINDS",
    "OBJECT_PALETTE",
    "TEXTURES",
    "SynthObject",
    "list_objects",
    "make_object",
    "mesh_from_sdf",
]
