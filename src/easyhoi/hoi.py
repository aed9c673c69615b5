"""The optimizer's input bundle (:class:`HOIInput`) and its output (:class:`HOIResult`).

Everything perception produces enters the optimizer through :class:`HOIInput`, whether computed
in-process, read from files written by other tools, or given by the user. The optimizer returns
a :class:`HOIResult` with one :class:`StageResult` snapshot per stage that ran.

Frames and units (docs/method.md section 2.2): the global frame is the OBJECT's canonical frame, in
the object's own arbitrary unit. ``metric_scale`` (metres per object unit) is recovered from the
hand's known size; the *metric object frame* is the object frame scaled by ``metric_scale``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.structures import Camera, HandParams

__all__ = ["HAND_MODELS", "HOIInput", "HOIResult", "StageResult", "as_bool_mask", "check_mesh"]

HAND_MODELS = ("open", "mano")


def as_bool_mask(mask: Any, name: str) -> np.ndarray:
    """(H, W) bool copy of a mask given as bool, or numbers in {0, 1} or {0, 255}.

    Raises:
        InvalidInputError: Not 2D, or values other than 0/1 (or 0/255 for uint8 images).
    """
    try:
        m = np.asarray(mask)
    except Exception as exc:  # noqa: BLE001 - anything that is not array-like
        raise InvalidInputError(f"{name} is not array-like: {exc}") from None
    if m.ndim != 2:
        raise InvalidInputError(f"{name} must be an (H, W) mask, got shape {m.shape}")
    if m.dtype == bool:
        return m.copy()
    if not (np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)):
        raise InvalidInputError(f"{name} has dtype {m.dtype}; expected bool or numbers")
    values = np.unique(m)
    if np.all(np.isin(values, (0, 1))):
        return m != 0
    if m.dtype == np.uint8 and np.all(np.isin(values, (0, 255))):
        return m != 0
    shown = ", ".join(str(v) for v in values[:6])
    raise InvalidInputError(
        f"{name} is not a binary mask: values {shown}{'...' if values.size > 6 else ''} "
        "(expected bool, 0/1, or 0/255 uint8)"
    )


def _as_image(image: Any, name: str) -> np.ndarray:
    im = np.asarray(image)
    if im.dtype != np.uint8:
        raise InvalidInputError(f"{name} must be uint8, got {im.dtype}")
    if im.ndim != 3 or im.shape[2] != 3:
        raise InvalidInputError(f"{name} must be an (H, W, 3) RGB image, got shape {im.shape}")
    if im.shape[0] == 0 or im.shape[1] == 0:
        raise InvalidInputError(f"{name} is empty ({im.shape[0]}x{im.shape[1]})")
    return im.copy()


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def check_mesh(mesh: Any, name: str = "object mesh") -> None:
    """Raise unless ``mesh`` is a ``trimesh.Trimesh`` with finite vertices and valid faces."""
    from easyhoi.geometry.mesh import validate_mesh

    validate_mesh(mesh, name)


def _check_json(meta: Any, name: str) -> dict:
    if not isinstance(meta, dict):
        raise InvalidInputError(f"{name} must be a dict, got {type(meta).__name__}")
    try:
        json.dumps(meta)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be JSON-serialisable: {exc}") from None
    return dict(meta)


@dataclass(frozen=True)
class HOIInput:
    """Everything the optimizer needs, validated on construction.

    Attributes:
        image ((H, W, 3) uint8): The RGB photo.
        hand_mask ((H, W) bool): Visible hand mask M_h.
        object_mask ((H, W) bool): Visible held-object mask M_o.
        amodal_mask ((H, W) bool): Complete (amodal) object mask M^_o.
        object_mesh (trimesh.Trimesh): Object mesh in its own canonical frame, arbitrary scale (not
            modified).
        hand_params (HandParams): Initial hand (batch 1) expressed in ``hand_camera``'s frame
            (metres).
        hand_camera (Camera): The full-image camera the hand estimate lives in (same size as the
            image).
        hand_model ({"open", "mano"}): Which hand model ``hand_params`` belong to.
        inpainted_image ((H, W, 3) uint8 or None): The photo with the hand removed, if available.
        complete_hand_mask ((H, W) bool or None): M^_h, the complete hand silhouette rendered from
            the hand estimate, if available.
        meta (dict): JSON-serialisable provenance (file names, backends, ...).

    Arrays are stored as read-only copies; masks are converted to bool (0/1 or 0/255 allowed).
    """

    image: np.ndarray
    hand_mask: np.ndarray
    object_mask: np.ndarray
    amodal_mask: np.ndarray
    object_mesh: Any
    hand_params: HandParams
    hand_camera: Camera
    hand_model: str = "open"
    inpainted_image: np.ndarray | None = None
    complete_hand_mask: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        img = _as_image(self.image, "image")
        H, W = img.shape[:2]
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("image", _frozen(img))
        names = {
            "hand_mask": "hand mask",
            "object_mask": "object mask",
            "amodal_mask": "amodal object mask",
            "complete_hand_mask": "complete hand mask",
        }
        for key, label in names.items():
            value = getattr(self, key)
            if value is None and key == "complete_hand_mask":
                continue
            if value is None:
                raise InvalidInputError(f"{label} is required")
            m = as_bool_mask(value, label)
            if m.shape != (H, W):
                raise InvalidInputError(
                    f"{label} is {m.shape[0]}x{m.shape[1]} but the image is {H}x{W}"
                )
            if not m.any():
                raise InvalidInputError(f"{label} is empty (no pixel set)")
            set_(key, _frozen(m))
        if self.inpainted_image is not None:
            inp = _as_image(self.inpainted_image, "inpainted image")
            if inp.shape[:2] != (H, W):
                raise InvalidInputError(
                    f"inpainted image is {inp.shape[0]}x{inp.shape[1]} but the image is {H}x{W}"
                )
            set_("inpainted_image", _frozen(inp))
        check_mesh(self.object_mesh)
        if not isinstance(self.hand_params, HandParams):
            raise InvalidInputError(
                f"hand_params must be HandParams, got {type(self.hand_params).__name__}"
            )
        if self.hand_params.batch_size != 1:
            raise InvalidInputError(
                f"hand_params must hold one hand, got a batch of {self.hand_params.batch_size}"
            )
        if not isinstance(self.hand_camera, Camera):
            raise InvalidInputError(
                f"hand_camera must be a Camera, got {type(self.hand_camera).__name__}"
            )
        if (self.hand_camera.height, self.hand_camera.width) != (H, W):
            raise InvalidInputError(
                f"hand camera is {self.hand_camera.height}x{self.hand_camera.width} "
                f"but the image is {H}x{W}"
            )
        if self.hand_model not in HAND_MODELS:
            raise InvalidInputError(
                f"hand_model must be one of {HAND_MODELS}, got {self.hand_model!r}"
            )
        set_("meta", _check_json(self.meta, "meta"))

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) of the photo."""
        return self.image.shape[0], self.image.shape[1]


