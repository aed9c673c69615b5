"""The web demo's request logic, without gradio: validate an upload, reconstruct, collect.

:func:`handle_request` is plain Python, so it can be tested and reused without the ``[demo]``
extra; :mod:`easyhoi.app` wraps it in a gradio page.

Every request works in its own temporary folder (the upload is copied in, the reconstruction
writes its result folder there, a zip of that folder is made for download); only the newest
``keep_runs`` request folders are kept. Uploads are limited in size and must decode as an image
(checked by content with :func:`easyhoi.io.image.load_image`, not by the file extension).
Failures reach the page as one readable sentence; tracebacks go to the server log only.

The reconstruction is injectable: ``reconstruct_fn(image_path, folder, config, *, seed,
progress, say)`` with the signature of :func:`easyhoi.pipeline.reconstruct_photo` (the
default): it writes the result folder ``folder`` and returns an object whose ``files`` lists
what it wrote; the page needs
``overlay.png``, ``scene.glb`` and ``result.json`` among them (see
:mod:`easyhoi.result_folder`). When the user clicked on the photo, it also gets
``prompts=`` (:class:`~easyhoi.perception.prompts.Prompts`, pixels of the upload).
"""

from __future__ import annotations

import json
import logging
import math
import re
import shutil
import tempfile
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from easyhoi.errors import (
    NO_OBJECT_HINT,
    BackendError,
    EasyHOIError,
    InvalidInputError,
    MissingDependencyError,
    NoHandError,
    NoObjectError,
    OptimizationError,
)

logger = logging.getLogger(__name__)

__all__ = [
    "DemoResult",
    "check_upload",
    "example_photo",
    "handle_request",
    "metrics_markdown",
    "synthetic_examples",
]

#: Default upload limit in megabytes.
MAX_UPLOAD_MB = 20
#: Request folders kept on disk (older ones are deleted when a new request starts).
KEEP_RUNS = 16
#: Largest accepted seed (numpy's seed range).
MAX_SEED = 2**32 - 1

#: ``(description, fraction in [0, 1] or None) -> None``: progress as shown on the page.
Progress = Callable[[str | None, float | None], None]

_TITLES = {
    NoHandError: "No hand was found in the photo",
    NoObjectError: "No held object was found in the photo",
    OptimizationError: "The reconstruction did not converge",
    BackendError: "A perception step failed",
    MissingDependencyError: "A dependency is missing on the server",
    InvalidInputError: "The photo cannot be used",
}


@dataclass(frozen=True)
class DemoResult:
    """What one request produced.

    Attributes:
        ok: True when the reconstruction succeeded.
        error: one readable sentence when ``ok`` is False (never a traceback), else "".
        overlay: overlay.png of the result folder.
        glb: scene.glb (hand, object and camera, metres).
        view_glb: a copy of scene.glb in the photo camera's frame for the 3D viewer, or None
            when it could not be made (the viewer then shows ``glb``).
        camera_position: ``(alpha, beta, radius)`` of the viewer's first view (the photo's
            viewpoint), or None; see :mod:`easyhoi.viz.viewer`.
        metrics: plausibility metrics and run facts (JSON-ready).
        metrics_text: ``metrics`` as a Markdown table.
        downloads: files offered for download: the zipped result folder first, then scene.glb
            and report.html when present.
        folder: the result folder.
        seconds: wall time of the request.
        warnings: sentences about perception the user must read: the hand used is not the
            first detected one, a mask or the hand's keypoints have low confidence (with what
            fixes it).
    """

    ok: bool
    error: str = ""
    overlay: Path | None = None
    glb: Path | None = None
    view_glb: Path | None = None
    camera_position: tuple[float, float, float] | None = None
    metrics: dict = field(default_factory=dict)
    metrics_text: str = ""
    downloads: tuple[Path, ...] = ()
    folder: Path | None = None
    seconds: float = 0.0
    warnings: tuple[str, ...] = ()


# ----------------------------------------------------------------------------------------------
# request handling (no gradio)
# ----------------------------------------------------------------------------------------------


def _default_reconstruct(*args, **kwargs):
    from easyhoi.pipeline import reconstruct_photo

    return reconstruct_photo(*args, **kwargs)


def _safe_stem(name: str) -> str:
    """A file stem safe for folder and zip names (letters, digits, ``-`` and ``_``)."""
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(str(name)).stem).strip("_")[:60]
    return stem or "photo"


def _fail(message: str, t0: float) -> DemoResult:
    return DemoResult(ok=False, error=message, seconds=time.perf_counter() - t0)


