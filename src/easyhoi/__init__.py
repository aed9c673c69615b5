"""easyhoi: single-image 3D hand-object reconstruction on a CPU (the EasyHOI method).

The small public API (every name that needs torch is imported on first use)::

    from easyhoi import reconstruct_photo, resolve_run, optimize, get_preset
    rec = reconstruct_photo("photo.jpg", "results/photo")  # photo -> result folder
    run = resolve_run(get_preset("fast"), seed=3)          # config + hand model + seed, once
    rec = reconstruct_photo("photo.jpg", "results/photo", run)
    result = optimize(hoi_input, run.config.optim, hand_model=run.hand_model)
"""

from easyhoi.errors import (
    BackendError,
    EasyHOIError,
    InvalidInputError,
    MissingDependencyError,
)

__version__ = "0.1.0"

#: Public names imported on first use: ``import easyhoi`` (and so ``easyhoi --help``) must not
#: pay for torch, which every one of these pulls in.
_LAZY = {
    "Camera": ("easyhoi.structures", "Camera"),
    "HandOutput": ("easyhoi.structures", "HandOutput"),
    "HandParams": ("easyhoi.structures", "HandParams"),
    "reconstruct_photo": ("easyhoi.pipeline", "reconstruct_photo"),
    "optimize": ("easyhoi.optim.run", "optimize"),
    "HOIInput": ("easyhoi.hoi", "HOIInput"),
    "HOIResult": ("easyhoi.hoi", "HOIResult"),
    "get_preset": ("easyhoi.config", "get_preset"),
    "EasyHOIConfig": ("easyhoi.config", "EasyHOIConfig"),
    "RunSettings": ("easyhoi.settings", "RunSettings"),
    "resolve_run": ("easyhoi.settings", "resolve_run"),
    "write_result_folder": ("easyhoi.result_folder", "write_result_folder"),
    "load_hand_model": ("easyhoi.hand", "load_hand_model"),
    "save_hoi_input": ("easyhoi.io.hoi_io", "save_hoi_input"),
    "load_hoi_input": ("easyhoi.io.hoi_io", "load_hoi_input"),
    "save_hoi_result": ("easyhoi.io.hoi_io", "save_hoi_result"),
    "load_hoi_result": ("easyhoi.io.hoi_io", "load_hoi_result"),
    "evaluate_result": ("easyhoi.evaluate", "evaluate_result"),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'easyhoi' has no attribute {name!r}")


__all__ = [
    "BackendError",
    "EasyHOIError",
    "InvalidInputError",
    "MissingDependencyError",
    "__version__",
    *_LAZY,
]


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