@dataclass(frozen=True)
class StageResult:
    """Snapshot at the end of one optimizer stage.

    Attributes:
        name (str): "initial", "camera", "contact" or "refine".
        hand_params (HandParams or None): Hand parameters after the stage (metric object frame),
            None if the stage has no hand.
        camera (Camera or None): Object camera after the stage (object frame, object units).
        losses (list of dict): History: one dict per recorded iteration, e.g. ``{"iter": 0, "total":
            0.8, "iou": 0.7}``.
        seconds (float): Wall time of the stage.
        iterations (int): Iterations run.
        metric_scale (float or None): Metres per object unit after the stage, if known.
        stop_reason (str): Why the stage ended ("stop_loss", "patience", "max_iters", "disabled",
            ...).
        extra (dict): JSON-serialisable stage-specific values (e.g. ICP residuals).
    """

    name: str
    hand_params: HandParams | None = None
    camera: Camera | None = None
    losses: list = field(default_factory=list)
    seconds: float = 0.0
    iterations: int = 0
    metric_scale: float | None = None
    stop_reason: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "losses", [dict(d) for d in self.losses])
        object.__setattr__(self, "extra", _check_json(self.extra, f"stage {self.name!r} extra"))

    def detach(self) -> StageResult:
        return replace(
            self,
            hand_params=None if self.hand_params is None else self.hand_params.detach(),
            camera=None if self.camera is None else self.camera.detach(),
        )

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        return {
            "name": self.name,
            "hand_params": None if self.hand_params is None else _params_dict(self.hand_params),
            "camera": None if self.camera is None else _camera_dict(self.camera),
            "losses": [{k: _plain(v) for k, v in d.items()} for d in self.losses],
            "seconds": float(self.seconds),
            "iterations": int(self.iterations),
            "metric_scale": None if self.metric_scale is None else float(self.metric_scale),
            "stop_reason": self.stop_reason,
            "extra": self.extra,
        }

    @classmethod
    def from_dict(cls, d: dict) -> StageResult:
        try:
            return cls(
                name=d["name"],
                hand_params=None if d["hand_params"] is None else _params_from(d["hand_params"]),
                camera=None if d["camera"] is None else _camera_from(d["camera"]),
                losses=d["losses"],
                seconds=d["seconds"],
                iterations=d["iterations"],
                metric_scale=d.get("metric_scale"),
                stop_reason=d.get("stop_reason", ""),
                extra=d.get("extra", {}),
            )
        except KeyError as exc:
            raise InvalidInputError(f"stage dictionary lacks the key {exc}") from None


