"""Stage 3, hand parameter refinement: global pose and articulation with the combined loss.

Variables (metric object frame, see :mod:`easyhoi.optim.state`): ``global_orient`` (Adam,
``lr_global``), the translation ``transl = transl_0 + (L m) delta`` with ``delta`` in normalised
object units (``L`` the object's largest side in object units; Adam, ``lr_transl`` or
``lr_global``: a step of 1e-4 moves the hand by 0.01 % of the object's size, whatever the metric
scale, as the paper's normalised object frame) and the 45 articulation parameters
(``lr_pose``); the shape and the metric scale ``m`` stay fixed during the gradient steps (the
push-out before them may change ``m``, see :func:`push_out`; its move is kept only when the
loss below is lower after it). Object-frame vertices are
``model(params).vertices / m``. The loss is::

    L = hand_mask_weight   * soft_iou(visible hand, M_h)
      + penetration_weight * (1/V) sum_v max(0, -d(v))      (d below penetration_threshold;
                             the contact zones' below pad_tolerance_m in metres if deeper)
      + contact_weight     * (K / |C|) sum_{v in C} max(0, d(v))   (C: contact zones)
                             (only d(v) < contact_max_distance, or opposition_max_distance
                              for the thumb's and index finger's C vertices; see contact_radii)
      + reg_weight         * ||theta - theta_0||_1

``K = contact_reference_count`` (115, MANO's contact-zone size): the contact sum is made
resolution independent like the mean penetration term, so the paper's weights balance the two
terms as they do for MANO whatever the hand mesh (the built-in OpenHand has |C| = 285; its raw
sum would weigh 2.5x more against the penetration mean than the paper's). For MANO
(|C| ~ 115-117) the factor is ~1, the paper's term.

with ``d`` the object SDF (trilinear lookup in an ``sdf_resolution``^3 grid) in normalised
object units (object units / the object's largest side). A term with weight 0 is not computed.
Adam over coarse-to-fine phases; each phase's lowest-loss state seeds the next; the last phase's
best state is returned. Stopping: ``patience`` or the phase's share of ``max_iters``. With
``close_gap`` a returned hand that does not touch the object is then moved along the camera rays
onto it (:mod:`easyhoi.optim.close_gap`; the metric scale changes, the projection does not), or,
when it lies beside the object in the photo, the object is moved onto it by at most a finger's
width (the returned camera moves with the hand, whose projection is kept).
"""

from __future__ import annotations

import time
from dataclasses import replace

import torch

from easyhoi.config import OptimConfig, RefineStageConfig
from easyhoi.hand.regions import DIGIT_JOINTS
from easyhoi.hoi import StageResult
from easyhoi.optim.adam import Adam
from easyhoi.optim.close_gap import close_gap, meet, moved_with_camera, rescaled_along_rays
from easyhoi.optim.hand_terms import photo_keypoint_terms, pose_prior_loss
from easyhoi.optim.loop import StageLoop, restore, run_phases, snapshot
from easyhoi.optim.losses import contact_loss, penetration_loss, pose_reg_loss, soft_iou_loss
from easyhoi.optim.state import Scene, hard_iou
from easyhoi.structures import Camera, HandParams

__all__ = [
    "PUSH_OUT_BALANCE",
    "PUSH_OUT_MAX",
    "PUSH_OUT_MIN_COS",
    "fit_refine",
    "push_out",
    "refine_terms",
]

#: :func:`push_out` stops when the depth-weighted normals cancel to below this fraction of the
#: summed depths (penetration from opposite sides: moving the whole hand cannot free it).
PUSH_OUT_BALANCE = 0.3
#: Largest total move of :func:`push_out`, normalised object units (a fifth of the object).
PUSH_OUT_MAX = 0.2
#: Smallest cosine between the way out and the camera ray used to size a move along the ray
#: (a surface seen edge-on: the depth move that frees it is long and :data:`PUSH_OUT_MAX` caps it).
PUSH_OUT_MIN_COS = 0.25


