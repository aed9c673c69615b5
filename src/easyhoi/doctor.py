"""``easyhoi doctor``: installed versions, renderer kernels and perception backends.

The command answers in a fraction of the time a reconstruction needs to start, so it imports
none of the heavy libraries it reports on (torch, mediapipe, gradio, transformers...): a
library's presence is its import spec, its version comes from the installed distribution's
metadata, and the perception backends are read from the ``@register("role", "name")``
decorators in the backend modules' source instead of importing those modules (which import
torch).
"""

from __future__ import annotations

import ast
import importlib.metadata
import importlib.util
import os
import platform
from pathlib import Path

__all__ = ["LIBRARIES", "doctor_lines", "library_version", "registered_backends"]

#: Top-level modules reported, in this order.
LIBRARIES = (
    "torch", "numpy", "scipy", "trimesh", "embreex", "point_cloud_utils", "pymeshfix",
    "pybullet", "geomloss", "numba", "cv2", "skimage", "mediapipe", "transformers", "diffusers",
    "gradio", "ray",
)  # fmt: skip


def library_version(module: str, dists: dict[str, list[str]] | None = None) -> str | None:
    """Installed version of the distribution providing top-level ``module`` (not imported).

    Args:
        module: A top-level import name (``cv2``, ``skimage``, ...).
        dists: ``importlib.metadata.packages_distributions()``, when already computed.

    Returns:
        The version string, ``"installed"`` when the module is importable but no distribution
        metadata names it, or None when the module cannot be found.
    """
    if importlib.util.find_spec(module) is None:
        return None
    dists = importlib.metadata.packages_distributions() if dists is None else dists
    for name in dists.get(module, ()):
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return "installed"


def _register_calls(source: str) -> list[tuple[str, str]]:
    """``(role, name)`` of every ``@register("role", "name")`` decorator in ``source``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.ClassDef):
            continue
        for dec in node.decorator_list:
            if (
                isinstance(dec, ast.Call)
                and getattr(dec.func, "id", getattr(dec.func, "attr", None)) == "register"
                and len(dec.args) == 2
                and all(isinstance(a, ast.Constant) and isinstance(a.value, str) for a in dec.args)
            ):
                out.append((dec.args[0].value, dec.args[1].value))
    return out


def registered_backends() -> dict[str, list[str]]:
    """Perception backends per role, read from the built-in backend modules' source.

    Gives the same names as :func:`easyhoi.perception.base.available` without importing the
    backend modules (a test checks the two agree).
    """
    from easyhoi.perception.base import _BUILTIN_MODULES, ROLES

    found: dict[str, set[str]] = {role: set() for role in ROLES}
    for module in _BUILTIN_MODULES:
        spec = importlib.util.find_spec(module)
        if spec is None or spec.origin is None:
            continue
        for role, name in _register_calls(Path(spec.origin).read_text(encoding="utf-8")):
            found.setdefault(role, set()).add(name)
    return {role: sorted(names) for role, names in found.items()}


def _kernels_line() -> str:
    try:
        import numba  # noqa: F401 - the compiled kernels need only numba itself
    except Exception as exc:  # noqa: BLE001 - report anything that fails to import
        return f"renderer kernels: torch (slower fallback; numba not usable: {type(exc).__name__})"
    from easyhoi import aot

    if aot.loaded() is not None:
        return "renderer kernels: numba (compiled ahead of time for this machine)"
    return "renderer kernels: numba (compiled; `python -m easyhoi.aot` builds them ahead of time)"


def doctor_lines(version: str) -> list[str]:
    """The lines ``easyhoi doctor`` prints."""
    lines = [f"easyhoi {version}, Python {platform.python_version()}"]
    dists = importlib.metadata.packages_distributions()
    for mod in LIBRARIES:
        v = library_version(mod, dists)
        lines.append(f"  {mod:18s} {v if v is not None else 'not available'}")
    lines.append(_kernels_line())
    lines.append("backends:")
    for role, names in registered_backends().items():
        lines.append(f"  {role:10s} {', '.join(names)}")
    mano = os.environ.get("EASYHOI_MANO_DIR")
    lines.append(
        "MANO: " + (f"EASYHOI_MANO_DIR={mano}" if mano else
                    "not configured (built-in open hand is used; pass --mano-dir to use MANO)")
    )  # fmt: skip
    return lines