@dataclass(frozen=True)
class HOIResult:
    """The reconstruction: hand and object in the object frame, the camera, and the history.

    Attributes:
        hand_params (HandParams): Final hand (batch 1) in the metric object frame:
            ``hand_model(hand_params).vertices / metric_scale`` are the hand vertices in object
            units.
        camera (Camera): Object camera (world = object frame, object units), fitted to the photo.
        hand_vertices ((V, 3) float64): Final hand vertices in object units.
        hand_faces ((F, 3) int64): Hand triangles (closed mesh).
        object_mesh (trimesh.Trimesh): The object, unchanged, in its own frame and units.
        metric_scale (float): Metres per object unit (from the hand's known size).
        hand_model: {"open", "mano"}
        stages (tuple of StageResult): One snapshot per stage, in order.
        timings (dict of str -> float): Seconds per named step.
        seed: int
        config (dict): The configuration used (:func:`easyhoi.config.to_dict`).
        plausibility (dict): JSON-serialisable report (penetration depth, contact, ...).
        meta (dict): JSON-serialisable provenance.
        hand_change (dict): How far the optimizer moved the hand from the estimator's, per keypoint
            in cm and px (:func:`easyhoi.optim.hand_change.hand_change`); empty when not computed.
    """

    hand_params: HandParams
    camera: Camera
    hand_vertices: np.ndarray
    hand_faces: np.ndarray
    object_mesh: Any
    metric_scale: float
    hand_model: str = "open"
    stages: tuple = ()
    timings: dict = field(default_factory=dict)
    seed: int = 0
    config: dict = field(default_factory=dict)
    plausibility: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    hand_change: dict = field(default_factory=dict)

    def __post_init__(self):
        v = np.asarray(self.hand_vertices, dtype=np.float64)
        f = np.asarray(self.hand_faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
            raise InvalidInputError(f"hand_vertices must be (V, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise InvalidInputError("hand_vertices contain NaN or infinite values")
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise InvalidInputError(f"hand_faces must be (F, 3) integers, got {f.shape} {f.dtype}")
        if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
            raise InvalidInputError(
                f"hand_faces index vertices in [{f.min()}, {f.max()}] but there are {v.shape[0]}"
            )
        object.__setattr__(self, "hand_vertices", _frozen(v.copy()))
        object.__setattr__(self, "hand_faces", _frozen(f.astype(np.int64)))
        check_mesh(self.object_mesh)
        if not (np.isfinite(self.metric_scale) and self.metric_scale > 0):
            raise InvalidInputError(f"metric_scale must be > 0, got {self.metric_scale}")
        object.__setattr__(self, "metric_scale", float(self.metric_scale))
        if self.hand_model not in HAND_MODELS:
            raise InvalidInputError(
                f"hand_model must be one of {HAND_MODELS}, got {self.hand_model!r}"
            )
        object.__setattr__(self, "stages", tuple(self.stages))
        for k in ("timings", "config", "plausibility", "meta"):
            object.__setattr__(self, k, _check_json(getattr(self, k), k))

    def detach(self) -> HOIResult:
        """A copy whose tensors (params, camera, stage snapshots) carry no autograd graph."""
        return replace(
            self,
            hand_params=self.hand_params.detach(),
            camera=self.camera.detach(),
            stages=tuple(s.detach() for s in self.stages),
        )

    def stage(self, name: str) -> StageResult:
        """The snapshot of the stage called ``name``."""
        for s in self.stages:
            if s.name == name:
                return s
        have = ", ".join(s.name for s in self.stages) or "none"
        raise InvalidInputError(f"no stage named {name!r} in this result (stages: {have})")

    def hand_mesh(self):
        """The final hand as a ``trimesh.Trimesh`` in object units."""
        import trimesh

        return trimesh.Trimesh(self.hand_vertices.copy(), self.hand_faces.copy(), process=False)

    def object_mesh_metric(self):
        """A copy of the object mesh scaled to metres (the metric object frame)."""
        m = self.object_mesh.copy()
        m.apply_scale(self.metric_scale)
        return m


# ----------------------------------------------------------------------------------------------
# JSON helpers shared with easyhoi.io.hoi_io (dtype-preserving)
# ----------------------------------------------------------------------------------------------


def _plain(v):
    if isinstance(v, np.generic):
        return v.item()
    if hasattr(v, "item") and getattr(v, "ndim", None) == 0:
        return v.item()
    return v


def _params_dict(p: HandParams) -> dict:
    d = p.to_dict()
    d["dtype"] = str(p.global_orient.dtype).replace("torch.", "")
    return d


def _dtype(name: Any):
    import torch

    if name not in ("float32", "float64"):
        raise InvalidInputError(f"unsupported dtype {name!r} (expected float32 or float64)")
    return getattr(torch, name)


def _params_from(d: dict) -> HandParams:
    if not isinstance(d, dict):
        raise InvalidInputError(f"hand parameters must be a mapping, got {type(d).__name__}")
    return HandParams.from_dict(d, dtype=_dtype(d.get("dtype", "float32")))


def _camera_dict(c: Camera) -> dict:
    d = c.to_dict()
    d["dtype"] = str(c.K.dtype).replace("torch.", "")
    return d


def _camera_from(d: dict) -> Camera:
    import torch

    if not isinstance(d, dict):
        raise InvalidInputError(f"camera must be a mapping, got {type(d).__name__}")
    dt = _dtype(d.get("dtype", "float32"))
    try:
        return Camera(
            torch.tensor(d["K"], dtype=dt),
            torch.tensor(d["R"], dtype=dt),
            torch.tensor(d["t"], dtype=dt),
            d["width"],
            d["height"],
        )
    except KeyError as exc:
        raise InvalidInputError(f"camera dictionary lacks the key {exc}") from None
