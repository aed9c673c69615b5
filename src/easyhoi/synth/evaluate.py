"""Per-scene ground truth and measurements of the synthetic benchmark.

:func:`evaluate_hand` measures one hand against the ground truth of a scene (units and frames:
:mod:`easyhoi.synth.benchmark`); :func:`gt_hand_state` gives the GT hand as a result would hold
it; :func:`refine_from_contact` re-runs stage 3 for the loss ablation; the private functions
measure the estimator's hand, the input object's quality and every stage snapshot of a run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh

from easyhoi import metrics
from easyhoi.config import OptimConfig
from easyhoi.structures import HandParams

#: Gravity cone of ``sd_cone_cm``: tilt from the image-down direction (degrees) and azimuths.
SD_CONE_TILT_DEG = 10.0
SD_CONE_AZIMUTHS = 6
#: Below this angle (degrees) a camera's image down is the GT camera's (the ground-truth rows,
#: whose camera is the GT one): ``sd_own_cm`` is then the untilted simulation already run.
SAME_GRAVITY_DEG = 1e-9

__all__ = [
    "evaluate_hand",
    "gt_hand_state",
    "refine_from_contact",
]


@dataclass
class _Truth:
    """Ground truth of one input: frames, the GT hand, the scene for GT-mask IoUs."""

    model: object
    world_from_canonical: np.ndarray  # (4, 4): x_world = A @ x_can + b (metres)
    metres_per_unit: float
    gravity_obj: np.ndarray  # (3,) unit, object (canonical) frame
    joints: np.ndarray  # (21, 3) world, metres
    verts: np.ndarray  # (V, 3) world, metres
    joints_cam: np.ndarray  # (21, 3) GT camera frame, metres
    keypoints_2d: np.ndarray  # (21, 2) GT pixels
    verts_cam: np.ndarray  # (V, 3) GT camera frame, metres
    opt_scene: object  # easyhoi.optim.state.Scene with the GT masks
    render_size: int
    sdf_resolution: int


def _truth(scene, inp, cfg: OptimConfig) -> _Truth:
    from easyhoi.optim.state import Scene as OptScene

    gt = inp.meta["gt"]
    M = np.asarray(gt["canonical_from_world"], float)
    s = float(np.linalg.norm(M[:3, 0]))
    Rc = M[:3, :3] / s
    R_cam = scene.camera.R.numpy()
    model = scene.hand_model
    with torch.no_grad():
        gt_cam = HandParams.from_dict(gt["hand_params_camera"]).to(torch.float64)
        out = model(gt_cam)
    gt_inp = replace(
        inp,
        hand_mask=scene.hand_mask,
        object_mask=scene.object_mask,
        amodal_mask=scene.object_amodal,
    )
    return _Truth(
        model=model,
        world_from_canonical=np.linalg.inv(M),
        metres_per_unit=float(gt["metres_per_unit"]),
        gravity_obj=Rc @ R_cam.T @ np.array([0.0, 1.0, 0.0]),
        joints=np.asarray(scene.keypoints_3d),
        verts=np.asarray(scene.grasp.vertices),
        joints_cam=out.keypoints[0].numpy(),
        keypoints_2d=np.asarray(scene.keypoints_2d, dtype=np.float64),
        verts_cam=out.vertices[0].numpy(),
        opt_scene=OptScene.from_input(gt_inp, model, cfg.torch_dtype),
        render_size=cfg.render_size,
        sdf_resolution=cfg.refine.sdf_resolution,
    )


def _hand_out(model, params: HandParams):
    with torch.no_grad():
        out = model(params.detach().to(torch.float64))
    return out.vertices[0].numpy(), out.keypoints[0].numpy()


def _mask_ious(truth: _Truth, v_obj: torch.Tensor, camera) -> tuple[float, float]:
    """Hard-render IoUs (visible hand vs GT M_h, object vs GT amodal) at ``render_size``."""
    from easyhoi.optim.state import hard_iou
    from easyhoi.render.raster import depth_map

    sc = truth.opt_scene
    with torch.no_grad():
        h, w = sc.render_size(1.0, truth.render_size)
        cam = camera.detach().to(sc.dtype).resized(w, h)
        zh = depth_map(v_obj.to(sc.dtype), truth.model.faces, cam)
        zo = sc.object_depth(cam)
        masks = sc.masks_at(h, w)
        vis = (torch.isfinite(zh) & (zh <= zo)).to(sc.dtype)
        return hard_iou(vis, masks["hand"]), hard_iou(
            torch.isfinite(zo).to(sc.dtype), masks["amodal"]
        )


def _kp2d_px(truth: _Truth, keypoints: np.ndarray, camera) -> float:
    """Mean pixel distance of ``keypoints`` (world of ``camera``) reprojected vs the GT's."""
    with torch.no_grad():
        uv, _ = camera.detach().to(torch.float64).project(torch.as_tensor(keypoints))
    return float(np.linalg.norm(uv.numpy() - truth.keypoints_2d, axis=1).mean())