def refine_terms(
    scene: Scene,
    params: HandParams,
    metric_scale: float,
    theta0: torch.Tensor,
    cfg: RefineStageConfig,
    camera: Camera | None = None,
    masks: dict | None = None,
) -> dict:
    """The weighted loss terms of stage 3 for ``params`` (differentiable).

    Args:
        scene: Scene
        params: HandParams (batch 1), metric object frame.
        metric_scale: float, metres per object unit.
        theta0: (1, 45) estimator articulation.
        cfg: RefineStageConfig (weights, threshold, SDF resolution).
        camera: Camera at the render resolution (needed when the mask term is on).
        masks: dict from :meth:`Scene.masks_at` at that resolution.

    Returns:
        dict of str -> () tensor: the unweighted terms present (``keypoints``,
            ``keypoint_drift``, ``prior``, ``mask``,
        ``penetration``, ``contact``, ``reg``) and ``total`` (weighted sum).
    """
    out = scene.hand_model(params)
    verts = out.vertices[0] / metric_scale
    terms: dict[str, torch.Tensor] = {}
    total = verts.new_zeros(())
    kp = scene.keypoints
    if cfg.keypoint_weight > 0 and kp is not None:
        H, W = scene.image_size
        uv, _ = camera.resized(W, H).project(out.keypoints[0] / metric_scale)
        drift = cfg.keypoint_drift_weight > 0
        terms.update(photo_keypoint_terms(uv, kp, cfg.keypoint_sigma, drift))
        total = total + cfg.keypoint_weight * terms["keypoints"]
        if "keypoint_drift" in terms:
            total = total + cfg.keypoint_drift_weight * terms["keypoint_drift"]
    if cfg.prior_weight > 0:
        # the axes are the right model's: a left hand's articulation is mirrored first
        sign = [1.0, -1.0, -1.0] if params.side == "left" else [1.0] * 3
        flip = torch.tensor(sign, dtype=params.pose.dtype, device=params.pose.device).repeat(15)
        terms["prior"] = pose_prior_loss(params.pose * flip, scene.flexion_axes(),
                                         reference=theta0 * flip)  # fmt: skip
        total = total + cfg.prior_weight * terms["prior"]
    if cfg.hand_mask_weight > 0:
        _, visible, _ = scene.hand_silhouettes(verts, camera)
        terms["mask"] = soft_iou_loss(visible, masks["hand"])
        total = total + cfg.hand_mask_weight * terms["mask"]
    if cfg.penetration_weight > 0 or cfg.contact_weight > 0:
        d = scene.sdf(verts, cfg.sdf_resolution)
        if cfg.penetration_weight > 0:
            terms["penetration"] = penetration_loss(
                d, penetration_thresholds(scene, cfg, metric_scale, d)
            )
            total = total + cfg.penetration_weight * terms["penetration"]
        if cfg.contact_weight > 0:
            dc = d[scene.regions.contact_vertices]
            terms["contact"] = contact_loss(
                dc, contact_radii(scene, cfg), reference_count=cfg.contact_reference_count
            )
            total = total + cfg.contact_weight * terms["contact"]
    if cfg.reg_weight > 0:
        terms["reg"] = pose_reg_loss(params.pose, theta0)
        total = total + cfg.reg_weight * terms["reg"]
    terms["total"] = total
    return terms


def penetration_thresholds(scene: Scene, cfg: RefineStageConfig, metric_scale: float, d):
    """Per-vertex SDF below which a hand vertex counts as penetrating (normalised object
    units, like ``d``): ``cfg.penetration_threshold``, and for the contact-zone vertices the
    deeper of it and ``cfg.pad_tolerance_m`` in metres; a float when no tolerance is set."""
    if cfg.pad_tolerance_m <= 0:
        return cfg.penetration_threshold
    pad = -cfg.pad_tolerance_m / (float(metric_scale) * float(scene.extent))
    t = torch.full(d.shape[-1:], cfg.penetration_threshold, dtype=d.dtype, device=d.device)
    t[scene.regions.contact_vertices.to(d.device)] = min(pad, cfg.penetration_threshold)
    return t


