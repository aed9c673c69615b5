"""Deterministic, area-uniform surface sampling of triangle meshes."""

from __future__ import annotations

import numpy as np
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.mesh import validate_mesh


def sample_surface(
    mesh: trimesh.Trimesh, n: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``n`` points uniformly by area on the surface of ``mesh``.

    Faces are drawn with probability proportional to their area, then a point is drawn uniformly
    inside the face (``u = 1 - sqrt(r1)``, ``v = sqrt(r1) * (1 - r2)``, ``w = sqrt(r1) * r2``).
    The same mesh, ``n`` and ``seed`` always give the same samples.

    Args:
        mesh (trimesh.Trimesh): A non-empty mesh with positive total area.
        n (int): Number of samples, >= 0.
        seed (int): Seed of the numpy random generator.

    Returns:
        points ((n, 3) float64): Sample positions.
        face_ids ((n,) int64): Index of the face each sample lies on.
        normals ((n, 3) float64): Unit normal of that face (winding order: counter-clockwise faces
            point outward).
    """
    validate_mesh(mesh)
    if not isinstance(n, int | np.integer) or n < 0:
        raise InvalidInputError(f"n must be a non-negative integer, got {n!r}")
    tri = np.asarray(mesh.triangles, dtype=np.float64)  # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    total = float(area2.sum())
    if not total > 0:
        raise InvalidInputError("mesh has zero surface area: expected at least one non-flat face")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(area2) / total
    face_ids = np.searchsorted(cdf, rng.random(n), side="right").astype(np.int64)
    face_ids = np.minimum(face_ids, len(cdf) - 1)
    r = rng.random((n, 2))
    s1 = np.sqrt(r[:, 0])
    bary = np.stack([1.0 - s1, s1 * (1.0 - r[:, 1]), s1 * r[:, 1]], axis=1)
    points = np.einsum("nk,nkd->nd", bary, tri[face_ids])
    normals = cross[face_ids] / np.maximum(area2[face_ids], 1e-300)[:, None]
    return points, face_ids, normals
