"""A small synthetic hand-holding-a-box result (and its input) for export / viz / report tests.

The hand is the built-in open hand in a partial grasp; the object is a box under its palm.
Object units are 1/20 m (``METRIC_SCALE = 0.05`` metres per unit). The photo is a rendered
"ground truth" (hand and box in other colours over a gradient); the result's hand is shifted a
little so that overlays do not match it exactly.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from easyhoi.hand import load_hand_model
from easyhoi.hand.regions import grasp_pose
from easyhoi.hoi import HOIInput, HOIResult, StageResult
from easyhoi.structures import Camera, HandParams
from easyhoi.viz.shade import SceneMesh, render_shaded

METRIC_SCALE = 0.05
BOX_EXTENTS_M = (0.07, 0.04, 0.06)
BOX_CENTER_M = (-0.085, -0.047, 0.0)
H, W = 120, 160


def hand_model():
    return load_hand_model("open", dtype=torch.float64)


def hand_params(shift=(0.0, 0.0, 0.0)) -> HandParams:
    z = torch.zeros(1, 3, dtype=torch.float64)
    t = torch.tensor([shift], dtype=torch.float64)
    return HandParams(z, t, grasp_pose(hand_model(), 0.6))


def box_mesh() -> trimesh.Trimesh:
    """The object in object units."""
    m = trimesh.creation.box(extents=np.array(BOX_EXTENTS_M) / METRIC_SCALE)
    m.apply_translation(np.array(BOX_CENTER_M) / METRIC_SCALE)
    return m


def camera(height: int = H, width: int = W, offset=(0.0, 0.0, 0.0)) -> Camera:
    c = np.array(BOX_CENTER_M) / METRIC_SCALE
    eye = c + np.array([1.6, 3.2, 7.5]) + np.asarray(offset)
    return Camera.look_at(eye, c + np.array([0.5, 0.2, 0.0]), up=(0.0, 1.0, 0.0),
                          focal=1.3 * width, width=width, height=height,
                          dtype=torch.float64)  # fmt: skip


def _losses(n: int, start: float, keys=("iou", "sinkhorn")) -> list[dict]:
    out = []
    for i in range(n):
        d = {"iter": i * 10}
        for j, k in enumerate(keys):
            d[k] = start * (j + 1) * np.exp(-0.08 * i) + 1e-3
        d["total"] = sum(d[k] for k in keys)
        out.append(d)
    return out


def make_result(height: int = H, width: int = W, plausibility=None) -> HOIResult:
    model = hand_model()
    final = hand_params((0.004, 0.003, 0.0))
    out = model(final)
    stages = (
        StageResult("initial", hand_params((0.03, 0.02, 0.01)), camera(height, width, (0.8, 0, 0))),
        StageResult("camera", hand_params((0.03, 0.02, 0.01)), camera(height, width),
                    _losses(20, 0.6), seconds=1.5, iterations=200, stop_reason="stop_loss"),
        StageResult("contact", hand_params((0.01, 0.01, 0.0)), camera(height, width),
                    _losses(30, 0.4, ("hand_iou",)), seconds=3.0, iterations=300,
                    metric_scale=METRIC_SCALE, stop_reason="max_iters"),
        StageResult("refine", final, camera(height, width),
                    _losses(25, 0.2, ("hand_mask", "penetration", "contact", "reg")),
                    seconds=2.25, iterations=250, metric_scale=METRIC_SCALE,
                    stop_reason="patience"),
    )  # fmt: skip
    if plausibility is None:
        plausibility = {"max_penetration_cm": 0.3217, "contact_ratio": 0.8125,
                        "intersection_volume_cm3": 1.875}  # fmt: skip
    return HOIResult(
        hand_params=final,
        camera=camera(height, width),
        hand_vertices=out.vertices[0].numpy() / METRIC_SCALE,
        hand_faces=out.faces.numpy(),
        object_mesh=box_mesh(),
        metric_scale=METRIC_SCALE,
        stages=stages,
        timings={"camera": 1.5, "contact": 3.0, "refine": 2.25, "total": 6.75},
        seed=7,
        config={"preset": "fast", "camera": {"lr": 0.01}},
        plausibility=plausibility,
        meta={"image": "synthetic.png"},
    )


def make_input(result: HOIResult | None = None, height: int = H, width: int = W) -> HOIInput:
    """A photo and masks rendered from the unshifted hand and the box."""
    model = hand_model()
    out = model(hand_params())
    hand = SceneMesh(out.vertices[0].numpy() / METRIC_SCALE, out.faces.numpy(), (200, 140, 110))
    box = box_mesh()
    obj = SceneMesh(box.vertices, box.faces, (210, 190, 60))
    cam = camera(height, width)
    yy, xx = np.mgrid[0:height, 0:width]
    bg = np.stack([60 + 80 * yy / height, 90 + 60 * xx / width, 110 + 0 * xx], -1).astype(np.uint8)
    r = render_shaded([hand, obj], cam, background=bg)
    amodal = render_shaded([obj], cam).labels == 0
    return HOIInput(
        image=r.image,
        hand_mask=r.labels == 0,
        object_mask=r.labels == 1,
        amodal_mask=amodal,
        object_mesh=box,
        hand_params=hand_params(),
        hand_camera=Camera.hamer_convention(width, height),
    )
