"""Rendering: differentiable soft silhouettes, occlusion-aware HOI masks, depth peeling.

Compiled numba kernels on the CPU, vectorized torch kernels on any device (a GPU included: they
run wherever their inputs are). See docs/rendering.md for the design, conventions and measured
performance, docs/gpu.md for the GPU path.
"""

from easyhoi.render.composite import HOIMasks, extend_depth, hoi_masks
from easyhoi.render.raster import Fragments, depth_map, peel, peel_pixels, rasterize
from easyhoi.render.soft import (
    cull_margin,
    get_backend,
    set_backend,
    set_compile,
    sigma_from_ndc,
    soft_log_visibility,
    soft_silhouette,
)

__all__ = [
    "Fragments",
    "HOIMasks",
    "cull_margin",
    "depth_map",
    "extend_depth",
    "get_backend",
    "hoi_masks",
    "peel",
    "peel_pixels",
    "rasterize",
    "set_backend",
    "set_compile",
    "sigma_from_ndc",
    "soft_log_visibility",
    "soft_silhouette",
]
