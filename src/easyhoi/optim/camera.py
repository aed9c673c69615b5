"""Stage 1, camera setup: fit the object camera so the object's silhouette matches M^_o.

Parameterisation (8 DoF, as the reference implementation): around an initial camera
``(f0, R0, t0)`` the stage optimizes

- ``log_f`` (2,): ``fx = f0 exp(log_f[0])``, ``fy = f0 exp(log_f[1])`` (principal point fixed at
  the image centre); a step of lr = 1e-2 changes the focal by 1 %; with ``square_pixels`` one
  shared value (fx = fy, 7 DoF);
- ``r`` (3,): axis-angle residual, ``R = Rot(r) R0``, applied about the OBJECT's centre ``c`` so
  a rotation step does not swing the object across the image;
- ``delta`` (3,): translation residual in units of the object's extent,
  ``t = t0 + R0 c - R c + extent * delta`` (a step of lr moves the object by 1 % of its size,
  the step size of the reference's raw translation for a unit-size object at distance 4.5).

Loss: ``iou_weight * soft_iou(S, M^_o)``, plus ``sinkhorn_weight * sinkhorn(S, M^_o)`` on a coarse
grid while the masks barely overlap (IoU loss above :data:`SINKHORN_GATE`, where the IoU alone
has vanishing gradients). Adam; coarse-to-fine phases (``resolution_schedule``) share
``max_iters``. A phase ends at ``stop_loss`` (IoU term), at ``patience`` or at its share of
iterations; its best state (lowest IoU loss) seeds the next phase and the last phase's best is
returned, unless the starting camera's sharp silhouette (the mesh's z-buffer) overlaps M^_o more
at the last phase's resolution: the blurred silhouette's optimum is not the sharp one's, and a
start that already fits (an object mesh built from M^_o itself, placed by its box) is kept
(``extra["kept_start"]``). A start whose sharp silhouette has IoU >= ``1 - stop_loss`` there
runs no iteration at all (stop reason ``"stop_loss"``). The camera returned is then moved along
the ray through the object's centre to the distance whose sharp silhouette fits best
(:func:`sharpen_depth`): the soft silhouette is wider than the mesh's, so the IoU fit leaves the
object a few per cent too small.

Initialisation (``init_from_masks``): for each candidate rotation (``init_rotations``, see
:func:`candidate_rotations`) the distance and the lateral offset are solved so that the
projected bounding box of the object matches the bounding box of M^_o (same centre, same area)
at the focal of ``init_fov_deg``; the candidate with the lowest soft IoU loss at the first
phase's resolution wins, a later one only when it is lower by more than
:data:`CANDIDATE_MARGIN` (near-ties keep the earlier candidate: the canonical view is preferred).
``"yaw"`` assumes the mesh's canonical frame roughly faces the camera (x right, y down, z away,
as the silhouette reconstructor outputs) and tries 4 yaws about its y axis; ``"cube"`` tries the
24 rotations that map the canonical axes onto the camera's axes (any mesh frame, e.g. a scan:
every rotation is within 62.8 degrees of one of them). Without ``init_from_masks`` the camera
looks at the object's centre from ``init_distance`` along +z (the reference implementation's
InstantMesh setup).
"""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
import torch

from easyhoi.config import CameraStageConfig, OptimConfig
from easyhoi.errors import OptimizationError
from easyhoi.geometry.masks import mask_box
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hoi import StageResult
from easyhoi.optim.adam import Adam
from easyhoi.optim.loop import StageLoop, early_stop, restore, run_phases, snapshot
from easyhoi.optim.losses import sinkhorn_mask_loss, soft_iou_loss
from easyhoi.optim.state import SILHOUETTE_SIGMA, Scene, hard_iou
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import soft_silhouette
from easyhoi.structures import Camera

__all__ = [
    "CANDIDATE_MARGIN",
    "CANDIDATE_YAWS",
    "SINKHORN_GATE",
    "candidate_rotations",
    "fit_box",
    "fit_camera",
    "initial_camera",
]

