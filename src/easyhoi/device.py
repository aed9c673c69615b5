"""Device names of a run: "cpu", "cuda" / "cuda:N", or "auto" (resolved once per run).

The device is chosen by ``--device`` (config field ``device``) and resolved by
:func:`resolve_device` inside :func:`easyhoi.settings.resolve_run`. "auto" is cuda when torch
sees a GPU and cpu otherwise, so a user with a GPU gets the large models at GPU speed without
asking (the optimizer then stays on the CPU, where it is faster:
:attr:`easyhoi.settings.RunSettings.optim_device`); asking for cuda where there is none is an
error, never a silent fallback (the run would be far slower than the user planned for).

Checking a name needs no torch; resolving "auto" or "cuda" imports it.
"""

from __future__ import annotations

import re

from easyhoi.errors import InvalidInputError

__all__ = ["DEVICES", "check_device_name", "resolve_device"]

#: Device names a run accepts ("cuda:N" picks GPU N).
DEVICES = ("auto", "cpu", "cuda")

_CUDA_INDEX = re.compile(r"cuda:(0|[1-9][0-9]*)")


def check_device_name(name) -> str:
    """``name`` when it is "auto", "cpu", "cuda" or "cuda:N"; InvalidInputError otherwise."""
    if not isinstance(name, str) or not (name in DEVICES or _CUDA_INDEX.fullmatch(name)):
        raise InvalidInputError(
            f"device must be one of {', '.join(DEVICES)} or cuda:N, got {name!r}"
        )
    return name


def resolve_device(name: str = "auto") -> str:
    """The concrete device of a run: "cpu", "cuda" or "cuda:N".

    Raises:
        InvalidInputError: an unknown name, or a cuda device that torch does not see (no GPU,
            no driver, a CPU-only torch build, or an index past the last GPU).
    """
    check_device_name(name)
    if name == "cpu":
        return "cpu"
    import torch

    available = torch.cuda.is_available()
    if name == "auto":
        return "cuda" if available else "cpu"
    if not available:
        build = "a CPU-only build" if torch.version.cuda is None else f"CUDA {torch.version.cuda}"
        raise InvalidInputError(
            f"device {name!r} asked for, but torch sees no CUDA GPU (torch {torch.__version__}, "
            f"{build}); use --device cpu or auto"
        )
    if ":" in name:
        index, count = int(name.split(":")[1]), torch.cuda.device_count()
        if index >= count:
            raise InvalidInputError(f"device {name!r} asked for, but torch sees {count} GPU(s)")
    return name
