"""Stage 2, HOI contact alignment: place the hand in the object frame (pose, translation, scale).

State. The articulation stays the estimator's. The hand is kept in the OBJECT CAMERA's frame in
metres, ``V_cam = Rot(r) (V0 - c0) + c0 + L * delta`` (``V0``: the initial hand, ``c0`` its
centroid, ``L`` its largest side, so a step of lr = 1e-2 moves it by 1 % of its size), together
with the metric scale ``m`` (metres per object unit). Object-frame vertices are
``R^T (V_cam / m - t)``. The projection of the hand depends only on ``V_cam``; ``m`` moves the
hand along the camera rays (the depth relative to the object, which the image does not fix).

Initialisation from the image evidence (:func:`initial_hand`): the estimator's hand is moved to
the object camera so that its centroid keeps its pixel and its apparent size (depth scaled by
the ratio of focal lengths); ``m`` is the median ratio of the hand's metric depth to the
object's depth (object units) over the pixels where the rendered hand overlaps M^_o, taking the
object's FRONT surface where M_h shows the hand (the hand is in front there) and its BACK
surface (farthest of ``peel_layers`` hits) where the hand is hidden: the hand is put at the
depth where it meets the object in the photo (not at the object's centre). That depth is then
refined by :func:`scan_scale` (41 depths from 1/2 to 2 times it, scored by the hand-mask IoU
plus a touching term: the closest vertex on the surface, or with ``scan_band`` > 0 the
contact zones on the surface).

Loop (Adam, coarse-to-fine phases sharing ``max_iters``):

(a) mask-constrained optimization of ``r`` and ``delta``: soft IoU between the VISIBLE rendered
    hand (occluded by the object) and M_h, plus ``rotation_prior_weight * ||r||^2`` (keeps the
    estimator's rotation relative to the camera; 0 in the paper preset), plus, with
    ``keypoint_weight`` > 0, the robust keypoint and drift terms of stage 3
    (:mod:`easyhoi.optim.hand_terms`) on the rigid hand's reprojected keypoints against the
    detector's: a hand mask that is wrong in places (a sleeve, a shadow, a finger lost to the
    object) pulls the rigid hand off where the detector saw it, and only where the keypoints
    leave it free does the mask move it (0 in the paper preset: the mask alone);
(b) at the iterations ``register_at``: first the depth along the rays is re-chosen by
    :func:`scan_scale` (photo occlusions + touching), then contact registration
    (:func:`register_contacts`):
    M_front = M^_o minus M_o, M_back = M^_h minus M_h (M^_h rendered from the current hand),
    restricted to M^_o (hidden BY THE OBJECT: pixels where the current hand merely misses M_h
    would otherwise pull the registration); depth peeling (``peel_layers``) along the rays
    through those pixels; object: nearest hit for front pixels, farthest for back pixels;
    hand: the same among hits on palmar faces; only rays that meet both surfaces count; an
    iterative translation-only ICP (:func:`easyhoi.geometry.icp.icp`) of the hand points onto the
    object points gives ``D`` (object frame). It is applied so that the hand's contact centroid
    ``q`` moves to ``q + D``: the depth component as a change of ``m`` (a scaling about the
    camera centre, which keeps the hand's projection and so the mask fit), the image-plane
    remainder as a translation (with ``optimise_scale=False``: all of it as a translation).

Best state: the states from the first registration on compete (before it the depth is not
yet aligned), including the state right after each depth scan (before its ICP move, which can
be biased where the two surfaces differ in shape, e.g. a flat palm behind a cylinder); the
score is ``IoU loss + rotation prior + keypoint terms + touching term``: by default the contact
distance ``|min_v d(v)|`` over the hand vertices in normalised object units (0 when the hand touches
the surface without penetrating it); with ``score_band`` the depth scan's contact-band term
(:func:`scan_scale`), so that the stage and its scans judge depth by the same criterion. The
closest-vertex distance favours the rigid hand whose single deepest vertex grazes the surface:
with the estimator's articulation (about 1 cm off) that hand is backed off the object, its
fingers no longer on it. Stopping: IoU loss < ``stop_loss`` once every registration
that fits under ``max_iters`` ran, or ``patience`` iterations without improvement after the last
registration, or ``max_iters``.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch

from easyhoi.config import ContactStageConfig, OptimConfig
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hoi import HOIInput, StageResult
from easyhoi.optim.adam import Adam
from easyhoi.optim.hand_terms import photo_keypoint_terms
from easyhoi.optim.loop import StageLoop, early_stop, run_phases
from easyhoi.optim.losses import soft_iou_loss
from easyhoi.optim.placement import camera_hand_to_object, hand_in_camera, move_hand, rest_wrist
from easyhoi.optim.registration import register_contacts
from easyhoi.optim.state import Scene, hard_iou
from easyhoi.render.raster import depth_map, rasterize
from easyhoi.structures import Camera, HandParams

logger = logging.getLogger(__name__)

__all__ = ["ContactState", "fit_contact", "initial_hand", "scan_scale"]

#: Factors of the initial metric scale tried by :func:`scan_scale` (log-spaced, 1/2 to 2).
SCALE_SCAN = tuple(float(x) for x in np.geomspace(0.5, 2.0, 41))
#: Bounds of the metric-scale change one registration may apply (guards degenerate ICP).
MAX_SCALE_STEP = 2.0


def _origin_camera(camera: Camera) -> Camera:
    """The same intrinsics with identity extrinsics (to work in the camera's own frame)."""
    dt, dev = camera.K.dtype, camera.K.device
    return Camera(camera.K.detach(), torch.eye(3, dtype=dt, device=dev),
                  torch.zeros(3, dtype=dt, device=dev),
                  camera.width, camera.height)  # fmt: skip


class ContactState:
    """The stage's variables (see the module docstring) and conversions."""

    def __init__(self, scene: Scene, params_cam: HandParams, camera: Camera, metric_scale: float):
        dt = scene.dtype
        self.scene = scene
        self.camera = camera.detach().to(dt)
        self._intrinsics = _origin_camera(self.camera)  # projects camera-frame points
        self.params_cam = params_cam.detach().to(dtype=dt)
        with torch.no_grad():
            out = scene.hand_model(self.params_cam)
            self.v0 = out.vertices[0]
            self.k0 = out.keypoints[0]
        self.c0 = self.v0.mean(0)
        self.L = float((self.v0.max(0).values - self.v0.min(0).values).max())
        self.r = torch.zeros(3, dtype=dt, device=scene.device, requires_grad=True)
        self.delta = torch.zeros(3, dtype=dt, device=scene.device, requires_grad=True)
        self.m = float(metric_scale)

    def verts_cam(self) -> torch.Tensor:
        """(V, 3) hand vertices in the object camera's frame, metres."""
        return self._moved(self.v0)

    def _moved(self, pts: torch.Tensor) -> torch.Tensor:
        """Camera-frame points of the start hand ``pts`` moved by the rigid ``r`` and ``delta``."""
        Rr = axis_angle_to_matrix(self.r)
        return (pts - self.c0) @ Rr.T + self.c0 + self.L * self.delta

    def keypoints_uv(self, width: int, height: int) -> torch.Tensor:
        """(21, 2) the hand's keypoints projected into a ``width`` x ``height`` photo. The metric
        scale moves the hand along the camera rays, so it does not change them."""
        return self._intrinsics.resized(width, height).project(self._moved(self.k0))[0]

    def verts_obj(self) -> torch.Tensor:
        """(V, 3) hand vertices in the object frame, object units."""
        return (self.verts_cam() / self.m - self.camera.t) @ self.camera.R

    def state(self):
        return (self.r.detach().clone(), self.delta.detach().clone(), self.m)

    def load(self, state) -> None:
        with torch.no_grad():
            self.r.copy_(state[0])
            self.delta.copy_(state[1])
        self.m = float(state[2])

    def hand_params(self) -> HandParams:
        """Current hand in the metric object frame."""
        with torch.no_grad():
            Rr = axis_angle_to_matrix(self.r)
            t = self.c0 - Rr @ self.c0 + self.L * self.delta
            wrist = rest_wrist(self.scene.hand_model, self.params_cam.betas)
            p_cam = move_hand(self.params_cam, Rr, t, wrist.to(Rr.dtype))
            return camera_hand_to_object(p_cam, self.camera, self.m, self.scene.hand_model)

    def apply_translation(
        self, D: np.ndarray, anchor: np.ndarray, use_scale: bool, depth_only: bool = False
    ) -> dict:
        """Move the hand so the object-frame point ``anchor`` goes to ``anchor + D``; with
        ``depth_only`` only the depth part (a change of ``m``): the image-plane part is left to
        the masks, which see it, and the hand stays on its silhouette."""
        R = self.camera.R.detach().double().cpu().numpy()
        t = self.camera.t.detach().double().cpu().numpy()
        q = R @ anchor + t
        q_new = R @ (anchor + D) + t
        k = 1.0
        if use_scale and q[2] > 0 and q_new[2] > 0:
            k = float(np.clip(q_new[2] / q[2], 1.0 / MAX_SCALE_STEP, MAX_SCALE_STEP))
        self.m = self.m / k
        shift = np.zeros(3) if depth_only else (q_new - k * q) * self.m  # metres, camera frame
        with torch.no_grad():
            self.delta += torch.as_tensor(shift / self.L, dtype=self.delta.dtype,
                                          device=self.delta.device)  # fmt: skip
        return {"scale_factor": 1.0 / k, "shift_m": float(np.linalg.norm(shift))}


def _touch(scene: Scene, verts_obj: torch.Tensor, sdf_resolution: int, band: float) -> float:
    """Touching term of the depth scan and the stage's score (see :func:`scan_scale`)."""
    return float(_touch_batch(scene, verts_obj[None], sdf_resolution, band)[0])


def _touch_batch(
    scene: Scene, verts_obj: torch.Tensor, sdf_resolution: int, band: float
) -> torch.Tensor:
    """:func:`_touch` of each of ``B`` hands, ``verts_obj`` (B, V, 3): a (B,) tensor, one SDF
    lookup for all of them."""
    with torch.no_grad():
        # the band term reads the contact zones alone, so only they are looked up (per point)
        pts = verts_obj[:, scene.regions.contact_vertices] if band > 0 else verts_obj
        B, V = pts.shape[:2]
        d = scene.sdf(pts.reshape(-1, 3), sdf_resolution).reshape(B, V)
        if band > 0:
            near = d.abs()
            # no contact zone in the band: the band term is flat, so the closest one's distance
            # beyond the band tells a hand resting near the object from one far off it
            beyond = (near.min(dim=1).values - band).clamp_min(0.0)
            return (near.clamp_max(band).mean(dim=1) + beyond) / band
        return d.min(dim=1).values.abs()


def scan_scale(
    scene: Scene,
    verts_cam: torch.Tensor,
    camera: Camera,
    m0: float,
    sdf_resolution: int,
    render_size: int,
    tie_margin: float = 0.0,
    band: float = 0.0,
    factors: tuple[float, ...] = SCALE_SCAN,
) -> tuple[float, float]:
    """1D search of the metric scale along the camera rays around ``m0``.

    Every candidate ``m`` in :data:`SCALE_SCAN` times ``m0`` keeps the hand's projection and
    changes only its depth relative to the object (and so the hand's size relative to it).
    Score: ``(1 - IoU(visible hand, M_h))`` (hard occlusion at half ``render_size``) plus a
    touching term, d the object SDF in normalised object units: with ``band = 0``,
    ``|min_v d(v)|`` (some hand vertex on the surface); with ``band > 0``, the mean over the
    contact-zone vertices of ``min(|d(v)|, band) / band`` (the palmar contact zones lie on the
    surface: too shallow they float, too deep they sink in; one touching fingertip is not
    enough), plus, when no contact-zone vertex lies within the band, the closest one's distance
    beyond it in bands (the band term alone is flat there and cannot tell a hand resting near
    the object from one far off it). The depth where the photo's occlusions hold and the hand
    grasps the surface. Where the photo cannot tell depths apart (the hand beside the object
    touches it at several depths), candidates within ``tie_margin`` of the best score tie and
    the one nearest ``m0`` (smallest ``|log(m / m0)|``) wins.

    Args:
        verts_cam: (V, 3) hand vertices in the object camera frame, metres.
        camera: object camera (full image size).
        tie_margin: float, score difference that counts as a tie (0: the best score).
        band: float, width of the contact band (normalised object units; 0: closest vertex).
        factors: the candidate factors of ``m0`` (default :data:`SCALE_SCAN`).

    Returns:
        (m, score) of the chosen candidate.
    """
    h, w = scene.render_size(0.5, render_size)
    cam = camera.detach().to(scene.dtype).resized(w, h)
    target = scene.masks_at(h, w)["hand"] > 0.5
    zo = scene.object_depth(cam)
    R, t = cam.R, cam.t
    scored = []
    with torch.no_grad():
        vc = verts_cam.to(scene.dtype)
        ms = [m0 * float(f) for f in factors]
        # a candidate scales the hand about the camera centre: the same projection, every depth
        # times m0 / m, so one z-buffer serves all of them
        zh0 = depth_map((vc / m0 - t) @ R, scene.hand_model.faces, cam)
        touch = _touch_batch(scene, torch.stack([(vc / m - t) @ R for m in ms]), sdf_resolution,
                             band).tolist()  # fmt: skip
        for f, m, tch in zip(factors, ms, touch, strict=True):
            zh = zh0 * (m0 / m)
            vis = torch.isfinite(zh) & (zh <= zo)
            union = int((vis | target).sum())
            iou = float((vis & target).sum()) / union if union else 0.0
            score = (1.0 - iou) + tch
            scored.append((score, abs(math.log(f)), m))
    best = min(s for s, _, _ in scored)
    score, _, m = min((c for c in scored if c[0] <= best + tie_margin), key=lambda c: c[1])
    return m, score


def initial_hand(
    scene: Scene,
    inp: HOIInput,
    camera: Camera,
    render_size: int,
    cfg: ContactStageConfig | None = None,
    sdf_resolution: int = 48,
) -> tuple[HandParams, float, dict]:
    """Place the estimator's hand in the object camera (see the module docstring).

    ``cfg`` gives ``peel_layers``, ``scan_tie_margin`` and ``scan_band`` (default: the
    defaults of :class:`~easyhoi.config.ContactStageConfig`).

    Returns:
        params_cam (HandParams): Hand in the object camera's frame, metres.
        metric_scale (float): Metres per object unit.
        note (dict): JSON-ready description (overlap pixels used, depths).
    """
    cfg = ContactStageConfig() if cfg is None else cfg
    model = scene.hand_model
    dt, dev = scene.dtype, scene.device
    hand_camera = inp.hand_camera.to(dt, dev)
    p_hc = hand_in_camera(inp.hand_params.to(dtype=dt, device=dev), hand_camera, model)
    with torch.no_grad():
        c = model(p_hc).vertices[0].mean(0)
    Kh, Ko = hand_camera.K, camera.K.detach().to(dt)
    k = math.sqrt(float(Ko[0, 0] * Ko[1, 1]) / float(Kh[0, 0] * Kh[1, 1]))
    cam_h0, cam_o0 = _origin_camera(hand_camera), _origin_camera(camera.to(dt))
    uv, z = cam_h0.project(c)
    c_new = cam_o0.unproject(uv, z * k)
    p_oc = HandParams(p_hc.global_orient, p_hc.transl + (c_new - c), p_hc.pose, p_hc.betas,
                      p_hc.side)  # fmt: skip
    h, w = scene.render_size(1.0, render_size)
    with torch.no_grad():
        verts = model(p_oc).vertices[0]
        zh = depth_map(verts, model.faces, cam_o0.resized(w, h))
        layers = rasterize(scene.object_verts, scene.object_faces, camera.detach().resized(w, h),
                           num_layers=cfg.peel_layers).depth  # fmt: skip
    zo_front = layers[..., 0]
    zo_back = torch.where(torch.isfinite(layers), layers, -torch.inf).max(dim=-1).values
    masks = scene.masks_at(h, w)
    sel = torch.isfinite(zh) & torch.isfinite(zo_front) & (masks["amodal"] > 0.5)
    # where the photo shows the hand it is in front of the object (touching its front surface);
    # where the object hides it, it is behind (touching the back surface)
    zo = torch.where(masks["hand"] > 0.5, zo_front, zo_back)
    if int(sel.sum()) > 0:
        m = float(torch.median(zh[sel] / zo[sel]))
        how = "overlap_depth_ratio"
    else:
        obj_c = camera.world_to_camera(scene.center.to(camera.K.dtype)).detach()
        m = float(c_new[2]) / float(obj_c[2])
        how = "centroid_depth_ratio"
    if not (math.isfinite(m) and m > 0):
        m = 1.0
        how = "fallback_unit"
    m_overlap = m
    m, scan_score = scan_scale(
        scene, verts, camera, m, sdf_resolution, render_size, cfg.scan_tie_margin, cfg.scan_band
    )
    note = {
        "metric_scale_init": m,
        "metric_scale_overlap": m_overlap,
        "scale_from": how,
        "scan_score": scan_score,
        "overlap_pixels": int(sel.sum()),
        "focal_ratio": k,
    }
    return p_oc, m, note


def _rot_prior(state: ContactState, cfg: ContactStageConfig) -> torch.Tensor:
    """``rotation_prior_weight * ||r||^2``: the hand's rotation away from the estimator's."""
    return cfg.rotation_prior_weight * (state.r**2).sum()


def _keypoint_terms(scene: Scene, state: ContactState, cfg: ContactStageConfig) -> torch.Tensor:
    """The weighted keypoint terms of the mask fit: the detector's keypoints hold the hand where
    the photo shows it (the robust term per joint, the drift term for the hand as a whole)."""
    H, W = scene.image_size
    t = photo_keypoint_terms(state.keypoints_uv(W, H), scene.keypoints, cfg.keypoint_sigma,
                             cfg.keypoint_drift_weight > 0)  # fmt: skip
    loss = cfg.keypoint_weight * t["keypoints"]
    if "keypoint_drift" in t:
        loss = loss + cfg.keypoint_drift_weight * t["keypoint_drift"]
    return loss


def fit_contact(
    scene: Scene,
    state: ContactState,
    cfg: ContactStageConfig,
    optim_cfg: OptimConfig,
    progress=None,
) -> StageResult:
    """Run stage 2 on ``state`` (modified in place; ends at the best state).

    Returns:
        StageResult: ``hand_params`` in the metric object frame, ``metric_scale``, history (``iou``,
            ``contact_dist``, ``total``), and ``extra["registrations"]`` (one dict per
            registration).
    """
    start = time.perf_counter()
    loop = StageLoop("contact", cfg.max_iters, optim_cfg.history_every, progress)
    opt = Adam([state.r, state.delta], lr=cfg.lr)
    sdf_res = optim_cfg.refine.sdf_resolution
    due = [r for r in cfg.register_at if r < cfg.max_iters]
    registrations: list[dict] = []
    # the touching part of the score: the scan's contact band, or the closest vertex
    score_band = cfg.scan_band if cfg.score_band else 0.0
    r = cfg.rescan_range
    rescan = tuple(float(x) for x in np.geomspace(1.0 / r, r, len(SCALE_SCAN)))

    def begin(frac):
        h, w = scene.render_size(frac, optim_cfg.render_size)
        return scene.masks_at(h, w), state.camera.resized(w, h)

    def register(phase, it):
        masks, cam = phase.context
        if not registrations and not cfg.initial_competes:
            loop.reset_best()  # only aligned states (after the first) compete
        with torch.no_grad():
            m_before = state.m
            state.m, _ = scan_scale(
                scene, state.verts_cam(), state.camera, state.m, sdf_res,
                optim_cfg.render_size, cfg.rescan_tie_margin, cfg.scan_band, rescan,
            )  # fmt: skip
            v = state.verts_obj()
            _, vis, _ = scene.hand_silhouettes(v, cam)
            scan = float(soft_iou_loss(vis, masks["hand"])) + float(_rot_prior(state, cfg))
            if cfg.keypoint_weight > 0 and scene.keypoints is not None:
                scan += float(_keypoint_terms(scene, state, cfg))
            loop.offer(scan + _touch(scene, v, sdf_res, score_band), state.state(), it)
        D, anchor, info = register_contacts(scene, v, cam, masks, cfg)
        info["scan_scale_factor"] = state.m / m_before
        info["iter"] = it
        if D is not None:
            info.update(state.apply_translation(D, anchor, cfg.optimise_scale,
                                                cfg.depth_only_registration))  # fmt: skip
        info["metric_scale"] = state.m
        registrations.append(info)
        phase.patience.reset()

    def step(phase, it):
        if due and it >= due[0]:
            due.pop(0)
            register(phase, it)
        masks, cam = phase.context
        verts = state.verts_obj()
        _, visible, _ = scene.hand_silhouettes(verts, cam)
        iou = soft_iou_loss(visible, masks["hand"])
        loss = iou
        cdist = _touch(scene, verts.detach(), sdf_res, score_band)
        terms = {"iou": float(iou.detach()), "contact_dist": cdist}
        if cfg.rotation_prior_weight > 0:
            prior = _rot_prior(state, cfg)
            loss = loss + prior
            terms["rot_prior"] = float(prior.detach())
        if cfg.keypoint_weight > 0 and scene.keypoints is not None:
            kp_loss = _keypoint_terms(scene, state, cfg)
            loss = loss + kp_loss
            terms["keypoints"] = float(kp_loss.detach())
        score = float(loss.detach()) + cdist
        terms["total"] = score
        loop.record(it, terms)
        loop.offer(score, state.state(), it)
        reason = None if due else early_stop(terms["iou"], cfg.stop_loss, phase.patience, score)
        return loss, reason

    it, stop_reason, last = run_phases(
        loop, cfg.resolution_schedule, cfg.max_iters, opt, (cfg.patience, cfg.min_delta),
        begin, step, state.load, reset_best=False,
    )  # fmt: skip
    masks, cam = last.context
    with torch.no_grad():
        _, visible, _ = scene.hand_silhouettes(state.verts_obj(), cam)
        final_iou = hard_iou(visible, masks["hand"])
    with torch.no_grad():
        cdist = _touch(scene, state.verts_obj(), sdf_res, 0.0)
    extra = {
        "registrations": registrations,
        "final_mask_iou": final_iou,
        "contact_distance": cdist,
        "best_iter": loop.best_iter,
    }
    return StageResult(
        name="contact",
        hand_params=state.hand_params(),
        camera=state.camera,
        losses=loop.history,
        seconds=time.perf_counter() - start,
        iterations=it,
        metric_scale=state.m,
        stop_reason=stop_reason,
        extra=extra,
    )