#: The Sinkhorn term is added while the soft IoU loss is above this value (masks barely
#: overlap); below it the IoU gradient suffices and the (costly) term is skipped.
SINKHORN_GATE = 0.5

#: Candidate yaw angles (degrees, about the canonical y axis) of ``init_rotations="yaw"``.
CANDIDATE_YAWS = (0.0, 90.0, 180.0, 270.0)

#: A later candidate rotation replaces the best one only if its soft IoU loss is lower by more
#: than this: near-ties (a cylinder turned about its axis) keep the earlier, canonical view.
CANDIDATE_MARGIN = 0.02

# A focal scaled by more than e^20 (about 5e8) is a diverged step, not a camera: the cameras the
# stage builds are not re-validated per iteration, so this bound keeps divergence a named error.
MAX_LOG_FOCAL = 20.0

#: Fixed-point iterations of :func:`fit_box`.
BOX_FIT_ITERS = 8


def fit_box(
    verts: np.ndarray,
    R: np.ndarray,
    focal: float,
    principal: tuple[float, float],
    box: np.ndarray,
    center: np.ndarray,
    extreme_ids: np.ndarray | None = None,
) -> np.ndarray:
    """Translation placing the object so its projected box matches ``box``.

    Args:
        verts: (V, 3) object vertices (object units).
        R: (3, 3) camera rotation.
        focal: float, pixels (fx = fy).
        principal: (cx, cy) pixels.
        box: (4,) target box ``u0, v0, u1, v1`` in pixels.
        center: (3,) object centre.
        extreme_ids: (K,) indices of the vertices that can be extreme (those of the convex
            hull, :func:`hull_vertex_ids`), or None for all. The same result: every vertex is
            used for the mean depth, and the box of the projected points, the extremes of
            ``x / z`` and ``y / z`` (with ``z > 0``) and of ``x``, ``y`` and ``z``, lies at
            vertices of the hull; where a point is at or behind the camera plane the iteration
            uses every vertex.

    Returns:
        (3,) ``t`` with ``x_cam = R x + t``: same box centre and area after a few fixed-point
        iterations (depth from the area ratio, lateral shift from the centre offset).
    """
    X_all = (verts - center) @ R.T
    X = X_all if extreme_ids is None else X_all[extreme_ids]
    mean_z = X_all[:, 2].mean()
    principal = np.asarray(principal)
    bw, bh = max(box[2] - box[0], 1.0), max(box[3] - box[1], 1.0)
    ext = np.ptp(X[:, :2], axis=0).clip(1e-12)
    z = focal * math.sqrt(ext[0] * ext[1] / (bw * bh)) - X[:, 2].min()
    T = np.array([0.0, 0.0, max(z, 1e-6)])
    target_c = 0.5 * (box[:2] + box[2:])

    def projected(T):
        P = X + T
        if P[:, 2].min() <= 1e-9 and X is not X_all:  # the clip below bends the projection
            P = X_all + T
        return focal * P[:, :2] / P[:, 2:3].clip(1e-9) + principal

    for _ in range(BOX_FIT_ITERS):
        pw, ph = np.ptp(projected(T), axis=0).clip(1e-9)
        T[2] = (T[2] + mean_z) * math.sqrt(pw * ph / (bw * bh)) - mean_z
        uv = projected(T)
        pc = 0.5 * (uv.min(axis=0) + uv.max(axis=0))
        T[:2] += (target_c - pc) * (T[2] + mean_z) / focal
    return T - R @ center


def hull_vertex_ids(verts: np.ndarray) -> np.ndarray | None:
    """Indices of the points of ``verts`` (V, 3) on its convex hull: the hull's vertices and
    the points within qhull's tolerance of a facet (``Qc``), which a rounding error could make
    extreme in some direction. None when the hull has no volume (flat or degenerate point sets:
    then every vertex is used)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(verts, qhull_options="Qc")
    except (QhullError, ValueError):
        return None
    return np.union1d(hull.vertices, hull.coplanar[:, 0]).astype(np.int64)


def _yaw(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _axes_label(R: np.ndarray) -> str:
    """Where the camera's x, y, z axes come from, e.g. ``"+x+y+z"`` (identity), ``"-z+y+x"``."""
    axes = np.argmax(np.abs(R), axis=1)
    return "".join(("+" if R[i, a] > 0 else "-") + "xyz"[a] for i, a in enumerate(axes))


