"""One self-contained HTML page per reconstruction.

The page has inline CSS only, no scripts and no external URLs: every picture is embedded as a
``data:image/png;base64`` URI, so the file can be mailed or opened offline.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hoi import HOIInput, HOIResult
from easyhoi.io.atomic import atomic_write_text

__all__ = [
    "PICTURES",
    "PICTURE_MAX_SIDE",
    "fmt",
    "picture_scale",
    "render_pictures",
    "report_html",
    "write_report",
]

#: Pictures of the report: file name -> caption.
PICTURES = {
    "overlay.png": "Hand (orange) and object (blue) over the photo",
    "views.png": "Other viewpoints around the object centre",
    "stages.png": "Stage snapshots, around the hand and object",
    "masks.png": "Input masks vs rendered masks, around the hand and object",
    "losses.png": "Loss curves",
}

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:24px auto;
max-width:1320px;color:#222;background:#fafafa;padding:0 16px}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;border-bottom:1px solid #ccc;
padding-bottom:3px;margin-top:1.6em}
.sub{color:#666;margin-top:0}
.row{display:flex;gap:16px;flex-wrap:wrap}.row figure{flex:1 1 420px}
figure{margin:0 0 12px 0}figure img{max-width:100%;border:1px solid #ddd;background:#fff}
figcaption{color:#555;font-size:.9em;margin-top:3px}
table{border-collapse:collapse;margin:6px 0 12px 0;font-size:.92em;background:#fff}
td,th{border:1px solid #ddd;padding:4px 10px;text-align:left}th{background:#f0f0f0}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.tables{display:flex;gap:28px;flex-wrap:wrap}
pre{background:#fff;border:1px solid #ddd;padding:8px;overflow:auto;font-size:.85em}
"""


def fmt(value) -> str:
    """Format a value for the report: floats with 4 significant digits, None as "n/a"."""
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        return "n/a" if math.isnan(v) else f"{v:.4g}"
    return str(value)


def _flatten(d: Mapping, prefix: str = "") -> list[tuple[str, object]]:
    rows = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            rows += _flatten(v, key + ".")
        elif isinstance(v, list | tuple) and len(v) <= 6:
            rows.append((key, ", ".join(fmt(x) for x in v)))
        elif isinstance(v, list | tuple):
            rows.append((key, f"[{len(v)} values]"))
        else:
            rows.append((key, v))
    return rows


def _perception_html(meta: Mapping) -> str:
    """Perception's confidence per mask and in the hand's keypoints (score, low, weak cues),
    the hand used and the prompts."""
    perception = meta.get("perception") or {}
    rows = [
        ("hand keypoints" if name == "keypoints" else name, c.get("score"),
         "yes" if c.get("low") else "no", "; ".join(c.get("reasons") or ()))
        for name, c in (perception.get("confidence") or {}).items()
    ]  # fmt: skip
    parts = ["<h2>Perception confidence</h2>",
             _table(rows, ("of", "score", "low", "weak cues"))]  # fmt: skip
    facts = []
    if perception.get("hand_index") is not None:
        facts.append(
            f"hand used: {perception['hand_index']} ({perception.get('side')}) of "
            f"{perception.get('hands_found')} detected, {perception.get('hand_choice')}"
        )
    prompts = meta.get("prompts")
    if prompts:
        given = {k: v for k, v in prompts.items() if v}
        facts.append("prompts (photo pixels): " + json.dumps(given))
    parts += [f"<p>{html.escape(f)}</p>" for f in facts]
    return "\n".join(parts)


#: Where the object's thickness along the view came from (``object_shape.depth_cue_from``).
_DEPTH_SOURCES = {
    "gap": "the gap between the fingers in front of the object and behind it",
    "pinch": "the aperture of a pinch across it along the view",
}
#: Parts of a family's score shown in the table, with their labels (the rest stays in
#: result.json); a surface of revolution's own tilt comes from the rim of its end.
_SCORE_NOTES = {
    "edge_bonus": "edge bonus",
    "depth_penalty": "depth penalty",
    "depth_scaled": "depth scaled by",
    "relief_agreement": "relief agreement",
    "tilt_deg": "tilted by its rim (deg)",
}


