"""Mesh loading, validation and normalisation (trimesh in, trimesh out).

Every function raises :class:`~easyhoi.errors.InvalidInputError` naming what was expected and what
was found: a missing file, an unsupported or corrupt file, an empty mesh, NaN vertices, faces that
index missing vertices.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from easyhoi.checks import check_faces
from easyhoi.errors import InvalidInputError

#: File suffixes :func:`load_mesh` accepts.
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


def load_mesh(path: str | Path, process: bool = False) -> trimesh.Trimesh:
    """Load a triangle mesh from an OBJ, PLY, GLB/GLTF, STL or OFF file.

    Scenes (GLB files with several nodes) are flattened into one mesh in world coordinates.

    Args:
        path (str or Path): The file to read.
        process (bool): Forwarded to trimesh: merge duplicate vertices and drop degenerate faces
            when True.

    Returns:
        trimesh.Trimesh: A validated mesh with (V, 3) float64 vertices and (F, 3) int64 faces, F >
            0.

    Raises:
        InvalidInputError: The file is missing, has an unsupported suffix, cannot be parsed, or
            holds no valid mesh.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"mesh file not found: expected an existing file, got '{p}'")
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InvalidInputError(
            f"unsupported mesh format: expected one of {', '.join(MESH_SUFFIXES)}, got '{suffix}'"
        )
    try:
        loaded = trimesh.load(p, force="mesh", process=process)
    except Exception as exc:  # trimesh raises many kinds of errors on corrupt files
        raise InvalidInputError(f"could not parse mesh file '{p}': {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        raise InvalidInputError(
            f"mesh file '{p}' holds no triangle mesh (got {type(loaded).__name__})"
        )
    validate_mesh(loaded, name=f"mesh '{p.name}'")
    return loaded


def validate_mesh_arrays(v: np.ndarray, f: np.ndarray, name: str = "mesh") -> None:
    """Raise unless ``v`` (V, 3) and ``f`` (F, 3) form a non-empty, finite, non-degenerate mesh.

    The one place where easyhoi checks mesh arrays (:func:`validate_mesh`, the metrics and
    :class:`~easyhoi.hoi.HOIInput` all call it).
    """
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidInputError(f"{name} vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InvalidInputError(f"{name} faces must have shape (F, 3), got {f.shape}")
    if len(v) == 0 or len(f) == 0:
        raise InvalidInputError(
            f"{name} is empty: expected at least one face, got {len(v)} vertices, {len(f)} faces"
        )
    if not np.isfinite(v).all():
        bad = int((~np.isfinite(v)).any(axis=1).sum())
        raise InvalidInputError(f"{name} has {bad} vertices with NaN or infinite coordinates")
    check_faces(f, len(v), f"{name} faces")
    if float(np.ptp(v[np.unique(f)], axis=0).max()) <= 0.0:
        raise InvalidInputError(f"{name} is degenerate: all its vertices are the same point")


def validate_mesh(
    mesh: trimesh.Trimesh, name: str = "mesh", require_watertight: bool = False
) -> None:
    """Raise unless ``mesh`` is a non-empty, finite triangle mesh with valid face indices.

    Args:
        mesh (trimesh.Trimesh): The mesh to check.
        name (str): How the mesh is named in error messages.
        require_watertight (bool): Also require a closed, consistently wound surface
            (``mesh.is_watertight``).
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"{name} must be a trimesh.Trimesh, got {type(mesh).__name__}")
    validate_mesh_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces), name)
    if require_watertight and not mesh.is_watertight:
        raise InvalidInputError(
            f"{name} must be watertight (closed, every edge shared by two faces); it is not: "
            "repair it with easyhoi.geometry.watertight.make_watertight"
        )


@dataclass(frozen=True)
class MeshNormalization:
    """The similarity ``x_norm = (x - center) * scale`` applied by :func:`normalize_mesh`.

    Attributes:
        center ((3,) float64 ndarray): Centre of the axis-aligned bounding box of the original mesh.
        scale (float): Factor that maps the original bounding radius to the target radius.
    """

    center: np.ndarray
    scale: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) original coordinates -> (..., 3) normalised coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def invert(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) normalised coordinates -> (..., 3) original coordinates."""
        return np.asarray(points, dtype=np.float64) / self.scale + self.center

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix of :meth:`apply`."""
        m = np.eye(4)
        m[:3, :3] *= self.scale
        m[:3, 3] = -self.center * self.scale
        return m


def normalize_mesh(
    mesh: trimesh.Trimesh, radius: float = 1.0
) -> tuple[trimesh.Trimesh, MeshNormalization]:
    """Centre a mesh on its bounding-box centre and scale it to a bounding radius ``radius``.

    The bounding radius is the largest distance of a vertex from the box centre, so afterwards
    every vertex lies in the ball of radius ``radius`` around the origin and one touches it.

    Args:
        mesh (trimesh.Trimesh): The mesh; it is not modified.
        radius (float): Target bounding radius, > 0.

    Returns:
        normalized (trimesh.Trimesh): A new mesh with the same faces.
        transform (MeshNormalization): ``transform.apply(mesh.vertices) == normalized.vertices``;
            ``invert`` undoes it.
    """
    validate_mesh(mesh)
    if not (np.isfinite(radius) and radius > 0):
        raise InvalidInputError(f"radius must be a positive finite number, got {radius}")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    used = v[np.unique(mesh.faces)]
    center = 0.5 * (used.min(axis=0) + used.max(axis=0))
    r = float(np.linalg.norm(used - center, axis=1).max())
    tf = MeshNormalization(center=center, scale=radius / r)
    out = trimesh.Trimesh(tf.apply(v), np.asarray(mesh.faces).copy(), process=False)
    return out, tf


def as_trimesh(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> trimesh.Trimesh:
    """Build and validate a trimesh from (V, 3) vertices and (F, 3) faces (no processing)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidInputError(f"{name} vertices must have shape (V, 3), got {v.shape}")
    check_faces(f, len(v), name=f"{name} faces")
    mesh = trimesh.Trimesh(v, f.astype(np.int64), process=False)
    validate_mesh(mesh, name=name)
    return mesh