def candidate_rotations(kind: str) -> list[tuple[str, np.ndarray]]:
    """Camera rotations tried by the mask-box initialisation, canonical view first.

    ``"yaw"``: :data:`CANDIDATE_YAWS` about the canonical y axis, labelled ``"yaw 90"``.
    ``"cube"``: the 24 proper rotations whose rows are signed canonical axes (the yaws first,
    in the same order, then the rest in a fixed order), labelled by :func:`_axes_label`.
    """
    yaws = [(f"yaw {y:g}", _yaw(y)) for y in CANDIDATE_YAWS]
    if kind == "yaw":
        return yaws
    out = [(_axes_label(R), np.round(R)) for _, R in yaws]
    seen = {lab for lab, _ in out}
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            R[[0, 1, 2], list(perm)] = signs
            label = _axes_label(R)
            if np.linalg.det(R) > 0 and label not in seen:
                seen.add(label)
                out.append((label, R))
    return out


def initial_camera(
    scene: Scene,
    cfg: CameraStageConfig,
    amodal_mask: np.ndarray,
    render_size: int,
    principal: tuple[float, float] | None = None,
    fov_height: float | None = None,
) -> tuple[Camera, dict]:
    """The stage's starting camera (full image size) and a JSON-ready note of how it was chosen.

    See the module docstring; ``render_size`` and the first phase fraction set the resolution
    at which candidates are compared. ``principal`` (default: the image centre) and
    ``fov_height`` (the pixel height the field of view spans, default the image's) describe the
    photo when the scene's image is a window of it (:mod:`easyhoi.optim.window`): the camera is
    then the one the whole photo would start from, cropped.
    """
    H, W = scene.image_size
    focal = 0.5 * (fov_height or H) / math.tan(math.radians(cfg.init_fov_deg) / 2.0)
    principal = (W / 2.0, H / 2.0) if principal is None else tuple(map(float, principal))
    verts = scene.object_verts.detach().double().cpu().numpy()
    c = scene.center.detach().double().cpu().numpy()
    dtype = scene.dtype
    if not cfg.init_from_masks:
        t = np.array([0.0, 0.0, cfg.init_distance]) - c
        cam = Camera.from_focal(focal, W, H, R=np.eye(3), t=t, principal=principal,
                                dtype=dtype, device=scene.device)  # fmt: skip
        return cam, {"init": "default", "distance": cfg.init_distance}
    box = np.asarray(mask_box(amodal_mask), dtype=np.float64)
    h, w = scene.render_size(cfg.resolution_schedule[0], render_size)
    target = scene.masks_at(h, w)["amodal"]
    best, notes = None, []
    extreme_ids = hull_vertex_ids(verts)
    for label, R in candidate_rotations(cfg.init_rotations):
        t = fit_box(verts, R, focal, principal, box, c, extreme_ids)
        cam = Camera.from_focal(focal, W, H, R=R, t=t, principal=principal, dtype=dtype,
                                device=scene.device)  # fmt: skip
        with torch.no_grad():
            sil = soft_silhouette(
                scene.object_verts, scene.object_faces, cam.resized(w, h), SILHOUETTE_SIGMA
            )
            loss = float(soft_iou_loss(sil, target))
        notes.append({"rotation": label, "iou_loss": loss})
        if best is None or loss < best[0] - CANDIDATE_MARGIN:
            best = (loss, cam, label)
    return best[1], {"init": "mask_box", "rotation": best[2], "candidates": notes}


