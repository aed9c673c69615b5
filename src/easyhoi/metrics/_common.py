"""Shared input handling for the metrics: mesh coercion, validation and inside tests.

Every metric takes meshes in METRES, either as ``trimesh.Trimesh`` or as a
``(vertices, faces)`` pair, and reports in centimetres.
"""

from __future__ import annotations

import numpy as np
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.mesh import validate_mesh_arrays

#: metres -> centimetres
M_TO_CM = 100.0


def to_numpy(x, name: str) -> np.ndarray:
    """Tensor / array-like -> float64 numpy array (detached, on the CPU)."""
    try:
        import torch

        if isinstance(x, torch.Tensor):
            return x.detach().cpu().double().numpy()
    except ImportError:  # pragma: no cover - torch is a core dependency
        pass
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"{name} must be numeric array-like, got {type(x).__name__}"
        ) from exc


def as_mesh(mesh, name: str, watertight: bool = False) -> trimesh.Trimesh:
    """Validate and coerce a mesh.

    Args:
        mesh (trimesh.Trimesh or tuple): A mesh, or ``(vertices (V, 3) float, faces (F, 3) int)`` in
            metres.
        name (str): Name used in error messages (for example ``"hand_mesh"``).
        watertight (bool): When True, raise unless the mesh is closed and consistently oriented
            (required by inside/outside tests).

    Returns:
        trimesh.Trimesh: A mesh built with ``process=False`` (vertex order preserved).

    Raises:
        InvalidInputError: Empty or degenerate meshes, non-finite vertices, bad face indices, or
            (when ``watertight``) a mesh that is not watertight.
    """
    if isinstance(mesh, trimesh.Trimesh):
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces)
    elif isinstance(mesh, tuple | list) and len(mesh) == 2:
        vertices = to_numpy(mesh[0], f"{name} vertices")
        faces = np.asarray(to_numpy(mesh[1], f"{name} faces"))
        if faces.size and not np.all(faces == np.round(faces)):
            raise InvalidInputError(f"{name} faces must be integers")
        faces = faces.astype(np.int64)
    else:
        raise InvalidInputError(
            f"{name} must be a trimesh.Trimesh or a (vertices, faces) pair, "
            f"got {type(mesh).__name__}"
        )
    validate_mesh_arrays(vertices, faces, name)
    out = trimesh.Trimesh(vertices, faces, process=False)
    area = float(out.area)
    if not area > 0:
        raise InvalidInputError(f"{name} is degenerate: expected a positive surface area, got 0")
    if watertight and not out.is_watertight:
        raise InvalidInputError(
            f"{name} must be watertight (closed) for inside tests, but it has "
            f"{_open_edge_count(out)} boundary edges; close it first "
            "(for example with easyhoi.geometry.watertight)"
        )
    if watertight and out.volume < 0:
        out = trimesh.Trimesh(vertices, faces[:, ::-1], process=False)  # inward normals
    return out


def _open_edge_count(mesh: trimesh.Trimesh) -> int:
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


def winding_number(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalised winding number of ``mesh`` at ``points``.

    Args:
        mesh (trimesh.Trimesh): Triangle mesh (outward normals give +1 inside).
        points ((N, 3) float): Query points in the mesh's units.

    Returns:
        (N,) float: About 1 inside a closed mesh, 0 outside (fast winding numbers, Barill et al.
            2018).
    """
    import point_cloud_utils as pcu

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0)
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    return np.asarray(pcu.triangle_soup_fast_winding_number(v, f, points), dtype=np.float64)


def inside(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(N,) bool: points inside the closed ``mesh`` (winding number > 0.5)."""
    return winding_number(mesh, points) > 0.5