def evaluate_hand(
    truth: _Truth,
    params: HandParams,
    m: float,
    camera,
    sd_steps: int,
    simulate: bool = True,
    cone: bool = True,
) -> dict:
    """Metrics of one hand (metric object frame, ``m`` metres per object unit) vs the truth.

    Returns a dict (lengths in cm, volumes in cm^3):

    * ``mpjpe_ra_cm`` / ``mpvpe_ra_cm``: global rotation and root removed (EasyHOI's
      convention: articulation and shape only);
    * ``mpjpe_root_cm``: metric camera frame, root-aligned (the hand through ``camera`` vs the
      GT hand in the GT camera, wrist translation removed: adds the global orientation);
    * ``mpjpe_cam_cm`` / ``mpvpe_cam_cm``: metric camera frame, no alignment (adds the depth,
      which the focal length / distance ambiguity of the fitted camera dominates);
    * ``mpjpe_world_cm`` / ``mpvpe_world_cm``: world (object) frame after the GT similarity,
      no alignment (adds the object pose and metric-scale errors, including the rotation
      ambiguity of symmetric objects);
    * ``sd_own_cm``: S.D. with gravity along image down of ``camera`` itself (+y of the camera
      frame, as the paper measures a result in its camera frame), and ``gravity_angle_deg``
      between that direction and the GT camera's down that ``sd_cm`` uses: where the object is
      symmetric, the object frame's turn about its axis is not in the photo, the camera's
      rotation in that frame follows it, and the two directions part;
    * ``sd_cm`` (S.D.), ``sd_cone_cm`` (S.D. averaged over gravity tilted by
      :data:`SD_CONE_TILT_DEG` at :data:`SD_CONE_AZIMUTHS` azimuths and the untilted one:
      :func:`easyhoi.metrics.cone_displacement`, lower variance), ``iv_cm3`` (solid, 5 mm
      grid) and ``iv_obman_cm3`` (ObMan voxels), ``pen_cm`` (deepest hand vertex inside),
      ``contact_cm`` (signed distance of the closest hand vertex to the surface, < 0 inside),
      ``in_contact`` (a vertex inside or within 5 mm);
    * ``kp2d_px``: mean distance (pixels) of the 21 keypoints reprojected through ``camera`` to
      the GT keypoints in the photo;
    * ``hand_iou`` / ``object_iou``: visible hand vs the GT M_h, object vs the GT amodal mask;
    * ``scale_err_pct``: |m / true m - 1| in %.

    ``simulate=False`` returns the hand errors only (``mpjpe_*``, ``mpvpe_*``, ``kp2d_px``);
    ``cone=False`` simulates the untilted gravity only (``sd_cone_cm`` None).
    """
    from easyhoi.metrics.interaction import _signed_depths

    model = truth.model
    V, K = _hand_out(model, params)
    A, b = truth.world_from_canonical[:3, :3], truth.world_from_canonical[:3, 3]
    Vw, Kw = (V / m) @ A.T + b, (K / m) @ A.T + b
    R = camera.R.detach().double().numpy()
    t = camera.t.detach().double().numpy() * m
    Vc, Kc = V @ R.T + t, K @ R.T + t
    errors = {
        **_hand_errors(truth, K, V, truth.joints, truth.verts, Kc, Vc),
        "mpjpe_world_cm": metrics.mpjpe(Kw, truth.joints),
        "mpvpe_world_cm": metrics.mpvpe(Vw, truth.verts),
        "kp2d_px": _kp2d_px(truth, K / m, camera),
    }
    if not simulate:
        return errors
    hand = trimesh.Trimesh(V, model.faces_for(params.side).numpy(), process=False)
    obj = truth.opt_scene.watertight.copy()
    obj.apply_scale(m)
    dist, inside = _signed_depths(V, obj)  # one closest-point query for pen / contact
    signed = np.where(inside, -dist, dist)
    hand_iou, object_iou = _mask_ious(truth, torch.as_tensor(V / m), camera)
    # the cone's first direction is the untilted gravity: its entry is the published S.D.
    azimuths = SD_CONE_AZIMUTHS if cone else 0
    sd_cone, sd_per = metrics.cone_displacement(
        hand, obj, truth.gravity_obj, SD_CONE_TILT_DEG, azimuths, steps=sd_steps
    )
    own_down = R.T @ np.array([0.0, 1.0, 0.0])  # image down of this hand's own camera
    angle = _angle_deg(own_down, truth.gravity_obj)
    if angle < SAME_GRAVITY_DEG:  # the GT camera itself: the simulation above
        sd_own = float(sd_per[0])
    else:
        sim = metrics.simulation_displacement(hand, obj, steps=sd_steps, gravity_dir=own_down)
        sd_own = float(sim.displacement)
    return {
        **errors,
        "sd_cm": sd_per[0],
        "sd_own_cm": sd_own,
        "gravity_angle_deg": angle,
        "sd_cone_cm": sd_cone if cone else None,
        "iv_cm3": metrics.intersection_volume(hand, obj, method="solid"),
        "iv_obman_cm3": metrics.intersection_volume(hand, obj, method="obman"),
        "pen_cm": float(dist[inside].max() * 100.0) if inside.any() else 0.0,
        "contact_cm": float(signed.min() * 100.0),
        "in_contact": bool(inside.any() or (dist <= 0.005).any()),
        "hand_iou": hand_iou,
        "object_iou": object_iou,
        "scale_err_pct": abs(m / truth.metres_per_unit - 1.0) * 100.0,
    }


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _estimator_hand(truth: _Truth, inp) -> dict:
    """The estimator's hand (camera frame) vs the GT hand in that camera: the "HaMeR" row;
    ``detector_kp2d_px``: the 2D keypoint detector's error (``meta["keypoints2d"]``)."""
    V, K = _hand_out(truth.model, inp.hand_params)
    out = _hand_errors(truth, K, V, truth.joints_cam, truth.verts_cam, K, V)
    out["kp2d_px"] = _kp2d_px(truth, K, inp.hand_camera)
    det = inp.meta.get("keypoints2d")
    if det is not None:
        d = np.asarray(det, dtype=np.float64) - truth.keypoints_2d
        out["detector_kp2d_px"] = float(np.linalg.norm(d, axis=1).mean())
    return out


