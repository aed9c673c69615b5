"""Adapters for large models loaded from LOCAL folders (no model hub access, ever).

Each adapter imports its heavy dependency only when it is instantiated and raises
:class:`~easyhoi.errors.MissingDependencyError` naming the extra that installs it:

=================================  ====================  =======================================
registry name                      module                extra (dependencies)
=================================  ====================  =======================================
``("amodal", "sam")``              :mod:`.sam`           ``sam`` (transformers)
``("object", "depth")``            :mod:`.depth`         ``depth`` (transformers)
``("inpainter", "diffusion")``     :mod:`.diffusion`     ``diffusion`` (diffusers, transformers)
``("segmenter", "grounded-sam")``  :mod:`.grounded_sam`  ``sam`` (transformers)
``("object", "shap-e")``           :mod:`.shap_e`        ``diffusion`` (diffusers, transformers)
=================================  ====================  =======================================

Weights are read with ``local_files_only=True`` from a folder the user gives (a folder written
by ``save_pretrained`` or a downloaded hub snapshot). Importing this package imports neither
transformers nor diffusers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from easyhoi.errors import InvalidInputError

__all__ = ["resolve_model_dir", "check_image", "check_bool_mask"]


def resolve_model_dir(path: str | Path | None, what: str, marker: str | None = None) -> Path:
    """The existing local folder holding a model, or :class:`InvalidInputError`.

    Args:
        path: folder given by the user.
        what: model name for the message ("SAM", "depth", "inpainting").
        marker: a file the folder must contain (``config.json``, ``model_index.json``).
    """
    if path is None:
        raise InvalidInputError(
            f"the {what} adapter needs model_dir, a local folder with the weights "
            "(nothing is downloaded)"
        )
    p = Path(path).expanduser()
    if not p.is_dir():
        raise InvalidInputError(
            f"{what} model folder not found: '{p}'; download the weights once and pass the "
            "local folder (nothing is downloaded)"
        )
    if marker is not None and not (p / marker).is_file():
        raise InvalidInputError(f"'{p}' is not a {what} model folder: it has no {marker}")
    return p


def check_image(image, name: str = "image") -> np.ndarray:
    """(H, W, 3) uint8 RGB or :class:`InvalidInputError`."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInputError(
            f"{name} must be an (H, W, 3) uint8 RGB array, got {img.shape} {img.dtype}"
        )
    return img


def check_bool_mask(mask, shape: tuple[int, int], name: str = "mask") -> np.ndarray:
    """(H, W) mask matching ``shape`` as bool, or :class:`InvalidInputError`."""
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise InvalidInputError(f"{name} is {m.shape} but the image is {tuple(shape)}")
    return m > 0.5 if m.dtype.kind == "f" else m.astype(bool)
