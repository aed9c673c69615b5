"""Real photos: the object's shape family on perception's outline and on the drawn one.

On synthetic photos ``bench_object.py`` measures the object step against scanned objects; real
photos have no 3D truth, but they have drawn outlines (``tests/data/perception_refs``). For every
development photo with a held object this script runs the perception chain with one object
point, the deepest pixel of the reference object (as ``bench_perception.py --click-only``), and
then the object step (:class:`~easyhoi.perception.objects.SilhouetteReconstructor`, with the
fitted hand's keypoints, as the chain calls it) twice on the same hand-free photo:

* on the amodal mask the chain made from its one-point mask (what the product does; the family
  must be the one the chain recorded, ``same`` in the rows);
* on the drawn reference outline, completed behind perception's hand mask as the amodal step
  completes a mask (:func:`~easyhoi.perception.amodal.occluder_completion`: its convex hull where
  it meets the hand grown by 2 px), with the reference as the visible mask.

Per photo: the one-point mask's IoU with the reference, the winning family on each outline and
where its thickness along the view came from (the hand's grip gap or pinch, or none); the summary
counts the families, the inflations (the fallback, a pillow of the outline) and the thickness
cues on each. The difference between the two columns is what perception's outline costs the
shape step. Each reference's held object's name (``kind`` of
:func:`bench_perception.reference`) gives its kind, and the kinds that one family suits
(:data:`KIND_FAMILIES`: a cup, a can, a bottle or a pen is a solid of revolution or a tube, a
phone, a book or a box a cuboid or a slab) score the winner on each outline (``kind_right`` of
``kind_scored``); each family's score and its parts are kept per row (``scores_perception``,
``scores_drawn``) so that a selection rule can be re-scored offline.
A picture (``--png``, next to the JSON by default) shows the photos whose two families differ:
the photo with both outlines, then each mesh seen from the photo's camera and from its right.

Usage::

    python benchmarks/bench_real_shapes.py [--only NAME] [--json OUT] [--png OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_perception import DATA, RESULTS, fit_to, iou, reference  # noqa: E402

#: Pixels the hand mask is grown by before the hull completes the drawn outline behind it (the
#: amodal step's own margin).
MARGIN_PX = 2.0
#: Outline colours of the picture: perception's one-point outline, the drawn one.
PERCEPTION_RGB, DRAWN_RGB = (230, 60, 40), (40, 200, 80)
#: Side of each rendered view of a mesh in the picture, pixels.
VIEW_PX = 160
#: Families that can be right for a kind of object: a cup, a can, a bottle, a bowl or a pen
#: is a solid of revolution (a long one a tube, a cup or a jug may have a handle); a phone, a
#: book, a box, a board or a sheet is a box or a slab; a ball is round every way.
ROUND = ("revolution", "tube", "handled")
FLAT = ("cuboid", "slab")
BALL = ("superquadric", "revolution")
#: The reference objects' names (``tests/data/perception_refs``) with a family that suits them;
#: objects of no one family (a trumpet, shears, a game controller) are not scored.
KIND_FAMILIES = {
    **dict.fromkeys(("paper cup", "reusable cup", "can", "spray bottle", "bottle", "pen",
                     "whisk", "microphone", "stone bowl", "marker", "spray can"), ROUND),
    **dict.fromkeys(("toy airplane", "phone", "book", "picture board", "knife",
                     "toy brick assembly", "candy strips", "board game", "card", "box",
                     "paper sheet"), FLAT),
    "cake pop": BALL,
}  # fmt: skip


def completed_reference(ref_object: np.ndarray, hand_mask: np.ndarray) -> np.ndarray:
    """The drawn (visible) outline completed behind the hand as the amodal step completes a mask."""
    from easyhoi.perception.amodal import occluder_completion

    return occluder_completion(ref_object, hand_mask, MARGIN_PX)


def shape_family(mesh) -> str:
    """The winning family recorded on an object mesh of the silhouette reconstructor."""
    return str((mesh.metadata.get("easyhoi") or {}).get("method"))


def shape_scores(mesh) -> dict:
    """Each family's score and its parts as the step recorded them on an object mesh."""
    return ((mesh.metadata.get("easyhoi") or {}).get("shape") or {}).get("scores") or {}