#: A runner-up family whose score is within this of the chosen one's is named in the report:
#: the outline alone hardly tells the two apart (on the development photos the inflation wins
#: most outlines by less than this over the slab or the next family; docs/object_shape.md).
NEAR_TIE = 0.04


def _near_tie(scores: Mapping, order: list[str], chosen) -> str | None:
    """The report's line on a runner-up within :data:`NEAR_TIE` of the chosen family, or None."""
    if chosen not in scores or len(order) < 2:
        return None
    runner = next(k for k in order if k != chosen)
    margin = float(scores[chosen].get("score", 0.0)) - float(scores[runner].get("score", 0.0))
    if margin >= NEAR_TIE:
        return None
    return (
        f"near tie: {runner} scored {margin:.3f} below {chosen}, so the outline alone hardly "
        f"tells them apart (--object-shape {runner} fits that family alone)"
    )


def _shape_html(meta: Mapping, sides_cm=None) -> str:
    """The object step's choice: the family, where the thickness along the view came from, the
    object's size, and every family's score (``meta["object_shape"]``, written by the offline
    object step; an imported or image-to-3D mesh has none)."""
    shape = meta.get("object_shape")
    if not isinstance(shape, Mapping) or not shape.get("scores"):
        return ""
    scores = shape["scores"]
    order = sorted(scores, key=lambda k: -float(scores[k].get("score", float("-inf"))))
    rows = []
    for name in order:
        s = scores[name]
        notes = "; ".join(f"{label} {fmt(s[k])}" for k, label in _SCORE_NOTES.items() if s.get(k))
        label = f"{name} (chosen)" if name == shape.get("shape") else name
        rows.append((label, s.get("iou"), s.get("complexity"), s.get("score"), notes))
    source = _DEPTH_SOURCES.get(shape.get("depth_cue_from"))
    if source:
        conf = fmt(shape.get("depth_cue_confidence"))
        depth = f"thickness along the view from {source} (confidence {conf})"
        if shape.get("flat_by_grip"):
            depth += "; the grip says the object is flat"
    else:
        # the priors' values from the families themselves (imported here: the pipeline that
        # wrote the record has them loaded already)
        from easyhoi.perception.shapes import cuboid, inflation, slab

        depth = (
            "thickness along the view not measured (no grip gap or pinch on the object): it is "
            "the chosen family's own assumption (round families as deep as wide, the fallback "
            f"{fmt(inflation.DEPTH_RATIO)} of that, a slab {fmt(slab.PRIOR_THICKNESS_RATIO)} of "
            f"its inscribed width, a box seen face-on {fmt(cuboid.PRIOR_DEPTH_RATIO)} of its "
            "shorter side), a guess; docs/object_shape.md"
        )
    if len(scores) == 1:
        how = "the one family fitted (--object-shape)"
    else:
        how = (
            f"the best of {len(scores)} families fitted; when you know the object's kind, "
            "--object-shape NAME fits that family alone"
        )
    facts = [f"chosen: {shape.get('shape')}, {how}", depth]
    if (tie := _near_tie(scores, order, shape.get("shape"))) is not None:
        facts.append(tie)
    if shape.get("tilt_deg"):
        facts.append(f"tilted out of the image by {fmt(shape['tilt_deg'])} degrees (keypoints)")
    if sides_cm is not None:
        facts.append(
            "size (along its principal axes): "
            + " x ".join(f"{float(v):.1f}" for v in sides_cm)
            + " cm"
        )
    parts = ["<h2>Object shape</h2>"] + [f"<p>{html.escape(f)}</p>" for f in facts]
    header = ("family", "fit IoU", "complexity", "score", "parts of the score")
    if not any(r[-1] for r in rows):  # no family's score has parts: no empty column
        rows, header = [r[:-1] for r in rows], header[:-1]
    parts.append(_table(rows, header))
    return "\n".join(parts)


