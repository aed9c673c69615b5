"""One folder of outputs per photo, written all-or-nothing.

``write_result_folder(result, inp, "out/IMG_0001", hand_model=model)`` produces::

    out/IMG_0001/
        scene.glb     hand, object and camera, metres (glTF)
        hand.ply      hand mesh, metres (metric object frame)
        object.ply    object mesh, metres (metric object frame)
        result.json   parameters, camera, metrics, timings, versions (see io.export.result_json)
        overlay.png   views.png   stages.png   masks.png   losses.png
        report.html   one self-contained page with all of the above

The caller names the folder (the CLI: ``--out/<photo stem>``; a batch: its planned folder per
photo). The files come from :mod:`easyhoi.io.export` (meshes, JSON) and :mod:`easyhoi.viz`
(pictures, report); :func:`easyhoi.io.atomic.publish_folder` makes the folder appear whole or
not at all.
"""

from __future__ import annotations

from pathlib import Path

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIInput, HOIResult
from easyhoi.io.atomic import atomic_write_bytes, publish_folder
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


def write_result_folder(
    result: HOIResult,
    inp: HOIInput,
    folder: str | Path,
    *,
    hand_model=None,
    title: str = "",
    full_size: bool = False,
) -> list[Path]:
    """Write every output of one photo into ``folder`` (created, or replaced once complete).

    Args:
        result: The reconstruction.
        inp: What it was reconstructed from (photo and masks for the pictures).
        folder: The result folder itself; its parent is created if needed.
        hand_model: The run's hand model; it poses the hands of the stage snapshots in
            ``stages.png`` (None: only the final stage shows the hand).
        title: The report's heading (e.g. the photo's file name; default the folder's name).
        full_size: Pictures at the photo's full size (``--full-size-pictures``) instead of at
            most :data:`easyhoi.viz.report.PICTURE_MAX_SIDE` pixels, with figure panels drawn
            at the size they are shown.

    Returns:
        The files of :data:`RESULT_FILES` at their final location.

    Raises:
        InvalidInputError: Wrong argument types, or a folder without a plain name.
        Any error of the writers propagates after the temporary folder is removed; an existing
        folder is then left untouched.
    """
    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"expected an HOIInput, got {type(inp).__name__}")
    final = Path(folder)

    def fill(tmp: Path) -> None:
        _write_all(result, inp, tmp, hand_model, title or final.name, full_size)

    publish_folder(final, fill, RESULT_FILES)
    return [final / f for f in RESULT_FILES]


def _write_all(
    result: HOIResult, inp: HOIInput, folder: Path, hand_model, title: str, full_size: bool
) -> None:
    from easyhoi.viz import report

    export_glb(result, folder / "scene.glb")
    export_ply(result.hand_mesh().apply_scale(result.metric_scale), folder / "hand.ply")
    export_ply(result.object_mesh_metric(), folder / "object.ply")
    write_result_json(result, folder / "result.json")
    pictures = report.render_pictures(result, inp, hand_model=hand_model, full_size=full_size)
    for name, data in pictures.items():
        atomic_write_bytes(folder / name, data)
    report.write_report(result, inp, folder, images=pictures, title=title)