def contact_radii(scene: Scene, cfg: RefineStageConfig):
    """Attraction radius of the contact term: ``contact_max_distance`` (a number or None), or
    with ``opposition_max_distance`` a (C,) tensor giving the thumb's and index finger's
    contact vertices that radius and the others ``contact_max_distance``."""
    if cfg.contact_max_distance is None or cfg.opposition_max_distance is None:
        return cfg.contact_max_distance
    regions = scene.regions
    part = regions.vertex_part[regions.contact_vertices]
    opposing = torch.as_tensor([*DIGIT_JOINTS["thumb"], *DIGIT_JOINTS["index"]], device=part.device)
    return torch.where(
        torch.isin(part, opposing),
        torch.tensor(float(cfg.opposition_max_distance), dtype=scene.dtype, device=part.device),
        torch.tensor(float(cfg.contact_max_distance), dtype=scene.dtype, device=part.device),
    )


def push_out(
    scene: Scene,
    params: HandParams,
    metric_scale: float,
    cfg: RefineStageConfig,
    camera: Camera | None = None,
    as_scale: bool = False,
) -> tuple[torch.Tensor, dict]:
    """Rigid move that takes a penetrating hand out of the object.

    Up to ``push_out_steps`` times: the vertices deeper than ``penetration_threshold`` give the
    way out (the SDF gradients at them, weighted by their depth, summed and normalised: ``n``)
    and the hand moves until the largest depth is covered along ``n``. With ``camera`` (object
    frame) the move is along the camera ray through the hand's centroid, by
    ``depth / (n . ray)`` (the ray's cosine with ``n`` floored at :data:`PUSH_OUT_MIN_COS`): a
    single photo fixes where the hand is in the image but hardly how far it is, so the depth is
    what may give; moving across the rays would shift every joint in the image. Without
    ``camera`` it moves along ``n``. Stops when nothing penetrates, when a move does not reduce
    the summed depth of the penetrating vertices (it is undone), or when the gradients cancel (a
    hand wrapped round the object: only its fingers can open), or after :data:`PUSH_OUT_MAX`
    normalised units in all (the capped move is checked like the others). The articulation is
    untouched, so a grasp that sank in as a whole (a depth or scale error) comes out without
    bending fingers.

    With ``camera`` and ``as_scale`` the move along the rays is a change of the metric scale
    instead of a translation: the object-unit hand is scaled about the camera centre by a
    factor ``k`` (``v -> eye + k (v - eye)``, the metric scale becomes ``m / k``), which is the
    same hand in the camera's metric frame: its projection is kept exactly, where a translation
    along the one ray through the centroid also changes the hand's apparent size. The step at
    the centroid is the same as for the translation.

    Returns:
        (3,) translation in object units (``as_scale``: the () factor ``k``, 1 = no move) and a
        JSON-ready note (steps, distance in normalised units).
    """
    with torch.no_grad():
        verts = scene.hand_model(params).vertices[0] / metric_scale
    ray = eye = None
    if camera is not None:
        eye = camera.center.detach().to(verts.dtype)
        ray = verts.mean(0) - eye
        dist = float(ray.norm())  # the centroid's distance from the camera, object units
        ray = ray / ray.norm().clamp_min(1e-12)
    scale = as_scale and ray is not None
    total = torch.zeros(3, dtype=verts.dtype, device=verts.device)
    steps, last, capped = 0, None, False

    def moved(t: torch.Tensor) -> torch.Tensor:
        if scale:  # t = the centroid's move along its ray: scale about the camera centre
            return eye + (verts - eye) * (1.0 + float(t @ ray) / dist)
        return verts + t

    for _ in range(cfg.push_out_steps + 1):
        v = moved(total).detach().requires_grad_(True)
        d = scene.sdf(v, cfg.sdf_resolution)
        inside = d < penetration_thresholds(scene, cfg, metric_scale, d)
        sunk = float((-d[inside]).detach().sum())
        if last is not None and sunk >= last[0]:  # the move made it worse: undo it, stop
            total, steps = last[1], steps - 1
            break
        if not bool(inside.any()) or steps == cfg.push_out_steps or capped:
            break
        last = (sunk, total)
        (grad,) = torch.autograd.grad(d[inside].sum(), v)
        depth = -d[inside].detach()
        normals = grad[inside] / grad[inside].norm(dim=1, keepdim=True).clamp_min(1e-12)
        n = (normals * depth[:, None]).sum(0)
        norm = float(n.norm())
        if norm < PUSH_OUT_BALANCE * float(depth.sum()):
            break
        step = float(depth.max()) * scene.extent
        if ray is None:
            total = total + n / norm * step
        else:
            cos = float(n @ ray) / norm
            sign = 1.0 if cos >= 0 else -1.0
            total = total + ray * (sign * step / max(abs(cos), PUSH_OUT_MIN_COS))
        steps += 1
        if float(total.norm()) > PUSH_OUT_MAX * scene.extent:
            # the capped move is the last one, but it is checked like any other (above)
            total = total * (PUSH_OUT_MAX * scene.extent / float(total.norm()))
            capped = True
    note = {"steps": steps, "distance": float(total.norm()) / scene.extent}
    if scale:
        k = 1.0 + float(total @ ray) / dist
        note["scale_factor"] = 1.0 / k
        return torch.tensor(k, dtype=verts.dtype, device=verts.device), note
    return total.detach(), note