def _hand_errors(truth: _Truth, K, V, gt_joints, gt_verts, Kc, Vc) -> dict:
    """Hand errors shared by every row: rotation-aligned (``K``, ``V`` against the GT
    ``gt_joints``, ``gt_verts`` of the same frame) and in the camera (``Kc``, ``Vc``)."""
    return {
        "mpjpe_ra_cm": metrics.mpjpe(K, gt_joints, align="rotation"),
        "mpvpe_ra_cm": metrics.mpvpe(
            V, gt_verts, align="rotation", pred_root=K[0], gt_root=gt_joints[0]
        ),
        "mpjpe_root_cm": metrics.mpjpe(Kc, truth.joints_cam, align="root"),
        "mpjpe_cam_cm": metrics.mpjpe(Kc, truth.joints_cam),
        "mpvpe_cam_cm": metrics.mpvpe(Vc, truth.verts_cam),
    }


def gt_hand_state(scene, inp):
    """The GT hand as a result would hold it: ``(params, m, camera)`` in the input's frames.

    ``params`` in the metric object frame, ``m`` the true metres per object unit, ``camera``
    the GT camera acting on object units (used for the "ground truth" reference row and tests).
    """
    from easyhoi.structures import Camera
    from easyhoi.synth.perturb import transform_hand

    M = np.asarray(inp.meta["gt"]["canonical_from_world"], float)
    s = float(np.linalg.norm(M[:3, 0]))
    Rc, c = M[:3, :3] / s, M[:3, 3]  # x_can = s Rc x + c
    gt = scene.hand_params.to(torch.float64)
    params = transform_hand(gt, Rc, c / s, scene.hand_model)  # x_metric = x_can / s = Rc x + c / s
    cam = scene.camera
    R = cam.R.double().numpy() @ Rc.T
    t = s * (cam.t.double().numpy() - R @ (c / s))
    camera = Camera(cam.K.clone(), torch.as_tensor(R), torch.as_tensor(t), cam.width, cam.height)
    return params, 1.0 / s, camera


