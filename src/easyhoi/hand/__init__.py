"""Hand models (built-in open hand, user-supplied MANO), region labels and keypoint fitting."""

from __future__ import annotations

import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.base import HandModel, mirror_params, mirror_points
from easyhoi.hand.regions import HandRegions

HAND_MODELS = ("open", "mano")


def load_hand_model(
    name: str = "open", mano_dir: str | None = None, dtype: torch.dtype = torch.float32
) -> HandModel:
    """Create a hand model by name.

    Args:
        name: "open" (built-in, freely licensed, default) or "mano" (needs the user's
            MANO_RIGHT.pkl: ``mano_dir`` or the ``EASYHOI_MANO_DIR`` environment variable).
        mano_dir: folder or file path of the user's MANO model.
        dtype: float32 or float64.
    """
    if name == "open":
        from easyhoi.hand.openhand import OpenHand

        return OpenHand(dtype=dtype)
    if name == "mano":
        from easyhoi.hand.mano import MANOHand

        return MANOHand(mano_dir).to(dtype)
    raise InvalidInputError(f"unknown hand model {name!r}; choose one of {HAND_MODELS}")


def builtin_hand_model(name: str, dtype: torch.dtype = torch.float32) -> HandModel:
    """The built-in hand model called ``name``: the one model that needs no user file.

    For callers that take an optional model and default to the built-in one. A MANO model is
    the user's file and is loaded once per run (:func:`easyhoi.settings.resolve_run`), so asking
    for it here is an error that says so.
    """
    if name == "open":
        return load_hand_model("open", dtype=dtype)
    if name == "mano":
        raise InvalidInputError(
            "the MANO hand model is not built in: load it once with "
            "easyhoi.settings.resolve_run (or load_hand_model('mano', mano_dir)) and pass it on"
        )
    raise InvalidInputError(f"unknown hand model {name!r}; choose one of {HAND_MODELS}")


__all__ = [
    "HAND_MODELS",
    "HandModel",
    "HandRegions",
    "builtin_hand_model",
    "load_hand_model",
    "mirror_params",
    "mirror_points",
]
