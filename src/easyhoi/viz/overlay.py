"""The reconstruction drawn over the photo: shaded hand and object, semi-transparent.

Meshes are drawn in the object frame (object units) with the result's fitted camera, so the
picture shows exactly what the optimizer matched against the masks.
"""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIResult, StageResult
from easyhoi.structures import Camera
from easyhoi.viz.shade import HAND_COLOR, OBJECT_COLOR, Render, SceneMesh, render_shaded

__all__ = [
    "OVERLAY_ALPHA",
    "photo_camera",
    "render_overlay",
    "result_meshes",
    "shrink_photo",
    "stage_meshes",
]

#: Opacity of the meshes in overlays.
OVERLAY_ALPHA = 0.65


def _check_result(result) -> HOIResult:
    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    return result


def _object_mesh(result: HOIResult, color) -> SceneMesh:
    m = result.object_mesh
    return SceneMesh(np.asarray(m.vertices), np.asarray(m.faces), color, "object")


def result_meshes(
    result: HOIResult, hand_color=HAND_COLOR, object_color=OBJECT_COLOR
) -> list[SceneMesh]:
    """The final hand and the object in the object frame (object units): ``[hand, object]``."""
    result = _check_result(result)
    hand = SceneMesh(result.hand_vertices, result.hand_faces, hand_color, "hand")
    return [hand, _object_mesh(result, object_color)]


def stage_meshes(
    result: HOIResult,
    stage: StageResult,
    hand_model=None,
    hand_color=HAND_COLOR,
    object_color=OBJECT_COLOR,
) -> tuple[list[SceneMesh], Camera, str]:
    """What one stage snapshot looked like.

    Args:
        result: HOIResult
        stage (StageResult): One of ``result.stages``.
        hand_model (HandModel or None): Poses the snapshot's hand parameters; without it only the
            final stage can show the hand (from ``result.hand_vertices``).

    Returns:
        meshes (list of SceneMesh): The hand (when known) and the object, in object units.
        camera (Camera): The stage's camera (the final camera when the snapshot has none).
        note (str): Empty, or why the hand is missing.
    """
    scale = stage.metric_scale if stage.metric_scale else result.metric_scale
    camera = stage.camera if stage.camera is not None else result.camera
    meshes: list[SceneMesh] = []
    note = ""
    is_last = bool(result.stages) and stage is result.stages[-1]
    if stage.hand_params is not None and hand_model is not None:
        out = hand_model(stage.hand_params.detach().to(dtype=torch.float64))
        verts = out.vertices[0].numpy() / scale
        meshes.append(SceneMesh(verts, out.faces.numpy(), hand_color, "hand"))
    elif is_last:
        meshes.append(result_meshes(result, hand_color)[0])
    else:
        note = "no hand in snapshot" if stage.hand_params is None else "hand model unavailable"
    meshes.append(_object_mesh(result, object_color))
    return meshes, camera, note


def photo_camera(camera: Camera, image: np.ndarray) -> Camera:
    """``camera`` for the photo's pixel grid (rescaled when the sizes differ)."""
    H, W = image.shape[:2]
    if (camera.height, camera.width) == (H, W):
        return camera
    return camera.resized(W, H)


def shrink_photo(image: np.ndarray, width: int | None) -> np.ndarray:
    """``image`` downscaled (area average, aspect kept) to ``width`` pixels when it is wider.

    Overlays drawn on the result take the camera from the image's size
    (:func:`photo_camera`), so a picture shown small is also drawn small: the rasterizer's and
    the PNG encoder's work grow with the pixel count.
    """
    H, W = image.shape[:2]
    if width is None or W <= width:
        return image
    import cv2

    h = max(1, round(H * width / W))
    return cv2.resize(image, (int(width), h), interpolation=cv2.INTER_AREA)


def _check_image(image) -> np.ndarray:
    im = np.asarray(image)
    if im.ndim != 3 or im.shape[2] != 3 or im.dtype != np.uint8:
        raise InvalidInputError(
            f"photo must be an (H, W, 3) uint8 image, got {im.shape} {im.dtype}"
        )
    return im


def render_overlay(
    result: HOIResult,
    image: np.ndarray,
    alpha: float = OVERLAY_ALPHA,
    meshes: list[SceneMesh] | None = None,
    camera: Camera | None = None,
) -> Render:
    """Hand and object shaded over the photo.

    Args:
        result: HOIResult
        image ((H, W, 3) uint8): The photo.
        alpha (float): Mesh opacity.
        meshes, camera (optional): Draw these instead of the final reconstruction (used for stage
            snapshots).

    Returns:
        Render: Same size as the photo; pixels no mesh covers are the photo's, unchanged.
    """
    result = _check_result(result)
    image = _check_image(image)
    meshes = result_meshes(result) if meshes is None else meshes
    cam = photo_camera(result.camera if camera is None else camera, image)
    return render_shaded(meshes, cam, background=image, alpha=alpha)