def thickness_cue(mesh) -> str | None:
    """Where the object's thickness along the view came from on an object mesh of the
    silhouette reconstructor: the grip's gap or pinch (``"gap"``, ``"pinch"``), or None when the
    hand gave none and every family kept its own depth."""
    shape = (mesh.metadata.get("easyhoi") or {}).get("shape") or {}
    return shape.get("depth_cue_from")


def mesh_views(mesh, size: int = VIEW_PX) -> np.ndarray:
    """(size, 2 size, 3) uint8: the mesh (canonical frame: u right, v down, z away from the
    photo's camera) seen from the photo's camera and from its right, side by side."""
    from easyhoi.structures import Camera
    from easyhoi.viz import OBJECT_COLOR, SceneMesh, render_shaded
    from easyhoi.viz.views import view_cameras

    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    c = (v.min(0) + v.max(0)) / 2
    radius = float(np.linalg.norm(v - c, axis=1).max())
    # the canonical frame is the photo camera's: the result's own "front" and "side" views
    photo = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    cams = view_cameras(c, radius, photo, size)
    meshes = [SceneMesh(v, f, OBJECT_COLOR, "object")]
    bg = np.array((250, 250, 250), np.uint8)
    return np.hstack(
        [render_shaded(meshes, cams[k], background=bg).image for k in ("front", "side")]
    )


def outlined_crop(rgb: np.ndarray, perceived: np.ndarray, drawn: np.ndarray) -> np.ndarray:
    """The photo around both outlines (a sixth of their extent around them), scaled to
    :data:`VIEW_PX` pixels high, both outlines drawn."""
    import cv2

    rows, cols = np.nonzero(perceived | drawn)
    y0, y1, x0, x1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    m = max(y1 - y0, x1 - x0) // 6 + 2
    y0, x0 = max(0, y0 - m), max(0, x0 - m)
    y1, x1 = min(rgb.shape[0], y1 + m), min(rgb.shape[1], x1 + m)
    out = np.ascontiguousarray(rgb[y0:y1, x0:x1])
    scale = VIEW_PX / out.shape[0]  # as tall as the mesh views beside it
    size = (max(1, round(out.shape[1] * scale)), VIEW_PX)
    out = cv2.resize(out, size, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    for mask, colour in ((perceived, PERCEPTION_RGB), (drawn, DRAWN_RGB)):
        crop = np.ascontiguousarray(mask[y0:y1, x0:x1]).astype(np.uint8)
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, contours, -1, colour, 2)
    return out


def picture(shown: list[tuple[dict, np.ndarray, object, object]]) -> np.ndarray:
    """(H, W, 3) uint8: per photo, the outlined crop and the two meshes' views."""
    from easyhoi.viz.compose import Panel, compose_grid

    panels = []
    for row, crop, m_perceived, m_drawn in shown:
        panels += [
            Panel(crop, f"{row['photo'][:30]}\nmask IoU {row['mask_iou']:.2f}"),
            Panel(mesh_views(m_perceived), f"perception's outline:\n{row['perception']}"),
            Panel(mesh_views(m_drawn), f"drawn outline:\n{row['drawn']}"),
        ]
    legend = [("perception's one-point outline", PERCEPTION_RGB), ("drawn outline", DRAWN_RGB)]
    title = "The object step on perception's outline and on the drawn one (front, right)"
    return compose_grid(panels, 3, 2 * VIEW_PX, title=title, legend=legend)