def refine_from_contact(inp, result, cfg: OptimConfig, opt_scene=None):
    """Re-run stage 3 from ``result``'s contact snapshot with ``cfg`` (seeded like optimize).

    Returns the refined :class:`HandParams` (metric object frame) and the metric scale they
    belong to (the push-out may change it).
    """
    from easyhoi.optim.refine import fit_refine
    from easyhoi.optim.state import Scene as OptScene

    contact = next(s for s in result.stages if s.name == "contact")
    if opt_scene is None:
        from easyhoi.hand import load_hand_model

        opt_scene = OptScene.from_input(inp, load_hand_model(inp.hand_model), cfg.torch_dtype)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        theta0 = inp.hand_params.pose.to(opt_scene.dtype)
        params, res = fit_refine(
            opt_scene,
            contact.hand_params,
            float(contact.metric_scale),
            contact.camera,
            cfg.refine,
            cfg,
            theta0=theta0,
        )
    return params, float(res.metric_scale)


def _object_quality(inp, m: float, truth: _Truth, gt_mesh, n: int) -> dict:
    """C.D. / F-scores of the input object at metric scale ``m`` vs the GT object (world)."""
    A = truth.world_from_canonical[:3, :3]
    R = A / np.linalg.norm(A[:, 0])
    v = np.asarray(inp.object_mesh.vertices) * m @ R.T + truth.world_from_canonical[:3, 3]
    pred = trimesh.Trimesh(v, np.asarray(inp.object_mesh.faces), process=False)
    out = {}
    for align in ("translation_scale", "none"):
        r = metrics.chamfer_fscore(pred, gt_mesh, n_samples=n, align=align)
        out[align] = {"cd": r.chamfer, "f5": r.fscore[5.0], "f10": r.fscore[10.0]}
    return out


def _stage_metrics(truth, result, steps: int, simulate: bool = True, cone: bool = True) -> dict:
    """:func:`evaluate_hand` of every stage snapshot of ``result``."""
    out = {}
    for st in result.stages:
        cam = st.camera if st.camera is not None else result.camera
        out[st.name] = evaluate_hand(
            truth, st.hand_params, float(st.metric_scale), cam, steps, simulate, cone
        )
    return out