def _accept_push(scene, p0, metric_scale, theta0, camera, cfg, optim_cfg, push):
    """The start of the gradient steps: the pushed hand when the stage's own loss (every term,
    at the first phase's render size) is lower there than at ``p0``, else ``p0``. The push-out
    judges its move by the summed depth of the penetrating vertices alone; a move along the
    camera rays also changes what the object hides of the hand (the mask term) and which pads
    lie on the surface (the contact term, within its radius), which the loss sees. Returns
    ``(translation, metric_scale)``; records ``kept`` and both losses in the push's note."""
    k_or_t, note = push
    if note["steps"] == 0:
        note["kept"] = False
        return p0.transl.clone(), metric_scale
    if cfg.push_out_scale:  # the same metric hand in the camera, the object's scale m / k
        pushed, m1 = rescaled_along_rays(p0, metric_scale, float(k_or_t), camera)
    else:
        pushed, m1 = replace(p0, transl=p0.transl + float(metric_scale) * k_or_t), metric_scale
    h, w = scene.render_size(cfg.resolution_schedule[0], optim_cfg.render_size)
    masks, cam = scene.masks_at(h, w), camera.resized(w, h)
    with torch.no_grad():
        before = float(refine_terms(scene, p0, metric_scale, theta0, cfg, cam, masks)["total"])
        after = float(refine_terms(scene, pushed, m1, theta0, cfg, cam, masks)["total"])
    note.update(kept=after < before, loss_before=before, loss_after=after)
    if after < before:
        return pushed.transl.detach().clone(), m1
    return p0.transl.clone(), metric_scale


