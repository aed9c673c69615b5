"""Save and load :class:`~easyhoi.hoi.HOIInput` and :class:`~easyhoi.hoi.HOIResult` folders.

Input folder::

    image.png  hand_mask.png  object_mask.png  amodal_mask.png
    [inpainted.png]  [complete_hand_mask.png]
    object.ply        binary PLY, float64 vertices (+ vertex colours when the mesh has them)
    input.json        schema "easyhoi.hoi_input", version, hand params, hand camera, meta

Result folder::

    hand.ply  object.ply
    result.json       schema "easyhoi.hoi_result", version, params, camera, stages, ...

Masks are 8-bit greyscale PNGs (0 / 255). Every file is written atomically
(:mod:`easyhoi.io.atomic`) and the JSON file last, so a folder with a JSON file is complete.
A missing or corrupt file raises :class:`~easyhoi.errors.InvalidInputError` naming it. The
object mesh may also be given as ``object.obj`` by hand (read when ``object.ply`` is absent).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import (
    HOIInput,
    HOIResult,
    StageResult,
    _camera_dict,
    _camera_from,
    _params_dict,
    _params_from,
)
from easyhoi.io.atomic import atomic_write_bytes, atomic_write_text
from easyhoi.io.export import EXPORT_SCHEMA, EXPORT_VERSION
from easyhoi.io.ply import mesh_from_ply_bytes, mesh_to_ply_bytes

__all__ = [
    "INPUT_SCHEMA",
    "RESULT_SCHEMA",
    "SCHEMA_VERSION",
    "load_hoi_input",
    "load_hoi_result",
    "mesh_from_ply_bytes",
    "mesh_to_ply_bytes",
    "save_hoi_input",
    "save_hoi_result",
]

INPUT_SCHEMA = "easyhoi.hoi_input"
RESULT_SCHEMA = "easyhoi.hoi_result"
SCHEMA_VERSION = 1

_MASKS = {
    "hand_mask": "hand_mask.png",
    "object_mask": "object_mask.png",
    "amodal_mask": "amodal_mask.png",
    "complete_hand_mask": "complete_hand_mask.png",
}


# ----------------------------------------------------------------------------------------------
# encoders / decoders
# ----------------------------------------------------------------------------------------------


def _png_bytes(array: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def _read_png(path: Path, mode: str) -> np.ndarray:
    from PIL import Image

    _require(path)
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode != mode:
                raise InvalidInputError(f"{path.name} has image mode {im.mode}, expected {mode}")
            return np.array(im)
    except InvalidInputError:
        raise
    except Exception as exc:  # noqa: BLE001 - PIL raises many types for corrupt files
        raise InvalidInputError(f"{path.name} is not a readable PNG image: {exc}") from None


def _require(path: Path) -> None:
    if not path.is_file():
        raise InvalidInputError(f"{path.name} is missing from {path.parent}")


def _read_mesh(folder: Path, stem: str, allow_obj: bool):
    ply = folder / f"{stem}.ply"
    obj = folder / f"{stem}.obj"
    if not ply.is_file() and allow_obj and obj.is_file():
        return mesh_from_ply_bytes(obj.read_bytes(), obj.name, file_type="obj")
    _require(ply)
    return mesh_from_ply_bytes(ply.read_bytes(), ply.name)


def _read_json(path: Path, schema: str) -> dict:
    _require(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"{path.name} is not valid JSON: {exc}") from None
    if not isinstance(d, dict) or d.get("schema") != schema:
        raise InvalidInputError(f"{path.name} is not an {schema} file (schema field missing)")
    version = d.get("version")
    if not isinstance(version, int) or version > SCHEMA_VERSION:
        raise InvalidInputError(
            f"{path.name} has schema version {version!r}; this easyhoi reads up to {SCHEMA_VERSION}"
        )
    return d


def _field(d: dict, key: str, filename: str) -> Any:
    if key not in d:
        raise InvalidInputError(f"{filename} lacks the field {key!r}")
    return d[key]


def _prepare(folder: str | Path) -> Path:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _dumps(d: dict) -> str:
    return json.dumps(d, indent=1, allow_nan=False)


# ----------------------------------------------------------------------------------------------
# HOIInput
# ----------------------------------------------------------------------------------------------


def save_hoi_input(inp: HOIInput, folder: str | Path) -> Path:
    """Write ``inp`` into ``folder`` (created if needed); returns the path of ``input.json``."""
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"save_hoi_input expects an HOIInput, got {type(inp).__name__}")
    folder = _prepare(folder)
    files = {"image": "image.png", "object_mesh": "object.ply"}
    atomic_write_bytes(folder / "image.png", _png_bytes(inp.image))
    for key, name in _MASKS.items():
        mask = getattr(inp, key)
        if mask is not None:
            atomic_write_bytes(folder / name, _png_bytes(mask.astype(np.uint8) * 255))
            files[key] = name
    if inp.inpainted_image is not None:
        atomic_write_bytes(folder / "inpainted.png", _png_bytes(inp.inpainted_image))
        files["inpainted_image"] = "inpainted.png"
    atomic_write_bytes(folder / "object.ply", mesh_to_ply_bytes(inp.object_mesh))
    doc = {
        "schema": INPUT_SCHEMA,
        "version": SCHEMA_VERSION,
        "files": files,
        "hand_model": inp.hand_model,
        "hand_params": _params_dict(inp.hand_params),
        "hand_camera": _camera_dict(inp.hand_camera),
        "meta": inp.meta,
    }
    return atomic_write_text(folder / "input.json", _dumps(doc))


def load_hoi_input(folder: str | Path) -> HOIInput:
    """Read a folder written by :func:`save_hoi_input` (or by hand, same layout)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"input folder {folder} does not exist")
    d = _read_json(folder / "input.json", INPUT_SCHEMA)
    files = _field(d, "files", "input.json")
    if not isinstance(files, dict):
        raise InvalidInputError("input.json: 'files' must be a mapping")

    def png(key: str, default: str | None, mode: str) -> np.ndarray | None:
        name = files.get(key, default)
        return None if name is None else _read_png(folder / name, mode)

    try:
        params = _params_from(_field(d, "hand_params", "input.json"))
        camera = _camera_from(_field(d, "hand_camera", "input.json"))
    except InvalidInputError as exc:
        raise InvalidInputError(f"input.json: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"input.json has malformed hand params or camera: {exc}") from None
    return HOIInput(
        image=png("image", "image.png", "RGB"),
        hand_mask=png("hand_mask", "hand_mask.png", "L"),
        object_mask=png("object_mask", "object_mask.png", "L"),
        amodal_mask=png("amodal_mask", "amodal_mask.png", "L"),
        object_mesh=_read_mesh(folder, "object", allow_obj=True),
        hand_params=params,
        hand_camera=camera,
        hand_model=d.get("hand_model", "open"),
        inpainted_image=png("inpainted_image", None, "RGB"),
        complete_hand_mask=png("complete_hand_mask", None, "L"),
        meta=d.get("meta", {}),
    )


# ----------------------------------------------------------------------------------------------
# HOIResult
# ----------------------------------------------------------------------------------------------


def save_hoi_result(result: HOIResult, folder: str | Path) -> Path:
    """Write ``result`` into ``folder``; returns the path of ``result.json``."""
    if not isinstance(result, HOIResult):
        raise InvalidInputError(
            f"save_hoi_result expects an HOIResult, got {type(result).__name__}"
        )
    folder = _prepare(folder)
    atomic_write_bytes(folder / "hand.ply", mesh_to_ply_bytes(result.hand_mesh()))
    atomic_write_bytes(folder / "object.ply", mesh_to_ply_bytes(result.object_mesh))
    doc = {
        "schema": RESULT_SCHEMA,
        "version": SCHEMA_VERSION,
        "files": {"hand_mesh": "hand.ply", "object_mesh": "object.ply"},
        "hand_model": result.hand_model,
        "hand_params": _params_dict(result.hand_params),
        "camera": _camera_dict(result.camera),
        "metric_scale": result.metric_scale,
        "stages": [s.to_dict() for s in result.stages],
        "timings": result.timings,
        "seed": result.seed,
        "config": result.config,
        "plausibility": result.plausibility,
        "hand_change": result.hand_change,
        "meta": result.meta,
    }
    try:
        text = _dumps(doc)
    except ValueError as exc:  # NaN / inf in a loss history or report
        raise InvalidInputError(f"result contains non-finite numbers: {exc}") from None
    return atomic_write_text(folder / "result.json", text)


def load_hoi_result(folder: str | Path) -> HOIResult:
    """Read a folder written by :func:`save_hoi_result` or a result folder of ``easyhoi
    reconstruct`` (:func:`easyhoi.result_folder.write_result_folder`: ``result.json`` in the
    export schema with ``hand.ply`` / ``object.ply`` in metres).

    From a result folder the meshes are brought back to object units (divided by
    ``metric_scale``, so equal to the original up to float rounding) and each stage keeps its
    summary (name, iterations, seconds, stop reason, final losses) but no snapshot.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"result folder {folder} does not exist")

    if _schema_of(folder / "result.json") == EXPORT_SCHEMA:
        return _load_exported_result(folder)
    d = _read_json(folder / "result.json", RESULT_SCHEMA)
    hand = _read_mesh(folder, "hand", allow_obj=False)
    with _malformed():
        stages = tuple(StageResult.from_dict(s) for s in _field(d, "stages", "result.json"))
        return _result_from(
            d,
            hand_params=_params_from(_field(d, "hand_params", "result.json")),
            camera=_camera_from(_field(d, "camera", "result.json")),
            hand=hand,
            object_mesh=_read_mesh(folder, "object", allow_obj=False),
            metric_scale=_field(d, "metric_scale", "result.json"),
            stages=stages,
        )


@contextlib.contextmanager
def _malformed():
    """Turn any error while interpreting ``result.json`` into a named InvalidInputError."""
    try:
        yield
    except InvalidInputError as exc:
        if str(exc).startswith(("result.json", "hand.ply", "object.ply")):
            raise
        raise InvalidInputError(f"result.json: {exc}") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f"result.json has malformed content: {exc}") from None


def _result_from(d: dict, hand, **fields) -> HOIResult:
    """An HOIResult from the parsed fields plus the optional entries shared by both schemas."""
    return HOIResult(
        hand_vertices=np.asarray(hand.vertices, dtype=np.float64),
        hand_faces=np.asarray(hand.faces),
        hand_model=d.get("hand_model", "open"),
        timings=d.get("timings", {}),
        seed=d.get("seed", 0),
        config=d.get("config", {}),
        plausibility=d.get("plausibility", {}),
        meta=d.get("meta", {}),
        hand_change=d.get("hand_change", {}),
        **fields,
    )


def _schema_of(path: Path) -> str | None:
    """The ``schema`` field of a JSON file, or None when unreadable (reported later)."""
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return d.get("schema") if isinstance(d, dict) else None


def _load_exported_result(folder: Path) -> HOIResult:
    """An :class:`HOIResult` from a result folder (export schema, meshes in metres)."""
    import torch

    from easyhoi.structures import HandParams

    d = json.loads((folder / "result.json").read_text(encoding="utf-8"))
    version = d.get("version")
    if not isinstance(version, int) or version > EXPORT_VERSION:
        raise InvalidInputError(
            f"result.json has export version {version!r}; this easyhoi reads up to {EXPORT_VERSION}"
        )
    hand = _read_mesh(folder, "hand", allow_obj=False)
    obj = _read_mesh(folder, "object", allow_obj=False)
    with _malformed():
        scale = float(_field(d, "metric_scale", "result.json"))
        if not np.isfinite(scale) or scale <= 0:
            raise InvalidInputError(f"result.json: metric_scale must be positive, got {scale}")
        obj.apply_scale(1.0 / scale)
        hand.apply_scale(1.0 / scale)
        stages = tuple(
            StageResult(
                name=s["name"],
                iterations=int(s["iterations"]),
                seconds=float(s["seconds"]),
                stop_reason=s.get("stop_reason", ""),
                losses=[s["final_losses"]] if s.get("final_losses") else [],
            )  # fmt: skip
            for s in _field(d, "stages", "result.json")
        )
        return _result_from(
            d,
            hand_params=HandParams.from_dict(_field(d, "hand", "result.json"), torch.float64),
            camera=_camera_from(_field(d, "camera_object_units", "result.json")),
            hand=hand,
            object_mesh=obj,
            metric_scale=scale,
            stages=stages,
        )
