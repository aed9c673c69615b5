"""Exports people can open: a GLB scene, PLY meshes and a self-describing JSON summary.

Everything exported here is in METRES, in the *metric object frame* (the object's canonical
frame scaled by ``HOIResult.metric_scale``, see :mod:`easyhoi.hoi`):

* hand vertices = ``result.hand_vertices * metric_scale`` (equal to posing ``hand_params``);
* object vertices = ``result.object_mesh.vertices * metric_scale``;
* camera: ``K`` and ``R`` unchanged, ``t_metric = t * metric_scale`` (OpenCV convention,
  ``x_cam = R @ x_world + t``).

In the GLB the camera is a glTF perspective camera node whose matrix is the camera-to-world
pose converted from OpenCV axes (x right, y down, z forward) to glTF axes (x right, y up, looking
down -z): ``pose = [R^T | -R^T t_metric] @ diag(1, -1, -1, 1)``. glTF cannot express an
off-centre principal point; the exact ``K`` is kept in the camera's ``extras``.

For a reloadable result (object units, float64) use :func:`easyhoi.io.hoi_io.save_hoi_result`.
"""

from __future__ import annotations

import json
import math
import platform
import struct
from pathlib import Path

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIResult, check_mesh
from easyhoi.io.atomic import atomic_write_bytes, atomic_write_text
from easyhoi.io.ply import mesh_to_ply_bytes
from easyhoi.structures import Camera

__all__ = [
    "EXPORT_SCHEMA",
    "camera_gltf",
    "export_glb",
    "export_ply",
    "glb_bytes",
    "metric_camera",
    "result_json",
    "write_result_json",
]

EXPORT_SCHEMA = "easyhoi.export"
EXPORT_VERSION = 1

_GLB_MAGIC = 0x46546C67
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_OPENCV_TO_GLTF = np.diag([1.0, -1.0, -1.0, 1.0])
HAND_RGBA = (236, 178, 140, 255)
OBJECT_RGBA = (70, 130, 230, 255)


def _check(result) -> HOIResult:
    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    return result


def metric_camera(result: HOIResult) -> Camera:
    """The result's camera for the metric object frame (``t`` scaled to metres), float64."""
    import torch

    c = _check(result).camera.detach().to(dtype=torch.float64)
    return Camera(c.K, c.R, c.t * result.metric_scale, c.width, c.height)


def camera_gltf(camera: Camera, znear: float = 0.01) -> tuple[dict, np.ndarray]:
    """A glTF perspective camera and its node pose for an OpenCV camera.

    Args:
        camera (Camera): World-to-camera extrinsics in the glTF scene's units.
        znear (float): Near plane distance (scene units), > 0.

    Returns:
        gltf_camera (dict): ``{"type": "perspective", "perspective": {yfov, aspectRatio, znear},
            "extras": {...}}`` with ``yfov = 2 atan(H / (2 fy))`` and ``aspectRatio = W fy / (H
            fx)`` (so the horizontal field of view is ``2 atan(W / (2 fx))``).
        pose ((4, 4) float64): Camera-to-world matrix with glTF camera axes (y up, looking down -z).
    """
    c = camera.detach()
    K = c.K.double().numpy()
    R = c.R.double().numpy()
    t = c.t.double().numpy()
    fx, fy = float(K[0, 0]), float(K[1, 1])
    W, H = c.width, c.height
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = -R.T @ t
    pose = c2w @ _OPENCV_TO_GLTF
    cam = {
        "name": "photo_camera",
        "type": "perspective",
        "perspective": {
            "yfov": 2.0 * math.atan(H / (2.0 * fy)),
            "aspectRatio": W * fy / (H * fx),
            "znear": float(znear),
        },
        "extras": {
            "K": K.tolist(),
            "width": W,
            "height": H,
            "convention": "K in pixels, OpenCV; pose converted to glTF camera axes",
        },
    }
    return cam, pose


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def _add_camera_to_glb(glb: bytes, cam: dict, pose: np.ndarray) -> bytes:
    """Insert a camera node into a GLB file's JSON chunk."""
    magic, version, _ = struct.unpack_from("<III", glb, 0)
    if magic != _GLB_MAGIC or version != 2:
        raise InvalidInputError("not a glTF 2.0 binary")
    off = 12
    chunks = []
    while off < len(glb):
        length, kind = struct.unpack_from("<II", glb, off)
        chunks.append((kind, glb[off + 8 : off + 8 + length]))
        off += 8 + length
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise InvalidInputError("GLB file has no JSON chunk first")
    doc = json.loads(chunks[0][1].decode("utf-8"))
    doc.setdefault("cameras", []).append(cam)
    nodes = doc.setdefault("nodes", [])
    nodes.append({"name": "photo_camera", "camera": len(doc["cameras"]) - 1,
                  "matrix": [float(x) for x in pose.flatten(order="F")]})  # fmt: skip
    scene = doc.setdefault("scenes", [{"nodes": []}])[doc.get("scene", 0)]
    scene.setdefault("nodes", []).append(len(nodes) - 1)
    body = _pad(json.dumps(doc, separators=(",", ":")).encode("utf-8"), b" ")
    parts = [struct.pack("<II", len(body), _CHUNK_JSON), body]
    for kind, data in chunks[1:]:
        data = _pad(data, b"\0") if kind == _CHUNK_BIN else data
        parts += [struct.pack("<II", len(data), kind), data]
    payload = b"".join(parts)
    return struct.pack("<III", _GLB_MAGIC, 2, 12 + len(payload)) + payload