def _object_sides_cm(result) -> np.ndarray | None:
    """The metric object's extents along its principal axes in cm, longest first (None for a
    mesh with no extent)."""
    v = np.asarray(result.object_mesh.vertices, np.float64) * float(result.metric_scale)
    if len(v) < 4 or not np.isfinite(v).all():
        return None
    c = v - v.mean(axis=0)
    _, axes = np.linalg.eigh(c.T @ c)
    return np.sort(np.ptp(c @ axes, axis=0) * 100.0)[::-1]


def _table(rows, header=("name", "value")) -> str:
    if not rows:
        return "<p><em>none recorded</em></p>"
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for row in rows:
        cells = []
        for i, v in enumerate(row):
            cls = ' class="num"' if i > 0 and not isinstance(v, str) else ""
            cells.append(f"<td{cls}>{html.escape(fmt(v))}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "\n".join(out) + "</table>"


def _img(data: bytes, alt: str) -> str:
    b64 = base64.b64encode(data).decode("ascii")
    return f'<img src="data:image/png;base64,{b64}" alt="{html.escape(alt)}">'


#: Pictures are drawn at most this many pixels on the photo's longer side (drawing with the
#: CPU rasterizer costs time in proportion to the pixel count; the photo itself keeps its size).
PICTURE_MAX_SIDE = 1024


def picture_scale(
    result: HOIResult, inp: HOIInput, max_side: int | None = PICTURE_MAX_SIDE
) -> tuple[HOIResult, HOIInput]:
    """``result`` and ``inp`` at picture size: photo, masks and every camera downscaled (the
    hand-removed photo and the complete hand mask, which no picture draws, dropped; see
    :func:`easyhoi.viz.zoom.mapped`).

    Returns the arguments unchanged when the photo's longer side is at most ``max_side``, or
    when ``max_side`` is None (full-size pictures).
    """
    import cv2

    from easyhoi.viz.zoom import mapped

    H, W = inp.image.shape[:2]
    if max_side is None or max(H, W) <= max_side:
        return result, inp
    s = max_side / max(H, W)
    w, h = max(1, round(W * s)), max(1, round(H * s))

    def img(a):
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA)

    def mask(m):
        small = cv2.resize(m.astype("uint8"), (w, h), interpolation=cv2.INTER_NEAREST)
        return small.astype(bool)

    return mapped(result, inp, img, mask, lambda c: c.resized(w, h))