#: Distance factors tried by :func:`sharpen_depth` (the object's projected size scales by their
#: inverse): 1 % steps within +-8 %.
DEPTH_FACTORS = tuple(float(f) for f in np.round(np.linspace(0.92, 1.08, 17), 4))


def sharp_iou(scene: Scene, camera: Camera, h: int, w: int, target: torch.Tensor) -> float:
    """IoU of the object's hard silhouette (the mesh's z-buffer) at ``h`` x ``w`` with
    ``target`` (thresholded at 0.5)."""
    z = depth_map(scene.object_verts, scene.object_faces, camera.resized(w, h))
    return hard_iou(torch.isfinite(z).to(target.dtype), target)


def sharpen_depth(
    scene: Scene, camera: Camera, h: int, w: int, target: torch.Tensor
) -> tuple[Camera, float, float]:
    """``camera`` moved along the ray through the object's centre to the distance whose hard
    silhouette best matches ``target`` (module docs): (camera, its IoU, the distance factor;
    1 on ties)."""
    c = camera.R @ scene.center.to(camera.R.dtype) + camera.t  # the centre in camera space
    best = None
    for f in sorted(DEPTH_FACTORS, key=lambda f: abs(f - 1.0)):
        cam = Camera._trusted(camera.K, camera.R, camera.t + (f - 1.0) * c, camera.width,
                              camera.height)  # fmt: skip
        iou = sharp_iou(scene, cam, h, w, target)
        if best is None or iou > best[1]:
            best = (cam, iou, f)
    return best


class _CameraParams:
    """Residual parameters around an initial camera (see the module docstring)."""

    def __init__(
        self,
        cam0: Camera,
        center: torch.Tensor,
        extent: float,
        optimise_focal: bool,
        square_pixels: bool = False,
    ):
        dt, dev = cam0.K.dtype, cam0.K.device
        self.cam0 = cam0.detach()
        self.center = center.to(dt)
        self.extent = float(extent)
        n_focal = 1 if square_pixels else 2  # one log-focal shared by both axes, or one each
        self.log_f = torch.zeros(n_focal, dtype=dt, device=dev, requires_grad=optimise_focal)
        self.r = torch.zeros(3, dtype=dt, device=dev, requires_grad=True)
        self.delta = torch.zeros(3, dtype=dt, device=dev, requires_grad=True)

    def tensors(self) -> list[torch.Tensor]:
        return [p for p in (self.log_f, self.r, self.delta) if p.requires_grad]

    def camera(self) -> Camera:
        c0 = self.cam0
        self._check_finite()
        f0 = c0.K.diagonal()[:2]
        df = f0 * torch.expm1(self.log_f.expand(2))
        K = c0.K + torch.diag(torch.cat([df, df.new_zeros(1)]))
        R = axis_angle_to_matrix(self.r) @ c0.R
        t = c0.t + c0.R @ self.center - R @ self.center + self.extent * self.delta
        # valid by construction (focals f0 * exp(log_f) > 0, a rotation, the size of a validated
        # camera), so not checked again every iteration; non-finite values surface as a
        # non-finite loss, which the stage loop reports
        return Camera._trusted(K, R, t, c0.width, c0.height)

    def _check_finite(self) -> None:
        """Raise :class:`OptimizationError` when a step has left the space of cameras."""
        lf = self.log_f.detach()
        ok = bool(torch.isfinite(self.r.detach()).all() & torch.isfinite(self.delta.detach()).all())
        if not ok or not bool((lf.abs() <= MAX_LOG_FOCAL).all()):
            raise OptimizationError(
                "stage 'camera': the camera diverged (focal scale exp("
                f"{lf.tolist()}), rotation/translation finite: {ok}); try a smaller learning rate"
            )

    def state(self) -> tuple[torch.Tensor, ...]:
        return snapshot((self.log_f, self.r, self.delta))

    def load(self, state) -> None:
        restore((self.log_f, self.r, self.delta), state)


