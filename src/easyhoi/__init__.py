"""easyhoi: single-image 3D hand-object reconstruction on a CPU (the EasyHOI method)."""

from easyhoi.errors import (
    BackendError,
    EasyHOIError,
    InvalidInputError,
    MissingDependencyError,
)
from easyhoi.structures import Camera, HandOutput, HandParams

__version__ = "0.1.0"

__all__ = [
    "BackendError",
    "Camera",
    "EasyHOIError",
    "HandOutput",
    "HandParams",
    "InvalidInputError",
    "MissingDependencyError",
    "__version__",
]