def _readable(exc: BaseException, replace: dict[str, str]) -> str:
    """One sentence for the page: a title for the error class plus its message, paths hidden."""
    msg = str(exc).strip() or type(exc).__name__
    for old, new in sorted(replace.items(), key=lambda kv: -len(kv[0])):
        if old:
            msg = msg.replace(old, new)
    msg = msg.splitlines()[0] if msg else msg
    if isinstance(exc, NoObjectError) and msg.endswith(NO_OBJECT_HINT):
        msg = msg[: -len(NO_OBJECT_HINT)] + ": click inside the object in the photo and run again"
    if isinstance(exc, EasyHOIError):
        title = next((t for cls, t in _TITLES.items() if isinstance(exc, cls)), "Error")
        return f"{title}: {msg}"
    return (
        f"Internal error ({type(exc).__name__}: {msg}). This is a bug; the server log has the "
        "details."
    )


def _prune(work_root: Path, keep: int) -> None:
    runs = sorted(
        (p for p in work_root.glob("run-*") if p.is_dir()), key=lambda p: p.stat().st_mtime
    )
    for old in runs[: max(0, len(runs) - keep)]:
        shutil.rmtree(old, ignore_errors=True)


def _zip_folder(folder: Path, dest: Path) -> Path:
    tmp = dest.with_name(dest.name + ".part")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                zf.write(f, arcname=f"{folder.name}/{f.relative_to(folder).as_posix()}")
    tmp.replace(dest)
    return dest


def _label(key: str) -> tuple[str, str]:
    """``penetration_depth_cm`` -> ("penetration depth", "cm")."""
    units = {"cm3": "cm³", "cm": "cm", "m": "m", "mm": "mm", "s": "s", "deg": "°"}
    parts = key.split("_")
    unit = ""
    if len(parts) > 1 and parts[-1] in units:
        unit = units[parts.pop()]
    text = " ".join(parts).replace("iou", "IoU")
    return text, unit


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None:
        return "n/a"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.3g}"
    return str(v)


def metrics_markdown(metrics: dict) -> str:
    """A Markdown table of :attr:`DemoResult.metrics` (plausibility rows, then run facts)."""
    rows = ["| metric | value |", "|---|---|"]
    from easyhoi.optim.run import SELF_CONSISTENCY_KEYS

    for key, value in metrics.get("plausibility", {}).items():
        text, unit = _label(key)
        if key in SELF_CONSISTENCY_KEYS:
            text += " (fit to its own mask, not accuracy)"
        shown = _fmt(value)
        rows.append(f"| {text} | {shown}{' ' + unit if unit and shown != 'n/a' else ''} |")
    shape = metrics.get("object_shape")
    if shape:
        rows.append(f"| object shape | {_shape_line(shape)} |")
    for key in ("preset", "seed", "seconds"):
        if key in metrics:
            value = metrics[key]
            shown = f"{value:.1f} s" if key == "seconds" else _fmt(value)
            rows.append(f"| {'run time' if key == 'seconds' else key} | {shown} |")
    return "\n".join(rows)


def _shape_line(shape: dict) -> str:
    """The object step's choice in a few words: the family and where its thickness along the
    view came from (``meta.object_shape`` of a result; docs/object_shape.md)."""
    source = {"gap": "from the grip", "pinch": "from a pinch"}.get(shape.get("depth_cue_from"))
    depth = source or "not measured (the family's assumption, a guess)"
    return f"{shape.get('shape', 'n/a')}; thickness along the view {depth}"


def _read_metrics(result_json: Path | None, rec) -> dict:
    plaus: dict = {}
    shape = None
    if result_json is not None:
        try:
            data = json.loads(result_json.read_text(encoding="utf-8"))
            plaus = dict(data.get("plausibility") or {})
            shape = (data.get("meta") or {}).get("object_shape")
        except (OSError, ValueError) as exc:
            logger.warning("cannot read %s: %s", result_json, exc)
    if not plaus:
        plaus = dict(getattr(getattr(rec, "result", None), "plausibility", None) or {})
    out = {"plausibility": plaus}
    if isinstance(shape, dict) and shape.get("shape"):
        out["object_shape"] = shape
    return out


def _perception_warnings(result_json: Path | None, prompted: bool) -> tuple[str, ...]:
    from easyhoi.perception.feedback import contact_line, hand_choice_note, low_confidence_lines

    try:
        doc = json.loads(result_json.read_text(encoding="utf-8")) if result_json else {}
    except (OSError, ValueError):
        return ()
    perception = (doc.get("meta") or {}).get("perception") or {}
    note = hand_choice_note(perception)
    lines = [note[0].upper() + note[1:] + "."] if note else []
    warnings = low_confidence_lines(perception, "demo", prompted)
    apart = contact_line(doc.get("plausibility") or {}, "demo", prompted)
    warnings += [apart] if apart else []
    return tuple(lines + [w[0].upper() + w[1:] + "." for w in warnings])


