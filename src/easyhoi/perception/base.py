"""Role protocols, their data types, and the backend registry.

Five roles turn a photo into the optimizer's inputs; each has an offline default and optional
adapters for large models loaded from local folders:

=====================  ==============================================================
role                   protocol
=====================  ==============================================================
``hand``               :class:`HandEstimator`: photo -> hands (keypoints, parameters, camera)
``segmenter``          :class:`HOISegmenter`: photo + hand -> visible hand / held-object masks
``inpainter``          :class:`Inpainter`: photo + mask -> photo with the hand removed
``amodal``             :class:`AmodalSegmenter`: inpainted photo + prompts -> amodal object mask
``object``             :class:`ObjectReconstructor`: object crop + mask -> object mesh
=====================  ==============================================================

Backends register with ``@register("role", "name")`` and are created by name with
:func:`create`. A backend module imports its heavy dependency lazily (inside ``__init__`` or
the method) and raises :class:`~easyhoi.errors.MissingDependencyError` naming the extra to
install; importing this module never imports a backend's dependency.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from easyhoi.errors import InvalidInputError

ROLES = ("hand", "segmenter", "inpainter", "amodal", "object")


# ----------------------------------------------------------------------------------------------
# data passed between roles (numpy, image conventions: (H, W, 3) uint8 RGB, (H, W) bool masks)
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HandDetection:
    """One detected hand.

    Attributes:
        keypoints2d: (21, 2) float pixel coordinates (u, v), OpenPose order.
        keypoints3d: (21, 3) float metric 3D keypoints in a camera-aligned frame (x right,
            y down, z forward), up to an unknown translation, or None.
        side: "right" or "left".
        score: detection confidence in [0, 1].
        params: fitted :class:`~easyhoi.structures.HandParams` in ``camera``'s frame, or None.
        camera: the :class:`~easyhoi.structures.Camera` the params are expressed in, or None.
        meta: backend-specific extras (JSON-serialisable).
    """

    keypoints2d: np.ndarray
    keypoints3d: np.ndarray | None
    side: str
    score: float
    params: Any = None
    camera: Any = None
    meta: dict = field(default_factory=dict)

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        """(u_min, v_min, u_max, v_max) of the 2D keypoints."""
        k = self.keypoints2d
        return (float(k[:, 0].min()), float(k[:, 1].min()), float(k[:, 0].max()),
                float(k[:, 1].max()))  # fmt: skip


@dataclass(frozen=True)
class Segmentation:
    """Masks of the hand-object interaction, all (H, W) bool.

    Attributes:
        hand_mask: visible hand M_h.
        object_mask: visible held object M_o (after contour-guided filtering); may be empty
            when ``has_object`` is False.
        has_object: False when no held object was found (a legitimate outcome).
        candidates: the object regions a user may pick instead (``--object-choice K`` takes
            the K-th), the one the automatic path used first; empty when the segmenter
            offers none or the object was pointed at.
        meta: backend extras.
        confidence: mask name ("hand", "object") ->
            :class:`~easyhoi.perception.confidence.MaskConfidence`; empty when the backend
            does not rate its masks.
    """

    hand_mask: np.ndarray
    object_mask: np.ndarray
    has_object: bool
    candidates: tuple[np.ndarray, ...] = ()
    meta: dict = field(default_factory=dict)
    confidence: dict = field(default_factory=dict)


@runtime_checkable
class HandEstimator(Protocol):
    def detect(self, image: np.ndarray) -> list[HandDetection]:
        """All hands in an (H, W, 3) uint8 RGB image, most confident first."""
        ...


@runtime_checkable
class HOISegmenter(Protocol):
    def segment(self, image: np.ndarray, hand: HandDetection, prompts=None) -> Segmentation:
        """Visible hand and held-object masks for ``hand``; ``prompts`` (a
        :class:`~easyhoi.perception.prompts.Prompts`) point at the object when given."""
        ...


@runtime_checkable
class Inpainter(Protocol):
    def inpaint(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 image with the (H, W) bool ``mask`` region filled in."""
        ...


@runtime_checkable
class AmodalSegmenter(Protocol):
    def segment(
        self,
        image: np.ndarray,
        points: np.ndarray,
        box: tuple[float, float, float, float],
        visible_mask: np.ndarray,
    ) -> np.ndarray:
        """(H, W) bool amodal mask prompted by (N, 2) (u, v) points and a (u0, v0, u1, v1) box."""
        ...


@runtime_checkable
class ObjectReconstructor(Protocol):
    def reconstruct(self, image: np.ndarray, mask: np.ndarray):
        """A watertight ``trimesh.Trimesh`` of the masked object in its own canonical frame."""
        ...


# ----------------------------------------------------------------------------------------------
# registry
# ----------------------------------------------------------------------------------------------

_REGISTRY: dict[str, dict[str, Callable[..., Any]]] = {r: {} for r in ROLES}


def register(role: str, name: str):
    """Class decorator registering a backend factory under ``role`` / ``name``."""
    if role not in ROLES:
        raise InvalidInputError(f"unknown perception role {role!r}; roles are {ROLES}")

    def deco(factory):
        _REGISTRY[role][name] = factory
        return factory

    return deco


def available(role: str) -> list[str]:
    """Names registered for ``role`` (registration happens when backend modules import)."""
    _load_builtin_backends()
    if role not in ROLES:
        raise InvalidInputError(f"unknown perception role {role!r}; roles are {ROLES}")
    return sorted(_REGISTRY[role])


def factory(role: str, name: str) -> Callable[..., Any]:
    """The registered factory (usually the class) of backend ``name`` for ``role``."""
    names = available(role)
    if name not in _REGISTRY[role]:
        raise InvalidInputError(f"unknown {role} backend {name!r}; available: {', '.join(names)}")
    return _REGISTRY[role][name]


def create(role: str, name: str, **kwargs):
    """Instantiate the backend ``name`` for ``role``."""
    return factory(role, name)(**kwargs)


#: Backend modules imported on first registry use (each imports its heavy dependency lazily).
_BUILTIN_MODULES: list[str] = [
    "easyhoi.perception.mediapipe_hand",
    "easyhoi.perception.masks",
    "easyhoi.perception.inpaint",
    "easyhoi.perception.amodal",
    "easyhoi.perception.objects",
    "easyhoi.perception.adapters.sam",
    "easyhoi.perception.adapters.grounded_sam",
    "easyhoi.perception.adapters.depth",
    "easyhoi.perception.adapters.diffusion",
    "easyhoi.perception.adapters.shap_e",
]


def _load_builtin_backends() -> None:
    import importlib

    for mod in _BUILTIN_MODULES:
        importlib.import_module(mod)