def glb_bytes(result: HOIResult) -> bytes:
    """The scene as GLB bytes: hand (skin colour), object (its colours) and the photo camera.

    Meshes and camera are in metres (metric object frame, see the module docstring).
    """
    import trimesh

    result = _check(result)
    s = result.metric_scale
    hand = trimesh.Trimesh(result.hand_vertices * s, result.hand_faces, process=False)
    hand.visual = trimesh.visual.ColorVisuals(
        hand, vertex_colors=np.tile(HAND_RGBA, (len(hand.vertices), 1))
    )
    obj = result.object_mesh_metric()
    if getattr(obj.visual, "kind", None) is None:
        obj.visual = trimesh.visual.ColorVisuals(
            obj, vertex_colors=np.tile(OBJECT_RGBA, (len(obj.vertices), 1))
        )
    scene = trimesh.Scene()
    scene.add_geometry(hand, node_name="hand", geom_name="hand")
    scene.add_geometry(obj, node_name="object", geom_name="object")
    cam = metric_camera(result)
    target = np.asarray(obj.bounds).mean(0)
    dist = float(np.linalg.norm(cam.R.numpy() @ target + cam.t.numpy()))
    gcam, pose = camera_gltf(cam, znear=max(1e-4, 0.01 * dist))
    return _add_camera_to_glb(scene.export(file_type="glb"), gcam, pose)


def export_glb(result: HOIResult, path: str | Path) -> Path:
    """Write :func:`glb_bytes` to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, glb_bytes(result))


def export_ply(mesh, path: str | Path) -> Path:
    """Write a ``trimesh.Trimesh`` as binary PLY (float64 vertices, vertex colours if any)."""
    check_mesh(mesh, "mesh")
    return atomic_write_bytes(path, mesh_to_ply_bytes(mesh))


def _versions() -> dict:
    import numpy
    import torch
    import trimesh

    import easyhoi

    return {
        "easyhoi": easyhoi.__version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "torch": torch.__version__,
        "trimesh": trimesh.__version__,
    }


def result_json(result: HOIResult) -> dict:
    """A JSON-ready summary of a reconstruction, in metres.

    Keys: ``schema``, ``version``, ``units`` ("metres"), ``frame``, ``hand_model``, ``hand``
    (MANO layout: ``global_orient`` 3, ``transl`` 3, ``pose`` 45, ``betas`` 10, ``side``),
    ``camera`` (``K``, ``R``, ``t`` in metres, ``width``, ``height``, ``convention``),
    ``camera_object_units`` (the same camera before scaling), ``metric_scale``,
    ``plausibility``, ``timings``, ``stages`` (name, iterations, seconds, stop reason, final
    losses; the refinement's ``close_gap`` note when it ran: the gap before, whether the hand
    was moved along its rays, and ``meet``, whether and how far the object was moved onto the
    hand), ``versions``, ``seed``, ``config``, ``meta``.
    """
    result = _check(result)
    p = result.hand_params.detach()
    cam = metric_camera(result).to_dict()
    stages = []
    for st in result.stages:
        last = {k: v for k, v in (st.losses[-1] if st.losses else {}).items()}
        entry = {"name": st.name, "iterations": int(st.iterations),
                 "seconds": float(st.seconds), "stop_reason": st.stop_reason,
                 "final_losses": _json_safe(last)}  # fmt: skip
        if (st.extra or {}).get("close_gap") is not None:
            entry["close_gap"] = _json_safe(st.extra["close_gap"])
        stages.append(entry)
    return {
        "schema": EXPORT_SCHEMA,
        "version": EXPORT_VERSION,
        "units": "metres",
        "frame": "metric object frame: the object's canonical frame scaled by metric_scale",
        "hand_model": result.hand_model,
        "hand": {
            "global_orient": p.global_orient[0].double().tolist(),
            "transl": p.transl[0].double().tolist(),
            "pose": p.pose[0].double().tolist(),
            "betas": p.betas[0].double().tolist(),
            "side": p.side,
            "layout": "MANO: global_orient 3 (axis-angle) + transl 3 (m) + pose 45 "
            "(15 joints axis-angle, flat mean) + betas 10",
            "num_vertices": int(len(result.hand_vertices)),
        },
        "camera": cam,
        "camera_object_units": result.camera.to_dict(),
        "metric_scale": result.metric_scale,
        "metric_scale_meaning": "metres per object unit",
        "plausibility": _json_safe(result.plausibility),
        "hand_change": _json_safe(result.hand_change),
        "timings": _json_safe(result.timings),
        "stages": stages,
        "versions": _versions(),
        "seed": int(result.seed),
        "config": _json_safe(result.config),
        "meta": _json_safe(result.meta),
    }


def _json_safe(v):
    """Plain floats; NaN and infinities become None (strict JSON has no NaN)."""
    if isinstance(v, dict):
        return {str(k): _json_safe(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json_safe(x) for x in v]
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return v
    if isinstance(v, int | np.integer):
        return int(v)
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f if math.isfinite(f) else None


def write_result_json(result: HOIResult, path: str | Path) -> Path:
    """Write :func:`result_json` to ``path`` atomically (indented, strict JSON)."""
    return atomic_write_text(path, json.dumps(result_json(result), indent=1, allow_nan=False))