def fit_camera(
    scene: Scene,
    cam0: Camera,
    cfg: CameraStageConfig,
    optim_cfg: OptimConfig,
    progress=None,
) -> tuple[Camera, StageResult]:
    """Run stage 1 from ``cam0``.

    Args:
        scene: Scene
        cam0 (Camera): Initial object camera at the full image size (:func:`initial_camera`).
        cfg: CameraStageConfig
        optim_cfg (OptimConfig): For ``render_size`` and ``history_every``.
        progress (callable or None): ``progress("camera", iteration, max_iters, terms)``.

    Returns:
        camera (Camera): Fitted camera (full image size, detached).
        result (StageResult): History (``iou``, ``sinkhorn``, ``total`` per recorded iteration),
            iterations, stop reason, and ``extra`` with the final hard IoU at the last resolution.
    """
    start = time.perf_counter()
    params = _CameraParams(cam0, scene.center, scene.extent, cfg.optimise_focal, cfg.square_pixels)
    loop = StageLoop("camera", cfg.max_iters, optim_cfg.history_every, progress)
    opt = Adam(params.tensors(), lr=cfg.lr)

    def begin(frac):
        h, w = scene.render_size(frac, optim_cfg.render_size)
        return h, w, scene.masks_at(h, w)["amodal"]

    def silhouette(phase):
        h, w, _ = phase.context
        cam = params.camera().resized(w, h)
        return soft_silhouette(scene.object_verts, scene.object_faces, cam, SILHOUETTE_SIGMA)

    def step(phase, it):
        target = phase.context[2]
        sil = silhouette(phase)
        iou = soft_iou_loss(sil, target)
        total = cfg.iou_weight * iou
        iou_v = float(iou.detach())
        terms = {"iou": iou_v}
        if cfg.use_sinkhorn and cfg.sinkhorn_weight > 0 and iou_v > SINKHORN_GATE:
            sk = sinkhorn_mask_loss(
                sil, target, cfg.sinkhorn_grid, cfg.sinkhorn_blur, cfg.sinkhorn_scaling
            )
            total = total + cfg.sinkhorn_weight * sk
            terms["sinkhorn"] = float(sk.detach())
        total_v = float(total.detach())
        terms["total"] = total_v
        loop.record(it, terms)
        loop.offer(iou_v, params.state(), it)
        return total, early_stop(iou_v, cfg.stop_loss, phase.patience, total_v)

    # the finest resolution, where the start's sharp silhouette is judged
    h, w, target = begin(cfg.resolution_schedule[-1])
    with torch.no_grad():
        start_iou = sharp_iou(scene, cam0, h, w, target)
    if start_iou >= 1.0 - cfg.stop_loss:  # the start already fits: no iteration (module docs)
        it, stop_reason, kept_start = 0, "stop_loss", True
        with torch.no_grad():
            camera, final_iou, factor = sharpen_depth(scene, cam0.detach(), h, w, target)
    else:
        it, stop_reason, last = run_phases(
            loop, cfg.resolution_schedule, cfg.max_iters, opt, (cfg.patience, cfg.min_delta),
            begin, step, params.load,
        )  # fmt: skip
        h, w, target = last.context
        with torch.no_grad():
            camera = params.camera().detach()
            camera, final_iou, factor = sharpen_depth(scene, camera, h, w, target)
        # the start is kept when its mesh silhouette already fits M^_o better (module docs)
        kept_start = start_iou > final_iou
        if kept_start:
            with torch.no_grad():
                camera, final_iou, factor = sharpen_depth(scene, cam0.detach(), h, w, target)
    extra = {
        "final_mask_iou": final_iou,
        "start_mask_iou": start_iou,
        "depth_factor": factor,
        "kept_start": kept_start,
        "best_iou_loss": loop.best_score if math.isfinite(loop.best_score) else None,
        "fx": float(camera.fx),
        "fy": float(camera.fy),
    }
    result = StageResult(
        name="camera",
        camera=camera,
        losses=loop.history,
        seconds=time.perf_counter() - start,
        iterations=it,
        stop_reason=stop_reason,
        extra=extra,
    )
    return camera, result