def _photo_view(files: dict, dest: Path):
    """(view.glb path, (alpha, beta, radius)) seen from the photo's camera, or (None, None)."""
    from easyhoi.io.atomic import atomic_write_bytes
    from easyhoi.viz.viewer import photo_view_glb

    try:
        cam = json.loads(files["result.json"].read_text(encoding="utf-8"))["camera"]
        data, view = photo_view_glb(files["scene.glb"], cam["R"], cam["t"], cam.get("K"),
                                    cam.get("height"))  # fmt: skip
        atomic_write_bytes(dest, data)
    except (KeyError, TypeError, ValueError, OSError, EasyHOIError) as exc:
        logger.warning("3D view from the photo's camera unavailable: %s", exc)
        return None, None
    return dest, view


def handle_request(
    image_path: str | Path | None,
    preset: str = "fast",
    seed: int | float | str | None = 0,
    *,
    work_root: str | Path,
    reconstruct_fn: Callable | None = None,
    max_upload_mb: float = MAX_UPLOAD_MB,
    keep_runs: int = KEEP_RUNS,
    progress: Progress | None = None,
    display_name: str | None = None,
    prompts=None,
    object_shape: str = "auto",
) -> DemoResult:
    """Run one demo request: validate the upload, reconstruct, collect the outputs.

    Args:
        image_path (path or None): The uploaded file (None: nothing uploaded).
        preset (str): Configuration preset (:func:`easyhoi.config.get_preset`).
        seed (int): Random seed (0 <= seed < 2**32); same photo + preset + seed -> same result.
        work_root (path): Folder under which this request gets its own ``run-*`` folder.
        reconstruct_fn (callable): ``(image_path, folder, config, *, seed, progress, say) -> object
            with .files``; default :func:`easyhoi.pipeline.reconstruct_photo`.
        max_upload_mb (float): Uploads larger than this are refused before decoding.
        keep_runs (int): How many request folders to keep under ``work_root``.
        progress (callable): ``(description, fraction or None)``, fed from the pipeline's callbacks.
        display_name (str): Name of the upload as the user knows it (default: the file's name).
        prompts (Prompts or None): Points clicked on the photo (pixels of the upload); checked
            against its size.
        object_shape (str): The object's shape family ("auto": the best fit; see
            ``perception.object_shape``).

    Returns:
        DemoResult: ``ok`` False with a readable ``error`` for bad input or a failed reconstruction;
            this function does not raise for those.
    """
    from dataclasses import replace

    from easyhoi.config import PRESETS, get_preset
    from easyhoi.io.image import load_image
    from easyhoi.shape_families import OBJECT_SHAPES

    t0 = time.perf_counter()
    if image_path is None or str(image_path) == "":
        return _fail("Please upload a photo (JPEG, PNG, WebP...) first.", t0)
    src = Path(image_path)
    shown = display_name or src.name
    try:
        size = src.stat().st_size
    except OSError:
        return _fail(f"The upload '{shown}' could not be read; please upload it again.", t0)
    limit = float(max_upload_mb) * 1024 * 1024
    if size > limit:
        return _fail(
            f"The photo '{shown}' is {size / 2**20:.1f} MB; the limit is {max_upload_mb:g} MB. "
            "Please upload a smaller file.",
            t0,
        )
    if preset not in PRESETS:
        return _fail(f"Unknown preset '{preset}'; choose one of {', '.join(sorted(PRESETS))}.", t0)
    try:
        seed_f = float(seed if seed is not None else 0)
    except (TypeError, ValueError):
        return _fail(f"The seed must be a whole number, got '{seed}'.", t0)
    if not seed_f.is_integer() or not 0 <= seed_f <= MAX_SEED:
        return _fail(f"The seed must be a whole number from 0 to {MAX_SEED}, got '{seed}'.", t0)
    seed_i = int(seed_f)
    if object_shape not in ("auto", *OBJECT_SHAPES):
        return _fail(
            f"Unknown object shape '{object_shape}'; choose auto or one of "
            f"{', '.join(OBJECT_SHAPES)}.",
            t0,
        )
    config = get_preset(preset)
    if object_shape != "auto":
        config = replace(config, perception=replace(config.perception, object_shape=object_shape))

    try:
        image = load_image(src)
        if prompts is not None:
            prompts.check(*image.original_size)
    except InvalidInputError as exc:
        return _fail(_readable(exc, {str(src): f"'{shown}'"}), t0)

    work_root = Path(work_root)
    work_root.mkdir(parents=True, exist_ok=True)
    _prune(work_root, max(0, keep_runs - 1))
    run = Path(tempfile.mkdtemp(prefix="run-", dir=work_root))
    stem = _safe_stem(shown)
    suffix = {"JPEG": ".jpg", "PNG": ".png", "WEBP": ".webp"}.get(image.source_format, "")
    local = run / "input" / f"{stem}{suffix or src.suffix.lower()[:6]}"
    local.parent.mkdir()
    shutil.copyfile(src, local)
    out_dir = run / "result" / stem  # the result folder; the download zip is named after it

    def on_progress(stage: str, it: int, total: int, losses: dict) -> None:
        if progress is not None:
            frac = min(max(it / total, 0.0), 1.0) if total else None
            progress(f"optimizing: {stage}", frac)

    def on_say(name: str) -> None:
        if progress is not None:
            progress(name, None)

    fn = reconstruct_fn or _default_reconstruct
    hide = {str(run): "", str(src): f"'{shown}'", str(local): f"'{shown}'"}
    extra = {} if prompts is None else {"prompts": prompts}
    try:
        rec = fn(local, out_dir, config, seed=seed_i, progress=on_progress, say=on_say,
                 **extra)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - every failure becomes a message on the page
        if isinstance(exc, EasyHOIError):
            logger.info("request failed: %s: %s", type(exc).__name__, exc)
        else:
            logger.exception("reconstruction failed with an internal error")
        return _fail(_readable(exc, hide), t0)

    files = {Path(f).name: Path(f) for f in (getattr(rec, "files", None) or [])}
    missing = [n for n in ("overlay.png", "scene.glb") if n not in files or not files[n].is_file()]
    if missing:
        logger.error("reconstruction returned %s, missing %s", sorted(files), missing)
        return _fail(
            f"Internal error: the reconstruction wrote no {' and no '.join(missing)}. "
            "This is a bug; the server log has the details.",
            t0,
        )
    folder = files["overlay.png"].parent
    if progress is not None:
        progress("packing the results", None)
    archive = _zip_folder(folder, run / f"{stem}-easyhoi.zip")
    downloads = [archive, files["scene.glb"]]
    if "report.html" in files:
        downloads.append(files["report.html"])
    metrics = _read_metrics(files.get("result.json"), rec)
    view_glb, camera_position = _photo_view(files, run / "view.glb")
    prompted = prompts is not None and prompts.has_object_prompt
    warnings = _perception_warnings(files.get("result.json"), prompted)
    seconds = time.perf_counter() - t0
    metrics.update(preset=preset, seed=seed_i, seconds=round(seconds, 2))
    return DemoResult(
        ok=True,
        overlay=files["overlay.png"],
        glb=files["scene.glb"],
        view_glb=view_glb,
        camera_position=camera_position,
        metrics=metrics,
        metrics_text=metrics_markdown(metrics),
        downloads=tuple(downloads),
        folder=folder,
        seconds=seconds,
        warnings=warnings,
    )