def render_pictures(
    result: HOIResult,
    inp: HOIInput,
    hand_model=None,
    full_size: bool = False,
    max_side: int | None = PICTURE_MAX_SIDE,
) -> dict[str, bytes]:
    """PNG bytes of every picture in :data:`PICTURES` (the expensive part of a report).

    ``overlay.png`` shows the whole photo, at most ``max_side`` pixels on its longer side;
    ``stages.png`` and ``masks.png`` show the window around the hand and the object
    (:mod:`easyhoi.viz.zoom`), cut from the photo at its own size.

    Args:
        result: The reconstruction.
        inp: Its input (photo and masks), at the photo's size.
        hand_model: The run's hand model, posing the stage snapshots' hands (None: only the
            final stage shows the hand).
        full_size: Draw the pictures at the photo's size (no ``max_side``) and the overlays
            inside the figures at their window's size instead of the size of their panels.
        max_side: Longer side of the pictures, pixels (None: the photo's).
    """
    from easyhoi.viz import masks, stages
    from easyhoi.viz.overlay import render_overlay, shrink_photo
    from easyhoi.viz.plots import losses_png, png_bytes
    from easyhoi.viz.views import views_png
    from easyhoi.viz.zoom import interaction_box, outlined, zoomed

    cap = None if full_size else max_side
    small_result, small_inp = picture_scale(result, inp, cap)
    box = interaction_box(result, inp)
    wide = max(masks.PANEL_WIDTH, stages.PANEL_WIDTH)
    zoom_result, zoom_inp = picture_scale(*zoomed(result, inp, box, wide), cap)
    photo = shrink_photo(small_inp.image, masks.PANEL_WIDTH)
    f = photo.shape[1] / inp.image.shape[1]
    context = outlined(photo, tuple(round(v * f) for v in box))
    prompts, size = inp.meta.get("prompts"), inp.meta.get("prompts_photo_size")
    if prompts and size:  # where the user pointed, on the whole photo
        from easyhoi.viz.marks import draw_marks

        context = draw_marks(
            context, prompts, context.shape[1] / size[0], context.shape[0] / size[1]
        )
    return {
        "overlay.png": png_bytes(render_overlay(small_result, small_inp.image).image),
        "views.png": views_png(result),
        "stages.png": stages.stages_png(
            zoom_result, zoom_inp.image, hand_model, full_size=full_size, zoomed=True
        ),
        "masks.png": masks.masks_png(
            zoom_result,
            zoom_inp,
            full_size=full_size,
            context=context,
            choices=masks.choice_panels(
                small_inp.image, inp.meta, small_inp.image.shape[1] / inp.image.shape[1]
            ),
        ),  # fmt: skip
        "losses.png": losses_png(result),
    }


def _hand_rows(result: HOIResult) -> list[tuple[str, object]]:
    p = result.hand_params.detach().to(dtype=torch.float64)
    pose = p.pose[0].numpy().reshape(15, 3)
    angles = np.degrees(np.linalg.norm(pose, axis=1))
    go = p.global_orient[0].numpy()
    return [
        ("hand model", result.hand_model),
        ("side", p.side),
        ("global orientation (axis-angle, rad)", ", ".join(fmt(float(x)) for x in go)),
        ("global rotation angle (deg)", float(np.degrees(np.linalg.norm(go)))),
        ("translation (m)", ", ".join(fmt(float(x)) for x in p.transl[0].numpy())),
        ("articulation: mean joint angle (deg)", float(angles.mean())),
        ("articulation: max joint angle (deg)", float(angles.max())),
        ("shape betas", ", ".join(fmt(float(x)) for x in p.betas[0].numpy())),
        ("vertices / faces", f"{len(result.hand_vertices)} / {len(result.hand_faces)}"),
    ]


def _camera_rows(result: HOIResult) -> list[tuple[str, object]]:
    from easyhoi.io.export import metric_camera

    cam = metric_camera(result)
    K = cam.K.numpy()
    center = np.asarray(result.object_mesh.bounds).mean(0) * result.metric_scale
    dist = float(np.linalg.norm(cam.R.numpy() @ center + cam.t.numpy()))
    fov = math.degrees(2 * math.atan(cam.height / (2 * K[1, 1])))
    return [
        ("image size (W x H)", f"{cam.width} x {cam.height}"),
        ("fx, fy (px)", f"{fmt(float(K[0, 0]))}, {fmt(float(K[1, 1]))}"),
        ("cx, cy (px)", f"{fmt(float(K[0, 2]))}, {fmt(float(K[1, 2]))}"),
        ("vertical field of view (deg)", fov),
        ("camera to object centre (m)", dist),
        ("metric scale (m per object unit)", result.metric_scale),
    ]


