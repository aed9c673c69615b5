"""The reconstruction seen from other viewpoints around the object centre.

Viewpoints are defined relative to the photo's camera so that "front" looks like the photo:

* ``front``: from the photo camera's side, along its viewing direction;
* ``side``:  from the photo's right, looking left;
* ``top``:   from above the photo's up direction, the photo camera at the bottom of the picture;
* ``back``:  from behind the object, facing the photo camera.

Every view looks at the object's bounding-box centre from a distance that fits the bounding
sphere of hand and object into a 30 degree field of view.
"""

from __future__ import annotations

import math

import numpy as np

from easyhoi.hoi import HOIResult
from easyhoi.structures import Camera
from easyhoi.viz.compose import Panel, compose_grid
from easyhoi.viz.overlay import _check_result, result_meshes
from easyhoi.viz.plots import png_bytes
from easyhoi.viz.shade import SceneMesh, render_shaded

__all__ = ["VIEW_NAMES", "VIEW_SIZE", "render_views", "view_cameras", "views_png"]

VIEW_NAMES = ("front", "side", "top", "back")
#: Side of each rendered view in pixels.
VIEW_SIZE = 320
_FOV_DEG = 30.0
_MARGIN = 1.08
_BACKGROUND = (250, 250, 250)


def view_cameras(
    center, radius: float, photo_camera: Camera, size: int = VIEW_SIZE
) -> dict[str, Camera]:
    """Cameras around ``center`` oriented from the photo camera's axes.

    Args:
        center ((3,) float): Point every view looks at (world frame).
        radius (float): Radius of a sphere around ``center`` that must fit in every view.
        photo_camera (Camera): Its rotation defines front / side / top / back.
        size (int): Width and height of each view in pixels.

    Returns:
        dict of str -> Camera: Keyed by :data:`VIEW_NAMES`.
    """
    c = np.asarray(center, dtype=np.float64)
    R = photo_camera.detach().R.double().numpy()
    x, y, z = R  # camera axes in world coordinates (right, down, forward)
    half = math.radians(_FOV_DEG) / 2
    dist = max(float(radius), 1e-9) / math.sin(half) * _MARGIN
    focal = 0.5 * size / math.tan(half)
    up = -y
    spec = {
        "front": (c - dist * z, up),
        "side": (c + dist * x, up),
        "top": (c - dist * y, z),
        "back": (c + dist * z, up),
    }
    return {
        name: Camera.look_at(eye, c, up=u, focal=focal, width=size, height=size)
        for name, (eye, u) in spec.items()
    }


def _frame(meshes: list[SceneMesh], object_mesh: SceneMesh) -> tuple[np.ndarray, float]:
    lo, hi = object_mesh.vertices.min(0), object_mesh.vertices.max(0)
    center = (lo + hi) / 2
    allv = np.concatenate([m.vertices for m in meshes])
    radius = float(np.linalg.norm(allv - center, axis=1).max())
    return center, radius


def render_views(result: HOIResult, size: int | None = None) -> dict[str, np.ndarray]:
    """Shaded renders of the final hand and object from :data:`VIEW_NAMES`.

    ``size`` defaults to :data:`VIEW_SIZE` (read at call time).

    Returns:
        dict of str -> (size, size, 3) uint8
    """
    result = _check_result(result)
    size = VIEW_SIZE if size is None else int(size)
    meshes = result_meshes(result)
    center, radius = _frame(meshes, meshes[1])
    cams = view_cameras(center, radius, result.camera, size)
    bg = np.array(_BACKGROUND, dtype=np.uint8)
    return {k: render_shaded(meshes, cam, background=bg).image for k, cam in cams.items()}


def views_png(result: HOIResult, size: int | None = None) -> bytes:
    """One PNG with the four views side by side, titled, with a colour legend.

    Each view is rendered ``size`` pixels square (default :data:`VIEW_SIZE`) and shown
    :data:`VIEW_SIZE` pixels wide.
    """
    views = render_views(result, size)
    legend = [(m.name, m.color) for m in result_meshes(result)]
    panels = [Panel(img, name) for name, img in views.items()]
    fig = compose_grid(
        panels, len(panels), VIEW_SIZE, legend=legend,
        title="Reconstruction from other viewpoints (around the object centre)",
    )  # fmt: skip
    return png_bytes(fig)
