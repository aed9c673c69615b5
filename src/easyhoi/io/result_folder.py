"""One folder of outputs per photo, written all-or-nothing.

``write_result_folder(result, inp, out_dir, "IMG_0001")`` produces ``out_dir/IMG_0001/`` with::

    scene.glb     hand, object and camera, metres (glTF)
    hand.ply      hand mesh, metres (metric object frame)
    object.ply    object mesh, metres (metric object frame)
    result.json   parameters, camera, metrics, timings, versions (see io.export.result_json)
    overlay.png   views.png   stages.png   masks.png   losses.png
    report.html   one self-contained page with all of the above

The folder is built in a hidden temporary sibling (``out_dir/.IMG_0001.tmp-*``) and renamed into
place only when every file is complete, so a killed run leaves no half folder under the final
name. An existing folder of that name is replaced only after the new one is complete: it is
first renamed aside, the new folder renamed in, then the old one deleted (if the second rename
fails the old folder is put back).
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from pathlib import Path

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIInput, HOIResult
from easyhoi.io.atomic import atomic_write_bytes
from easyhoi.io.export import export_glb, export_ply, write_result_json

__all__ = ["RESULT_FILES", "write_result_folder"]

#: Every file the folder holds, in writing order.
RESULT_FILES = (
    "scene.glb",
    "hand.ply",
    "object.ply",
    "result.json",
    "overlay.png",
    "views.png",
    "stages.png",
    "masks.png",
    "losses.png",
    "report.html",
)


def _folder_name(image_name: str) -> str:
    name = Path(str(image_name)).name
    stem = Path(name).stem if Path(name).suffix else name
    bad = not stem or stem in (".", "..") or stem.startswith(".") or "/" in str(image_name)
    bad = bad or "\\" in str(image_name) or "\0" in str(image_name)
    if bad:
        raise InvalidInputError(
            f"image_name must be a plain file name such as 'IMG_0001.jpg', got {image_name!r}"
        )
    return stem


def _write_all(result: HOIResult, inp: HOIInput, folder: Path, title: str) -> None:
    from easyhoi.viz.report import render_pictures, write_report

    export_glb(result, folder / "scene.glb")
    export_ply(result.hand_mesh().apply_scale(result.metric_scale), folder / "hand.ply")
    export_ply(result.object_mesh_metric(), folder / "object.ply")
    write_result_json(result, folder / "result.json")
    pictures = render_pictures(*picture_scale(result, inp))
    for name, data in pictures.items():
        atomic_write_bytes(folder / name, data)
    write_report(result, inp, folder, images=pictures, title=title)


#: Pictures are drawn at most this many pixels on the photo's longer side (drawing with the
#: CPU rasterizer costs time in proportion to the pixel count; the photo itself keeps its size).
PICTURE_MAX_SIDE = 1024


def picture_scale(
    result: HOIResult, inp: HOIInput, max_side: int = PICTURE_MAX_SIDE
) -> tuple[HOIResult, HOIInput]:
    """``result`` and ``inp`` at picture size: photo, masks and every camera downscaled.

    Returns the arguments unchanged when the photo's longer side is at most ``max_side``.
    """
    from dataclasses import replace

    import cv2

    H, W = inp.image.shape[:2]
    if max(H, W) <= max_side:
        return result, inp
    s = max_side / max(H, W)
    w, h = max(1, round(W * s)), max(1, round(H * s))

    def img(a):
        return None if a is None else cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA)

    def mask(m):
        if m is None:
            return None
        small = cv2.resize(m.astype("uint8"), (w, h), interpolation=cv2.INTER_NEAREST)
        return small.astype(bool)

    def cam(c):
        return None if c is None else c.resized(w, h)

    small_inp = replace(
        inp, image=img(inp.image), hand_mask=mask(inp.hand_mask),
        object_mask=mask(inp.object_mask), amodal_mask=mask(inp.amodal_mask),
        inpainted_image=img(inp.inpainted_image),
        complete_hand_mask=mask(inp.complete_hand_mask), hand_camera=cam(inp.hand_camera),
    )  # fmt: skip
    stages = tuple(replace(st, camera=cam(st.camera)) for st in result.stages)
    return replace(result, camera=cam(result.camera), stages=stages), small_inp


def write_result_folder(
    result: HOIResult, inp: HOIInput, out_dir: str | Path, image_name: str
) -> list[Path]:
    """Write every output of one photo into ``out_dir / <image stem>``.

    Parameters
    ----------
    result : HOIResult
        The reconstruction.
    inp : HOIInput
        What it was reconstructed from (photo and masks for the pictures).
    out_dir : path-like
        Parent folder (created if needed).
    image_name : str
        The photo's file name; its stem names the folder (``"IMG_1.jpg"`` -> ``IMG_1``).

    Returns
    -------
    list of Path
        The files of :data:`RESULT_FILES` at their final location.

    Raises
    ------
    InvalidInputError
        Wrong argument types or an ``image_name`` with path separators.
    Any error of the writers propagates after the temporary folder is removed; an existing
    folder is then left untouched.
    """
    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"expected an HOIInput, got {type(inp).__name__}")
    name = _folder_name(image_name)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / name
    if final.exists() and not final.is_dir():
        raise InvalidInputError(f"{final} exists and is not a folder")
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.tmp-", dir=out_dir))
    try:
        _write_all(result, inp, tmp, Path(str(image_name)).name)
        missing = [f for f in RESULT_FILES if not (tmp / f).is_file()]
        if missing:
            raise InvalidInputError(f"result folder incomplete, missing {missing}")
        tmp.chmod(0o755)
        _swap_into_place(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [final / f for f in RESULT_FILES]


def _swap_into_place(tmp: Path, final: Path) -> None:
    """Rename ``tmp`` to ``final``, replacing an existing ``final`` only once ``tmp`` is whole."""
    if not final.exists():
        tmp.rename(final)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
    old.rmdir()
    final.rename(old)
    try:
        tmp.rename(final)
    except BaseException:
        with contextlib.suppress(OSError):
            old.rename(final)
        raise
    shutil.rmtree(old, ignore_errors=True)
