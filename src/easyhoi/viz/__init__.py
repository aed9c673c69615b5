"""Pictures of a reconstruction: shaded overlays, other viewpoints, stages, masks, loss curves.

Everything renders on the CPU with the project's own hard rasterizer
(:mod:`easyhoi.render.raster`); the figures (views, stages, masks) are composed and the loss
curves drawn with Pillow (:mod:`easyhoi.viz.compose`, :mod:`easyhoi.viz.chart`); no OpenGL,
no matplotlib (:func:`easyhoi.viz.plots.new_figure` serves the benchmark's tables).
Functions named ``*_png`` return PNG bytes (write them with :mod:`easyhoi.io.atomic`).
"""

from easyhoi.viz.masks import mask_iou, mask_ious, masks_png, rendered_masks
from easyhoi.viz.overlay import render_overlay, result_meshes, stage_meshes
from easyhoi.viz.plots import losses_png, png_bytes
from easyhoi.viz.shade import HAND_COLOR, OBJECT_COLOR, Render, SceneMesh, render_shaded
from easyhoi.viz.stages import render_stages, stages_png
from easyhoi.viz.views import VIEW_NAMES, render_views, view_cameras, views_png

__all__ = [
    "HAND_COLOR",
    "OBJECT_COLOR",
    "VIEW_NAMES",
    "Render",
    "SceneMesh",
    "losses_png",
    "mask_iou",
    "mask_ious",
    "masks_png",
    "png_bytes",
    "render_overlay",
    "render_shaded",
    "render_stages",
    "render_views",
    "rendered_masks",
    "result_meshes",
    "stage_meshes",
    "stages_png",
    "view_cameras",
    "views_png",
]
