"""Mesh bytes: a mesh as binary PLY (exact float64 vertices), and a mesh from PLY or OBJ bytes.

Shared by the HOIInput / HOIResult folders (:mod:`easyhoi.io.hoi_io`) and the exports
(:mod:`easyhoi.io.export`).
"""

from __future__ import annotations

import io

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import check_mesh

__all__ = ["mesh_from_ply_bytes", "mesh_to_ply_bytes"]


def mesh_to_ply_bytes(mesh) -> bytes:
    """Binary little-endian PLY of a ``trimesh.Trimesh`` with float64 vertices (exact)."""
    check_mesh(mesh, "mesh")
    v = np.asarray(mesh.vertices, dtype="<f8")
    f = np.asarray(mesh.faces)
    colors = None
    if getattr(mesh.visual, "kind", None) == "vertex":
        colors = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment easyhoi",
        f"element vertex {len(v)}",
    ]
    header += [f"property double {a}" for a in "xyz"]
    vdt: list[tuple] = [("p", "<f8", (3,))]
    if colors is not None:
        header += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
        vdt.append(("c", "u1", (4,)))
    header += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    vd = np.zeros(len(v), dtype=vdt)
    vd["p"] = v
    if colors is not None:
        vd["c"] = colors
    fd = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    fd["n"] = 3
    fd["i"] = f
    return ("\n".join(header) + "\n").encode("ascii") + vd.tobytes() + fd.tobytes()


def mesh_from_ply_bytes(data: bytes, name: str = "mesh.ply", file_type: str = "ply"):
    """Parse mesh bytes (PLY or OBJ) into a validated ``trimesh.Trimesh`` (no processing)."""
    import trimesh

    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=file_type, process=False, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for corrupt files
        raise InvalidInputError(
            f"{name} is not a readable {file_type.upper()} mesh: {exc}"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"{name} does not hold a triangle mesh")
    check_mesh(mesh, name)
    return mesh