def run_photo(path: Path, ref: dict, settings, keep: list | None = None) -> dict:
    """One photo: the chain with one object point, then the object step on both outlines.
    With ``keep``, a photo whose two families differ appends (row, outlined crop, mesh on
    perception's outline, mesh on the drawn one) to it for the picture."""
    from types import SimpleNamespace

    from easyhoi.errors import EasyHOIError
    from easyhoi.io.image import load_image
    from easyhoi.perception.chain import perceive
    from easyhoi.perception.objects import SilhouetteReconstructor, hand_inputs
    from easyhoi.perception.prompts import Prompts

    rgb = load_image(path).rgb
    ref = fit_to(ref, rgb.shape[:2])
    row = {"photo": path.name, "kind": ref["kind"]}
    try:
        prompts = Prompts(object_points=(tuple(float(v) for v in ref["point"]),))
        inp, _ = perceive(rgb, settings, prompts=prompts)
    except EasyHOIError as exc:
        return {**row, "error": f"{type(exc).__name__}: {exc}"}
    row["mask_iou"] = iou(inp.object_mask, ref["object"])
    rec = SilhouetteReconstructor()
    hand = SimpleNamespace(params=inp.hand_params, camera=inp.hand_camera,
                           keypoints2d=inp.meta["keypoints2d"], keypoints3d=None)  # fmt: skip
    img = inp.inpainted_image if inp.inpainted_image is not None else inp.image

    def mesh(amodal, visible):
        kw = hand_inputs(rec, hand, settings.hand_model, inp.hand_mask, visible)
        return rec.reconstruct(img, amodal, **kw)

    m_perceived = mesh(inp.amodal_mask, inp.object_mask)
    row["perception"] = shape_family(m_perceived)
    row["scores_perception"] = shape_scores(m_perceived)
    row["cue_perception"] = thickness_cue(m_perceived)
    row["same"] = row["perception"] == (inp.meta.get("object_shape") or {}).get("shape")
    drawn = ref["object"]
    m_drawn = mesh(completed_reference(drawn, inp.hand_mask), drawn)
    row["drawn"] = shape_family(m_drawn)
    row["scores_drawn"] = shape_scores(m_drawn)
    row["cue_drawn"] = thickness_cue(m_drawn)
    if keep is not None and row["perception"] != row["drawn"]:
        keep.append((row, outlined_crop(rgb, inp.object_mask, drawn), m_perceived, m_drawn))
    return row


def summary(rows: list[dict]) -> dict:
    """Family counts on each outline, the inflations among them, and the photos that differ."""
    ok = [r for r in rows if "error" not in r]
    out = {"photos": len(rows), "reconstructed": len(ok)}
    for side in ("perception", "drawn"):
        counts = Counter(r[side] for r in ok)
        out[f"{side}_families"] = dict(sorted(counts.items()))
        out[f"{side}_inflation"] = counts.get("inflation", 0)
        # how often the hand measured the thickness along the view (docs/object_shape.md)
        cues = Counter(r.get(f"cue_{side}") for r in ok if r.get(f"cue_{side}"))
        out[f"{side}_thickness_cue"] = dict(sorted(cues.items()))
    out["differ"] = sum(r["perception"] != r["drawn"] for r in ok)
    kinds = [r for r in ok if r.get("kind") in KIND_FAMILIES]
    for side in ("perception", "drawn"):  # the family suits the object's kind
        out[f"{side}_kind_right"] = sum(r[side] in KIND_FAMILIES[r["kind"]] for r in kinds)
    out["kind_scored"] = len(kinds)
    out["chain_family_reproduced"] = sum(bool(r["same"]) for r in ok)
    masks = [r["mask_iou"] for r in ok]
    out["mask_iou_ge_0.5"] = float(np.mean([m >= 0.5 for m in masks])) if masks else 0.0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="substring of the photo names to run")
    ap.add_argument("--json", type=Path, default=RESULTS / "bench_real_shapes.json")
    ap.add_argument("--png", type=Path, default=None,
                    help="the picture (default: the JSON's path with .png)")  # fmt: skip
    args = ap.parse_args(argv)
    from easyhoi.settings import resolve_run

    settings = resolve_run(None, seed=0)
    rows, shown = [], []
    for f in sorted((ROOT / "tests" / "data" / "perception_refs").glob("*.json")):
        if args.only not in f.stem:
            continue
        ref = reference(f)
        if ref["object"] is None or ref["point"] is None:
            continue
        if not (DATA / ref["image"]).is_file():
            print(f"skipped (photo not found): {ref['image']}", file=sys.stderr)
            continue
        row = run_photo(DATA / ref["image"], ref, settings, keep=shown)
        rows.append(row)
        if "error" in row:
            print(f"{row['photo']:45s} {row['error']}", flush=True)
        else:
            fams = f"perception {row['perception']:12s} drawn {row['drawn']}"
            print(f"{row['photo']:45s} mask {row['mask_iou']:.2f}  {fams}", flush=True)
    out = {"summary": summary(rows), "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1))
    print(json.dumps(out["summary"], indent=1))
    if shown:
        from easyhoi.viz.png import encode_png

        png = args.png or args.json.with_suffix(".png")
        png.write_bytes(encode_png(picture(shown), 6))
        print(f"picture: {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