def fit_refine(
    scene: Scene,
    params0: HandParams,
    metric_scale: float,
    camera: Camera,
    cfg: RefineStageConfig,
    optim_cfg: OptimConfig,
    theta0: torch.Tensor | None = None,
    progress=None,
) -> tuple[HandParams, StageResult]:
    """Run stage 3 from ``params0`` (metric object frame).

    Args:
        theta0 ((1, 45) or None): Articulation the regulariser pulls towards (default:
            ``params0.pose``).

    Returns:
        params: HandParams, the refined hand (metric object frame, detached).
        result: StageResult with the history of every term; its ``metric_scale`` is the one
            ``params`` belong to (changed by the push-out with ``push_out_scale``).
    """
    start = time.perf_counter()
    dt = scene.dtype
    p0 = params0.detach().to(dtype=dt)
    theta0 = (p0.pose if theta0 is None else theta0.to(dt)).detach().clone()
    go = p0.global_orient.clone().requires_grad_(cfg.optimise_global)
    camera = camera.detach().to(dt)
    push = None
    tr0 = p0.transl.clone()
    if cfg.push_out_steps > 0:
        push = push_out(scene, p0, metric_scale, cfg, camera, as_scale=cfg.push_out_scale)
        tr0, metric_scale = _accept_push(scene, p0, metric_scale, theta0, camera, cfg,
                                         optim_cfg, push)  # fmt: skip
    unit = float(scene.extent) * float(metric_scale)  # metres per normalised object unit
    delta = torch.zeros_like(tr0).requires_grad_(cfg.optimise_global)
    pose = p0.pose.clone().requires_grad_(cfg.optimise_pose)
    variables = (go, delta, pose)
    groups = []
    if cfg.optimise_global:
        groups.append({"params": [go], "lr": cfg.lr_global})
        lr_t = cfg.lr_global if cfg.lr_transl is None else cfg.lr_transl
        groups.append({"params": [delta], "lr": lr_t})
    if cfg.optimise_pose:
        groups.append({"params": [pose], "lr": cfg.lr_pose})
    opt = Adam(groups) if groups else None
    loop = StageLoop("refine", cfg.max_iters, optim_cfg.history_every, progress)
    current = lambda: p0.__class__(go, tr0 + unit * delta, pose, p0.betas, p0.side)  # noqa: E731

    phases_begun = []

    def begin(frac):
        # rigid_first: the first phase moves the hand as a whole (the articulation's step size
        # is 0), so penetration is resolved by the hand's pose before any finger bends
        if cfg.rigid_first and cfg.optimise_pose and opt is not None:
            opt.param_groups[-1]["lr"] = 0.0 if not phases_begun else cfg.lr_pose
        phases_begun.append(frac)
        h, w = scene.render_size(frac, optim_cfg.render_size)
        return scene.masks_at(h, w), camera.resized(w, h)

    def step(phase, it):
        masks, cam = phase.context
        terms = refine_terms(scene, current(), metric_scale, theta0, cfg, cam, masks)
        total = terms["total"]
        plain = {k: float(v.detach()) for k, v in terms.items()}
        loop.record(it, plain)
        loop.offer(plain["total"], snapshot(variables), it)
        if phase.patience.exhausted(plain["total"]):
            return total, "patience"
        if not total.requires_grad:
            return total, "no_active_term"
        return total, None

    it, stop_reason, last = run_phases(
        loop, cfg.resolution_schedule, cfg.max_iters, opt, (cfg.patience, cfg.min_delta),
        begin, step, lambda state: restore(variables, state),
    )  # fmt: skip
    masks, cam = last.context
    params = current().detach().clone()
    gap = None
    if cfg.close_gap:
        k, gap = close_gap(scene, params, metric_scale, camera, cfg.sdf_resolution,
                           0.5 * cfg.penetration_threshold, PUSH_OUT_MAX)  # fmt: skip
        if k != 1.0:
            params, metric_scale = rescaled_along_rays(params, metric_scale, k, camera)
        else:
            delta, gap["meet"] = meet(scene, params, metric_scale, camera, cfg.sdf_resolution,
                                      0.5 * cfg.penetration_threshold, PUSH_OUT_MAX)  # fmt: skip
            if delta is not None:
                params, camera = moved_with_camera(params, metric_scale, camera, delta)
                cam = camera.resized(cam.width, cam.height)
    with torch.no_grad():
        verts = scene.hand_model(params).vertices[0] / metric_scale
        _, visible, _ = scene.hand_silhouettes(verts, cam)
        final_iou = hard_iou(visible, masks["hand"])
    with torch.no_grad():
        final = refine_terms(scene, params, metric_scale, theta0, cfg, cam, masks)
    extra = {
        "push_out": None if push is None else push[1],
        "close_gap": gap,
        "final_mask_iou": final_iou,
        "final_terms": {k: float(v) for k, v in final.items()},
        "best_iter": loop.best_iter,
    }
    result = StageResult(
        name="refine",
        hand_params=params,
        camera=camera,
        losses=loop.history,
        seconds=time.perf_counter() - start,
        iterations=it,
        metric_scale=float(metric_scale),
        stop_reason=stop_reason,
        extra=extra,
    )
    return params, result
