"""Tiny synthetic hand-object scenes with ground truth for the optimizer tests and benchmark.

World frame = the OpenHand frame (metres; fingers along -x, palm facing -y, thumb +z). The hand
holds a grasp pose; the object (cylinder along z, or box) sits under the palm, pushed towards
the hand until its signed distance to the closest hand vertex equals ``gap`` (touching, no
penetration). A camera looks at the grasp from below the palm; masks come from hard z-buffers:
M_h = hand in front, M_o = object in front, M^_o = the whole object, M^_h = the whole hand.

The object is handed to the optimizer in a canonical frame ``x_c = s R_c (x_w - c_w)`` whose
axes roughly face the camera (R_c = small rotation @ camera rotation) with unit-less scale
(largest side ``object_units`` units), so the ground-truth object camera and metric scale are
known. The hand estimate lives in a HaMeR-like camera (f = 5000 / 256 * size) with perturbed
rotation, translation and articulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand import load_hand_model
from easyhoi.hand.regions import grasp_pose
from easyhoi.hoi import HOIInput
from easyhoi.optim.placement import move_hand, rest_wrist
from easyhoi.render.raster import depth_map
from easyhoi.structures import Camera, HandParams

#: Default view direction (camera position relative to the grasp) per object kind: the cylinder
#: is seen from below the palm (the object hides part of the hand: back contacts), the box from
#: the thumb side (the fingers hide part of the object: front contacts).
DEFAULT_VIEWS = {"cylinder": (-0.6, -1.0, 0.8), "box": (-0.5, 0.3, 1.0)}


@dataclass
class SynthScene:
    inp: HOIInput
    gt_camera: Camera  # object camera (object frame, object units), full image size
    gt_hand: HandParams  # metric object frame
    gt_metric_scale: float  # metres per object unit
    gt_hand_cam: HandParams  # unperturbed hand in the hand camera's frame
    world_camera: Camera
    model: object
    object_world: trimesh.Trimesh


def _sdf_cylinder(p: np.ndarray, r: float, h: float) -> np.ndarray:
    radial = np.linalg.norm(p[:, :2], axis=1) - r
    axial = np.abs(p[:, 2]) - h / 2
    out = np.linalg.norm(np.stack([radial.clip(0), axial.clip(0)], 1), axis=1)
    return out + np.minimum(np.maximum(radial, axial), 0)


def _sdf_box(p: np.ndarray, ext: np.ndarray) -> np.ndarray:
    q = np.abs(p) - ext / 2
    return np.linalg.norm(q.clip(0), axis=1) + np.minimum(q.max(axis=1), 0)


def _rot(aa) -> np.ndarray:
    return axis_angle_to_matrix(torch.as_tensor(aa, dtype=torch.float64)).numpy()


def make_scene(
    kind: str = "cylinder",
    size: int = 96,
    seed: int = 0,
    gap: float = 0.001,
    view=None,
    object_units: float = 2.0,
    rot_noise: float = 0.08,
    trans_noise: float = 0.04,
    depth_noise: float = 0.08,
    pose_noise: float = 0.04,
    canon_tilt=(0.12, -0.18, 0.08),
    grasp: float = 0.9,
) -> SynthScene:
    """Build a scene (deterministic for a seed). Noise: radians / fraction of depth / radians."""
    rng = np.random.default_rng(seed)
    model = load_hand_model("open", dtype=torch.float64)
    pose = grasp_pose(model, grasp).double()
    pw = HandParams(torch.zeros(1, 3, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64),
                    pose)  # fmt: skip
    with torch.no_grad():
        hv = model(pw).vertices[0].numpy()
    if view is None:
        view = DEFAULT_VIEWS[kind]
    if kind == "cylinder":
        r, h = 0.028, 0.10
        sdf = lambda p: _sdf_cylinder(p, r, h)  # noqa: E731
        obj = trimesh.creation.cylinder(radius=r, height=h, sections=40)
    elif kind == "box":
        ext = np.array([0.05, 0.045, 0.09])
        sdf = lambda p: _sdf_box(p, ext)  # noqa: E731
        obj = trimesh.creation.box(ext)
    else:
        raise ValueError(kind)
    cx, cz = -0.078, -0.006
    lo, hi = -0.25, 0.0  # lo: far below the palm (no contact), hi: inside the hand
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        d = sdf(hv - np.array([cx, mid, cz])).min()
        lo, hi = (mid, hi) if d > gap else (lo, mid)
    c_w = np.array([cx, lo, cz])
    obj.apply_translation(c_w)

    # camera looking at the grasp from below the palm
    d = np.asarray(view, dtype=np.float64)
    d /= np.linalg.norm(d)
    focal = 1.5 * size
    target = 0.5 * (c_w + hv.mean(axis=0))
    cam_w = Camera.look_at(target + 0.45 * d, target, up=(-1.0, 0.0, 0.0), focal=focal,
                           width=size, height=size, dtype=torch.float64)  # fmt: skip
    ov = torch.as_tensor(obj.vertices)
    of = torch.as_tensor(obj.faces)
    zh = depth_map(torch.as_tensor(hv), model.faces, cam_w).numpy()
    zo = depth_map(ov, of, cam_w).numpy()
    hand_mask = np.isfinite(zh) & (zh <= zo)
    object_mask = np.isfinite(zo) & (zo < zh)
    amodal = np.isfinite(zo)
    complete = np.isfinite(zh)

    # canonical object frame: roughly facing the camera, unit-less scale
    Rcam = cam_w.R.numpy()
    Rc = _rot(canon_tilt) @ Rcam
    s = object_units / float(np.ptp(obj.vertices, axis=0).max())
    canon = trimesh.Trimesh((obj.vertices - c_w) @ Rc.T * s, obj.faces, process=False)
    m_gt = 1.0 / s
    R_o = Rcam @ Rc.T
    t_o = s * (Rcam @ c_w + cam_w.t.numpy())
    gt_cam = Camera.from_focal(focal, size, size, R=R_o, t=t_o, dtype=torch.float64)
    wrist = rest_wrist(model, pw.betas)
    gt_hand = move_hand(pw, torch.as_tensor(Rc), torch.as_tensor(-Rc @ c_w), wrist)

    # hand estimate in a HaMeR-like camera, perturbed
    p_cam = move_hand(pw, cam_w.R, cam_w.t, wrist)
    f_h = 5000.0 / 256.0 * size
    k = f_h / focal
    with torch.no_grad():
        centroid = model(p_cam).vertices[0].mean(0)
    # same pixels and apparent size in the longer-focal camera: only the depth scales
    push = torch.tensor([0.0, 0.0, float((k - 1) * centroid[2])], dtype=torch.float64)
    p_hcam = HandParams(p_cam.global_orient, p_cam.transl + push, p_cam.pose)
    Rn = _rot(rng.normal(size=3) * rot_noise / np.sqrt(3))
    zc = float(centroid[2]) * k
    shift = np.array([*(rng.normal(size=2) * trans_noise * zc / np.sqrt(2)),
                      rng.choice([-1.0, 1.0]) * depth_noise * zc])  # fmt: skip
    c_h = (centroid + push).numpy()
    noisy = move_hand(p_hcam, torch.as_tensor(Rn), torch.as_tensor(c_h - Rn @ c_h + shift),
                      wrist)  # fmt: skip
    pose_n = noisy.pose + torch.as_tensor(rng.normal(size=(1, 45)) * pose_noise)
    noisy = HandParams(noisy.global_orient, noisy.transl, pose_n)
    hand_cam = Camera.from_focal(f_h, size, size, dtype=torch.float32)
    image = np.full((size, size, 3), 128, dtype=np.uint8)
    inp = HOIInput(
        image=image,
        hand_mask=hand_mask,
        object_mask=object_mask,
        amodal_mask=amodal,
        object_mesh=canon,
        hand_params=noisy.to(dtype=torch.float32),
        hand_camera=hand_cam,
        hand_model="open",
        complete_hand_mask=complete,
        meta={"synthetic": kind, "seed": seed},
    )
    return SynthScene(inp, gt_cam, gt_hand, m_gt, p_hcam, cam_w, model, obj)
