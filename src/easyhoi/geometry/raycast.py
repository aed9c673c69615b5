"""Ray casting against triangle meshes, every hit per ray (trimesh + Embree).

Used to cross-check the renderer's depth peeling and to render the depth maps fused by
:mod:`easyhoi.geometry.watertight`.
"""

from __future__ import annotations

import numpy as np
import trimesh

from easyhoi.checks import check_finite
from easyhoi.errors import InvalidInputError
from easyhoi.geometry.mesh import validate_mesh


def ray_intersector(mesh: trimesh.Trimesh, backend: str = "auto"):
    """A trimesh ray intersector: Embree (``"embree"``) or the rtree one (``"triangle"``).

    ``"auto"`` takes Embree when the ``embreex`` package imports, the rtree intersector otherwise.
    """
    if backend not in ("auto", "embree", "triangle"):
        raise InvalidInputError(f"backend must be 'auto', 'embree' or 'triangle', got {backend!r}")
    if backend in ("auto", "embree"):
        try:
            from trimesh.ray import ray_pyembree

            if ray_pyembree.RayMeshIntersector is not None:
                return ray_pyembree.RayMeshIntersector(mesh)
        except ImportError:
            pass
        if backend == "embree":
            from easyhoi.errors import MissingDependencyError

            raise MissingDependencyError("embreex", purpose="Embree ray casting")
    from trimesh.ray import ray_triangle

    return ray_triangle.RayMeshIntersector(mesh)


def _check_rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3:
        raise InvalidInputError(f"origins must have shape (N, 3), got {o.shape}")
    if d.shape != o.shape:
        raise InvalidInputError(f"directions must have shape {o.shape} like origins, got {d.shape}")
    check_finite(o, "origins")
    check_finite(d, "directions")
    norm = np.linalg.norm(d, axis=1)
    if len(norm) and norm.min() <= 0:
        raise InvalidInputError(f"directions must be non-zero; {int((norm <= 0).sum())} are zero")
    return o, d / norm[:, None]


def cast_rays_all_hits(
    mesh: trimesh.Trimesh,
    origins: np.ndarray,
    directions: np.ndarray,
    max_hits: int = 4,
    backend: str = "auto",
    dedup_tol: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Intersect rays with a mesh and keep the first ``max_hits`` hits of each ray, nearest first.

    Hits closer than ``dedup_tol`` along one ray are merged (a ray through a shared edge is
    reported once per adjacent face by Embree).

    Args:
        mesh (trimesh.Trimesh): The mesh to hit.
        origins ((N, 3) float): Ray origins. Only hits in front of the origin (depth >= 0) count.
        directions ((N, 3) float): Ray directions, non-zero (normalised here; depths are Euclidean
            distances).
        max_hits (int): K, the number of hit layers kept (4 matches the optimizer's depth peeling).
        backend (str): ``"auto"``, ``"embree"`` or ``"triangle"`` (see :func:`ray_intersector`).
        dedup_tol (float, optional): Merge distance; default ``1e-7`` times the mesh's bounding-box
            diagonal.

    Returns:
        points ((N, K, 3) float64): Hit positions; zeros where invalid.
        face_ids ((N, K) int64): Hit faces; -1 where invalid.
        depths ((N, K) float64): Distance from the origin; ``inf`` where invalid.
        valid ((N, K) bool): Which layers hold a hit.
    """
    validate_mesh(mesh)
    o, d = _check_rays(origins, directions)
    if not isinstance(max_hits, int | np.integer) or max_hits < 1:
        raise InvalidInputError(f"max_hits must be a positive integer, got {max_hits!r}")
    n, k = len(o), int(max_hits)
    points = np.zeros((n, k, 3))
    face_ids = np.full((n, k), -1, dtype=np.int64)
    depths = np.full((n, k), np.inf)
    valid = np.zeros((n, k), dtype=bool)
    if n == 0:
        return points, face_ids, depths, valid
    tol = dedup_tol if dedup_tol is not None else 1e-7 * float(np.linalg.norm(mesh.extents))
    loc, ray_idx, tri_idx = ray_intersector(mesh, backend).intersects_location(
        o, d, multiple_hits=k > 1
    )
    if len(loc) == 0:
        return points, face_ids, depths, valid
    loc = np.asarray(loc, dtype=np.float64)
    ray_idx = np.asarray(ray_idx, dtype=np.int64)
    tri_idx = np.asarray(tri_idx, dtype=np.int64)
    t = np.einsum("ij,ij->i", loc - o[ray_idx], d[ray_idx])
    keep = t >= -tol
    loc, ray_idx, tri_idx, t = loc[keep], ray_idx[keep], tri_idx[keep], t[keep]
    order = np.lexsort((t, ray_idx))
    loc, ray_idx, tri_idx, t = loc[order], ray_idx[order], tri_idx[order], t[order]
    # drop duplicates: same ray, depth within tol of the previous kept hit of that ray
    same_ray = np.r_[False, ray_idx[1:] == ray_idx[:-1]]
    dup = same_ray & (np.r_[np.inf, np.diff(t)] <= tol)
    loc, ray_idx, tri_idx, t = loc[~dup], ray_idx[~dup], tri_idx[~dup], t[~dup]
    # rank of each hit within its ray
    starts = np.r_[0, np.flatnonzero(ray_idx[1:] != ray_idx[:-1]) + 1]
    first = np.repeat(starts, np.diff(np.r_[starts, len(ray_idx)]))
    rank = np.arange(len(ray_idx)) - first
    sel = rank < k
    r, j = ray_idx[sel], rank[sel]
    points[r, j] = loc[sel]
    face_ids[r, j] = tri_idx[sel]
    depths[r, j] = np.maximum(t[sel], 0.0)
    valid[r, j] = True
    return points, face_ids, depths, valid


def cast_rays_first_hit(
    mesh: trimesh.Trimesh,
    origins: np.ndarray,
    directions: np.ndarray,
    backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit per ray: ``cast_rays_all_hits(..., max_hits=1)`` without the layer axis.

    Returns:
        points: (N, 3) float64, face_ids : (N,) int64, depths : (N,) float64, valid : (N,) bool
    """
    p, f, t, v = cast_rays_all_hits(mesh, origins, directions, max_hits=1, backend=backend)
    return p[:, 0], f[:, 0], t[:, 0], v[:, 0]
