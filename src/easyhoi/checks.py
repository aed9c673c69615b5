"""Input guards that raise :class:`InvalidInputError` stating what was expected and what came."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from easyhoi.errors import InvalidInputError

ArrayLike = torch.Tensor | np.ndarray
_NUMPY_FLOATS = (torch.float32, torch.float64)


def check_shape(x: ArrayLike, shape: Sequence[int | None], name: str) -> None:
    """Raise unless ``x.shape`` matches ``shape``; ``None`` entries match any size.

    A leading ``...`` is not supported: pass the full expected shape.
    """
    actual = tuple(x.shape)
    if len(actual) != len(shape) or any(
        s is not None and s != a for s, a in zip(shape, actual, strict=False)
    ):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InvalidInputError(f"{name} must have shape {want}, got {actual}")


def check_last_dim(x: ArrayLike, size: int, name: str) -> None:
    if x.ndim < 1 or x.shape[-1] != size:
        raise InvalidInputError(f"{name} must have shape (..., {size}), got {tuple(x.shape)}")


def check_finite(x: ArrayLike, name: str) -> None:
    if isinstance(x, torch.Tensor):
        if x.device.type == "cpu" and x.dtype in _NUMPY_FLOATS:
            # the same test through a zero-copy numpy view: a third of torch's per-call cost
            ok = np.isfinite(x.detach().numpy()).all()
        else:
            ok = torch.isfinite(x).all().item()
    else:
        ok = np.isfinite(x).all()
    if not ok:
        raise InvalidInputError(f"{name} contains NaN or infinite values")


def check_faces(faces: ArrayLike, num_vertices: int, name: str = "faces") -> None:
    """Faces must be (F, 3) integers indexing existing vertices."""
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InvalidInputError(f"{name} must have shape (F, 3), got {tuple(faces.shape)}")
    if faces.shape[0] == 0:
        return
    if isinstance(faces, torch.Tensor) and faces.dtype != torch.bool:
        lo, hi = (int(v) for v in torch.aminmax(faces))
    else:
        lo, hi = int(faces.min()), int(faces.max())
    if lo < 0 or hi >= num_vertices:
        raise InvalidInputError(
            f"{name} index vertices in [{lo}, {hi}] but there are only {num_vertices} vertices"
        )
