"""A copy of ``scene.glb`` for web viewers, arranged so the first view is the photo's view.

Orbit viewers (gradio's ``Model3D``, a Babylon.js arc-rotate camera in a right-handed scene)
keep the world's +Y up and orbit around the centre of the model's bounding box, placed by
``(alpha, beta, radius)``: ``position = centre + radius (cos a sin b, cos b, sin a sin b)``.
The exported scene lives in the object's frame, whose +Y is arbitrary with respect to the photo,
so the viewer copy is expressed in the photo camera's glTF frame instead (x right, y up, z
towards the viewer: ``p' = diag(1, -1, -1) (R p + t)`` for the OpenCV camera ``R, t`` in
metres). The camera centre is then the origin, and :func:`orbit_to_origin` gives the
``(alpha, beta, radius)`` that put the viewer's camera there, looking at the model with the
photo's up direction. Geometry and colours are unchanged (a rigid motion); the downloadable
``scene.glb`` keeps the documented object frame.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from easyhoi.errors import InvalidInputError

#: OpenCV camera axes (x right, y down, z forward) -> glTF camera axes (x right, y up, z back).
CV_TO_GL = np.diag([1.0, -1.0, -1.0])


def orbit_to_origin(centre) -> tuple[float, float, float]:
    """``(alpha, beta)`` in degrees and ``radius`` of an arc-rotate camera at the origin.

    Inverse of ``position = centre + radius (cos a sin b, cos b, sin a sin b)`` for
    ``position = 0``.
    """
    d = -np.asarray(centre, dtype=np.float64).reshape(3)
    radius = float(np.linalg.norm(d))
    if not np.isfinite(radius) or radius == 0:
        raise InvalidInputError("the model's centre coincides with the camera")
    beta = math.acos(max(-1.0, min(1.0, d[1] / radius)))
    alpha = math.atan2(d[2], d[0])
    return math.degrees(alpha), math.degrees(beta), radius


def orbit_position(centre, alpha: float, beta: float, radius: float) -> np.ndarray:
    """The arc-rotate camera position for ``(alpha, beta)`` in degrees (for checks)."""
    a, b = math.radians(alpha), math.radians(beta)
    offset = radius * np.array([math.cos(a) * math.sin(b), math.cos(b), math.sin(a) * math.sin(b)])
    return np.asarray(centre, dtype=np.float64) + offset


#: Vertical field of view (radians) of the viewer's camera (Babylon.js default).
VIEWER_FOV = 0.8


def photo_view_glb(
    scene_glb: str | Path, R, t, K=None, height: int | None = None
) -> tuple[bytes, tuple[float, float, float]]:
    """Viewer copy of ``scene_glb`` in the photo camera's glTF frame and its first view.

    Args:
        scene_glb: ``scene.glb`` of a result folder (metres, object frame).
        R: (3, 3) world-to-camera rotation (OpenCV), ``t``: (3,) translation in metres
            (``result.json``'s ``camera``).
        K, height: the photo's intrinsics and height in pixels; when given, the radius is
            scaled by ``tan(fov_photo / 2) / tan(VIEWER_FOV / 2)`` so that the model fills the
            viewer about as much as the photo (same direction, different distance: the viewer's
            field of view is wider than most photos').

    Returns:
        (GLB bytes, (alpha degrees, beta degrees, radius metres)).

    Raises:
        InvalidInputError: unreadable GLB, no meshes, or a bad camera.
    """
    import trimesh

    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise InvalidInputError("camera R must be (3, 3) and t (3,), finite")
    try:
        scene = trimesh.load(str(scene_glb), file_type="glb", force="scene")
    except Exception as exc:  # noqa: BLE001 - any loader failure is a bad file
        raise InvalidInputError(f"cannot read {Path(scene_glb).name}: {exc}") from None
    meshes = scene.dump(concatenate=False)  # world-space copies, visuals kept
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces)]
    if not meshes:
        raise InvalidInputError(f"{Path(scene_glb).name} holds no mesh")
    T = np.eye(4)
    T[:3, :3] = CV_TO_GL @ R
    T[:3, 3] = CV_TO_GL @ t
    out = trimesh.Scene()
    for i, m in enumerate(meshes):
        m = m.copy()
        m.apply_transform(T)
        out.add_geometry(m, geom_name=m.metadata.get("name") or f"mesh_{i}")
    lo, hi = out.bounds
    alpha, beta, radius = orbit_to_origin((lo + hi) / 2.0)
    if K is not None and height is not None:
        fy = float(np.asarray(K, dtype=np.float64)[1, 1])
        if np.isfinite(fy) and fy > 0 and int(height) > 0:
            radius *= (0.5 * int(height) / fy) / math.tan(VIEWER_FOV / 2)
    view = (alpha, beta, radius)
    buf = io.BytesIO()
    out.export(buf, file_type="glb")
    return buf.getvalue(), view