def check_upload(image_path: str | Path | None, max_upload_mb: float = MAX_UPLOAD_MB):
    """Validate an upload for the preview: ``(rgb thumbnail or None, error message or "")``."""
    from easyhoi.io.image import load_image

    if not image_path:
        return None, ""
    src = Path(image_path)
    try:
        size = src.stat().st_size
    except OSError:
        return None, "The upload could not be read; please upload it again."
    if size > float(max_upload_mb) * 2**20:
        return None, (
            f"The photo '{src.name}' is {size / 2**20:.1f} MB; the limit is {max_upload_mb:g} MB."
        )
    try:
        return load_image(src, max_side=512).rgb, ""
    except InvalidInputError as exc:
        return None, _readable(exc, {str(src): f"'{src.name}'"})


# ----------------------------------------------------------------------------------------------
# example photos
# ----------------------------------------------------------------------------------------------


#: Seeds of the example scenes: photos whose hand and held object the automatic perception
#: finds, so that an example shows a whole reconstruction without any click.
EXAMPLE_SEEDS = (1, 2)


def synthetic_examples(folder: str | Path, seeds: Sequence[int] = EXAMPLE_SEEDS) -> list[Path]:
    """Example photos rendered by :func:`easyhoi.synth.make_scene`, saved as PNG in ``folder``.

    Uses the public ``make_scene(seed)`` and :func:`example_photo` of its result; a failure
    only removes that example (it is logged).
    """
    from PIL import Image

    from easyhoi.synth import make_scene

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for seed in seeds:
        try:
            path = folder / f"synthetic-{seed}.png"
            Image.fromarray(example_photo(make_scene(seed))).save(path)
            out.append(path)
        except Exception as exc:  # noqa: BLE001 - examples are optional
            logger.warning("synthetic example %d unavailable: %s", seed, exc)
    return out


def example_photo(scene) -> np.ndarray:
    """The (H, W, 3) uint8 photo of a synthetic scene (its ``image``)."""
    photo = np.asarray(scene.image)
    if photo.ndim != 3 or photo.shape[2] != 3:
        raise InvalidInputError(f"a scene photo must be (H, W, 3), got {photo.shape}")
    return photo.astype(np.uint8)
