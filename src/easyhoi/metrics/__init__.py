"""Evaluation metrics with the published conventions (docs/method.md section 3; docs/metrics.md).

Inputs are in metres; outputs in centimetres (cm, cm^2, cm^3) as the papers report.
"""

from easyhoi.metrics.hand import align_hands, mpjpe, mpvpe
from easyhoi.metrics.interaction import (
    contact_ratio,
    in_contact,
    intersection_volume,
    penetration_depth,
)
from easyhoi.metrics.object import (
    Alignment,
    FScoreSummary,
    ObjectMetrics,
    aggregate_fscore,
    align_points,
    chamfer_fscore,
    sample_surface,
)
from easyhoi.metrics.simulation import (
    Decomposition,
    SimResult,
    VHACDParams,
    clear_memory_cache,
    cone_displacement,
    convex_decomposition,
    default_cache_dir,
    gravity_cone,
    simulation_displacement,
)

__all__ = [
    "Alignment",
    "Decomposition",
    "FScoreSummary",
    "ObjectMetrics",
    "SimResult",
    "VHACDParams",
    "aggregate_fscore",
    "align_hands",
    "align_points",
    "chamfer_fscore",
    "clear_memory_cache",
    "contact_ratio",
    "convex_decomposition",
    "default_cache_dir",
    "in_contact",
    "intersection_volume",
    "mpjpe",
    "mpvpe",
    "penetration_depth",
    "sample_surface",
    "simulation_displacement",
    "cone_displacement",
    "gravity_cone",
]