def report_html(
    result: HOIResult, inp: HOIInput, images: Mapping[str, bytes] | None = None, title: str = ""
) -> str:
    """The report page as a string.

    Args:
        result: The reconstruction.
        inp: Its input.
        images: Pictures already rendered, file name -> PNG bytes (keys of :data:`PICTURES`);
            missing ones are rendered.
        title: Shown in the heading (e.g. the photo's name); defaults to
            ``result.meta["image"]``.
    """
    from easyhoi.io.export import result_json
    from easyhoi.viz.masks import mask_ious
    from easyhoi.viz.plots import png_bytes

    if not isinstance(result, HOIResult):
        raise InvalidInputError(f"expected an HOIResult, got {type(result).__name__}")
    if not isinstance(inp, HOIInput):
        raise InvalidInputError(f"expected an HOIInput, got {type(inp).__name__}")
    pics = dict(images or {})
    if any(k not in pics for k in PICTURES):
        pics = {**render_pictures(result, inp), **pics}
    title = title or str(result.meta.get("image", "")) or "reconstruction"
    doc = result_json(result)
    ious = mask_ious(result, inp)
    from easyhoi.optim.run import SELF_CONSISTENCY_KEYS

    metric_rows = [
        (f"{k} (fit to its own masks, not accuracy)" if k in SELF_CONSISTENCY_KEYS else k, v)
        for k, v in _flatten(result.plausibility)
    ]
    metric_rows += [(f"mask IoU: {k.replace('_', ' ')}", v) for k, v in ious.items()]
    timing_rows = [(k, v) for k, v in _flatten(result.timings)]
    stage_rows = []
    for st in doc["stages"]:
        last = st["final_losses"].get("total")
        stage_rows.append((st["name"], st["iterations"], st["seconds"], st["stop_reason"], last))
    sub = (
        f"hand model {result.hand_model} · seed {result.seed} · "
        f"metric scale {fmt(result.metric_scale)} m/unit · {len(result.stages)} stages · "
        f"easyhoi {doc['versions']['easyhoi']}"
    )
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>EasyHOI report: {html.escape(title)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>EasyHOI reconstruction: {html.escape(title)}</h1>",
        f'<p class="sub">{html.escape(sub)}</p>',
        '<div class="row">',
        f"<figure>{_img(png_bytes(inp.image), 'input photo')}<figcaption>Input photo"
        "</figcaption></figure>",
        f"<figure>{_img(pics['overlay.png'], 'overlay')}<figcaption>"
        f"{html.escape(PICTURES['overlay.png'])}</figcaption></figure>",
        "</div>",
        '<div class="tables"><div><h2>Metrics</h2>',
        _table(metric_rows, ("metric", "value")),
        "</div><div><h2>Timings (s)</h2>",
        _table(timing_rows, ("step", "seconds")),
        "</div></div>",
        _perception_html(result.meta),
        _shape_html(result.meta, _object_sides_cm(result)),
        "<h2>Stages</h2>",
        _table(stage_rows, ("stage", "iterations", "seconds", "stop reason", "final total loss")),
        '<div class="tables"><div><h2>Hand parameters</h2>',
        _table(_hand_rows(result), ("parameter", "value")),
        "</div><div><h2>Camera (OpenCV convention, metres)</h2>",
        _table(_camera_rows(result), ("parameter", "value")),
        "</div></div>",
    ]
    for name in ("views.png", "stages.png", "masks.png", "losses.png"):
        cap = html.escape(PICTURES[name])
        parts += [f"<h2>{cap}</h2>", f"<figure>{_img(pics[name], name)}</figure>"]
    details = {"versions": doc["versions"], "config": doc["config"], "meta": doc["meta"]}
    parts += [
        "<h2>Versions and configuration</h2>",
        f"<pre>{html.escape(json.dumps(details, indent=1, sort_keys=True))}</pre>",
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def write_report(
    result: HOIResult,
    inp: HOIInput,
    folder: str | Path,
    images: Mapping[str, bytes] | None = None,
    title: str = "",
) -> Path:
    """Write ``report.html`` into ``folder`` (which must exist) atomically; returns its path.

    See :func:`report_html` for the arguments.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"report folder {folder} does not exist")
    return atomic_write_text(folder / "report.html", report_html(result, inp, images, title))
