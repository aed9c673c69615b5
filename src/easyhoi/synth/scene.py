"""Synthetic hand-object scenes with exact ground truth.

:func:`make_scene` builds, from one seed: an object (:mod:`easyhoi.synth.objects`), a grasp of
it (:mod:`easyhoi.synth.grasp`), a camera looking at the pair, the ground truth seen by that
camera (visible and amodal masks of both, depth, 2D/3D keypoints) and a shaded photo
(:mod:`easyhoi.synth.photo`). :meth:`SynthScene.to_hoi_input` turns a scene into the optimizer's
input with perturbations standing in for the large models (:mod:`easyhoi.synth.perturb`).

World frame = the object's metric frame (metres, the object centred on its bounding box).

Camera: a random vertical field of view of 35-55 degrees; the viewing direction is drawn around
the direction from the object to the hand (so the hand faces the camera) and the image "up" is
set so that the forearm (the wrist side of the hand) points towards the bottom of the image
(+- 60 degrees); the distance makes the pair's bounding box fill 50-70 % of the image, centred.
Views where less than 40 % of the hand or 30 % of the object is visible are redrawn (up to 6
draws, then the best is kept). With ``hold=True`` the camera is then turned about its viewing
axis (30-degree steps, nearest first) until the GT grasp holds the object under gravity along
the image's down direction (the 35-step simulation moves it at most 1 cm): photos show objects
that are held, whichever way the hand is turned; an in-plane roll leaves what is visible as is.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.render.raster import depth_map, rasterize
from easyhoi.structures import Camera, HandParams
from easyhoi.synth.grasp import GRASP_TYPES, Grasp, analyse_object, synthesize_grasp
from easyhoi.synth.objects import OBJECT_KINDS, SynthObject, make_object
from easyhoi.synth.photo import SurfaceLayer, object_albedo, shade_photo, skin_tone

_KIND_WEIGHTS = (0.25, 0.2, 0.15, 0.2, 0.2)
_GRASP_WEIGHTS = (0.5, 0.3, 0.2)
#: ``make_scene(hold=True)``: the grasp "holds" when the object moves at most this far (cm) in
#: the 35-step simulation under image-down gravity; camera rolls are tried in these steps.
HOLD_CM = 1.0
HOLD_ROLL_STEP_DEG = 30.0


@dataclass(frozen=True)
class SynthScene:
    """One synthetic hand-object image with its ground truth.

    Attributes:
        seed: int
        object (SynthObject): Object in the world frame (metres).
        grasp (Grasp): The synthesized grasp (its params are the GT hand in the world frame).
        camera (Camera): World-to-camera, OpenCV convention, float64.
        image ((H, W, 3) uint8): The photo.
        hand_mask, object_mask ((H, W) bool): Visible hand / object (hard raster, depth comparison;
            disjoint).
        hand_amodal, object_amodal ((H, W) bool): Complete silhouettes (``hand_mask <=
            hand_amodal``).
        depth ((H, W) float64): Camera z of the nearest surface, ``inf`` on the background.
        keypoints_3d ((21, 3) float64): OpenPose-order hand keypoints, world frame.
        keypoints_2d ((21, 2) float64): Their pixel coordinates.
        timings (dict): Seconds per step ("object", "grasp", "camera", "render", "photo", "total").
        hand_model (HandModel): The model the hand parameters belong to (not compared, not shown).
        gravity_sd_cm (float or None): With ``make_scene(hold=True)``: the GT grasp's simulation
            displacement (cm) under gravity along the camera's +y (image down), else None.

    The arrays are read-only.
    """

    seed: int
    object: SynthObject
    grasp: Grasp
    camera: Camera
    image: np.ndarray
    hand_mask: np.ndarray
    object_mask: np.ndarray
    hand_amodal: np.ndarray
    object_amodal: np.ndarray
    depth: np.ndarray
    keypoints_3d: np.ndarray
    keypoints_2d: np.ndarray
    timings: dict = field(default_factory=dict)
    hand_model: object = field(default=None, compare=False, repr=False)
    gravity_sd_cm: float | None = None

    def __post_init__(self):
        for name in ("image", "hand_mask", "object_mask", "hand_amodal", "object_amodal", "depth",
                     "keypoints_3d", "keypoints_2d"):  # fmt: skip
            getattr(self, name).setflags(write=False)
        if self.hand_model is None:
            object.__setattr__(self, "hand_model", _default_model())

    @property
    def hand_params(self) -> HandParams:
        """GT hand (batch 1) in the world frame, metres."""
        return self.grasp.params

    @property
    def hand_mesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.grasp.vertices, self.grasp.faces, process=False)

    @property
    def object_mesh(self) -> trimesh.Trimesh:
        return self.object.mesh

    def to_hoi_input(self, perturbation="none", seed: int | None = None, rotate=None):
        """The optimizer's input for this scene (see :func:`easyhoi.synth.perturb.make_hoi_input`).

        Args:
            perturbation (str or Perturbation): A level of
                :data:`easyhoi.synth.perturb.PERTURBATION_LEVELS` or a custom one.
            seed (int, optional): Seed of the perturbations (default: the scene's seed).
            rotate (bool, optional): Override the level's random canonical rotation of the object.
        """
        from easyhoi.synth.perturb import make_hoi_input

        return make_hoi_input(self, perturbation, self.seed if seed is None else seed, rotate)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    return _unit(rng.normal(size=3))


def _roll(up: np.ndarray, view: np.ndarray, angle: float) -> np.ndarray:
    """``up`` turned by ``angle`` radians about the viewing direction."""
    return _unit(np.cos(angle) * up + np.sin(angle) * np.cross(view, up))


def frame_camera(points: np.ndarray, view_dir, up, fov_deg: float, fill: float, size: int):
    """Camera looking along ``-view_dir`` at ``points`` so that their box fills ``fill``.

    Args:
        points ((N, 3) float): World points to frame.
        view_dir ((3,) float): Unit direction from the points towards the camera.
        up ((3,) float): World direction shown as image up.
        fov_deg (float): Vertical field of view.
        fill (float): Fraction of the image side covered by the larger side of the points' 2D box.
        size (int): Image width = height.

    Returns:
        Camera (float64)
    """
    f = 0.5 * size / np.tan(np.radians(fov_deg) / 2)
    target = 0.5 * (points.min(axis=0) + points.max(axis=0))
    dist = 0.5
    for _ in range(3):
        cam = Camera.look_at(target + dist * view_dir, target, up, f, size, size, torch.float64)
        uv, z = cam.project(torch.as_tensor(points))
        uv = uv.numpy()
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        extent = float((hi - lo).max())
        # perspective scale ~ 1 / distance: rescale the distance, then recentre the box
        centre_off = 0.5 * (lo + hi) - size / 2
        zc = float(np.median(z.numpy()))
        R = cam.R.numpy()
        target = target + (R[0] * centre_off[0] + R[1] * centre_off[1]) * zc / f
        dist = dist * extent / (fill * size)
    return Camera.look_at(target + dist * view_dir, target, up, f, size, size, torch.float64)


def _layer(verts: np.ndarray, faces: np.ndarray, cam: Camera) -> SurfaceLayer:
    fr = rasterize(torch.as_tensor(verts), torch.as_tensor(faces), cam, num_layers=1)
    return SurfaceLayer(
        fr.face_ids[..., 0].numpy(),
        fr.bary[..., 0, :].numpy(),
        fr.depth[..., 0].numpy(),
        verts,
        faces,
    )


def _visibility(grasp: Grasp, mesh: trimesh.Trimesh, cam: Camera) -> tuple[float, float]:
    """Visible fractions of the hand and of the object in a (cheap, low-resolution) view."""
    small = cam.resized(64, 64)
    zh = depth_map(torch.as_tensor(grasp.vertices), torch.as_tensor(grasp.faces), small).numpy()
    zo = depth_map(torch.as_tensor(mesh.vertices), torch.as_tensor(mesh.faces), small).numpy()
    h, o = np.isfinite(zh), np.isfinite(zo)
    vis_h = (h & (zh <= zo)).sum() / max(h.sum(), 1)
    vis_o = (o & (zo < zh)).sum() / max(o.sum(), 1)
    return float(vis_h), float(vis_o)


def _choose_camera(grasp: Grasp, mesh: trimesh.Trimesh, size: int, rng: np.random.Generator):
    """The view (most visible of up to 6 draws): ``(camera, view, up, fov_deg, fill)``."""
    hand_c = grasp.vertices.mean(axis=0)
    obj_c = np.asarray(mesh.vertices).mean(axis=0)
    towards_hand = _unit(hand_c - obj_c)
    R_hand = grasp.params.global_orient  # axis-angle
    from easyhoi.geometry.transforms import axis_angle_to_matrix

    forearm = axis_angle_to_matrix(R_hand.double())[0].numpy()[:, 0]  # hand +x: wrist side
    points = np.concatenate([grasp.vertices, np.asarray(mesh.vertices)])
    best, best_score = None, -1.0
    for _ in range(6):
        view = _unit(0.7 * towards_hand + rng.uniform(0.6, 1.2) * _random_unit(rng))
        up = -forearm - (-forearm @ view) * view
        if np.linalg.norm(up) < 0.2:
            up = _random_unit(rng)
            up = up - (up @ view) * view
        up = _unit(up)
        up = _roll(up, view, rng.uniform(-1.05, 1.05))
        fov, fill = rng.uniform(35, 55), rng.uniform(0.5, 0.7)
        cam = frame_camera(points, view, up, fov, fill, size)
        vh, vo = _visibility(grasp, mesh, cam)
        score = min(vh / 0.4, vo / 0.3)
        if score > best_score:
            best, best_score = (cam, view, up, fov, fill), score
        if score >= 1.0:
            break
    return best


def _holding_roll(grasp: Grasp, mesh: trimesh.Trimesh, view, up, fov, fill, size: int):
    """Turn the camera about its axis until the GT grasp holds under image-down gravity.

    Rolls in steps of :data:`HOLD_ROLL_STEP_DEG`, nearest to the drawn one first; the first whose
    simulation displacement (35 steps, gravity along the camera's +y) is at most
    :data:`HOLD_CM` is kept, else the one that moves the object least (an in-plane rotation
    changes neither visibility nor framing, so the view stays as drawn).

    Returns:
        (camera, displacement_cm, up): ``up`` the world direction now shown as image up.
    """
    from easyhoi.metrics.simulation import simulation_displacement

    points = np.concatenate([grasp.vertices, np.asarray(mesh.vertices)])
    hand = (grasp.vertices, grasp.faces)
    n = int(round(360 / HOLD_ROLL_STEP_DEG))
    order = [0] + [k * s for k in range(1, n // 2 + 1) for s in (1, -1)]
    best = None
    for k in order[:n]:  # 0, 1, -1, 2, -2, ..., 6 (x 30 degrees)
        up_k = _roll(up, view, np.radians(k * HOLD_ROLL_STEP_DEG))
        cam = frame_camera(points, view, up_k, fov, fill, size)
        gravity = cam.R.numpy()[1]  # camera +y (image down) in the world
        sd = simulation_displacement(hand, mesh, gravity_dir=gravity).displacement
        if best is None or sd < best[1]:
            best = (cam, float(sd), up_k)
        if sd <= HOLD_CM:
            break
    return best


def make_scene(
    seed: int,
    object_kind: str = "random",
    grasp_type: str = "random",
    image_size: int = 256,
    hand_model=None,
    photo: bool = True,
    check_stability: bool = False,
    hold: bool = False,
) -> SynthScene:
    """Build a synthetic scene.

    Args:
        seed (int): Everything (object, hand shape, grasp, camera, photo) derives from it.
        object_kind (str or Path): One of :data:`~easyhoi.synth.objects.OBJECT_KINDS`, a mesh path,
            or "random".
        grasp_type (str): One of :data:`~easyhoi.synth.grasp.GRASP_TYPES` or "random".
        image_size (int): Square image side in pixels (>= 32).
        hand_model (HandModel, optional): Default: ``load_hand_model("open")`` (created once per
            process).
        photo (bool): Render the shaded photo (else a flat grey image).
        check_stability (bool): Run the physics check of the grasp (slow).
        hold (bool): Turn the camera about its viewing axis until the grasp holds the object under
            gravity along the image's down direction (:func:`_holding_roll`), as in a photo of an
            object held up; the displacement is kept in ``SynthScene.gravity_sd_cm``.

    Returns:
        SynthScene
    """
    if not isinstance(image_size, int) or image_size < 32:
        raise InvalidInputError(f"image_size must be an integer >= 32, got {image_size!r}")
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 31337])
    if object_kind == "random":
        object_kind = str(rng.choice(OBJECT_KINDS, p=_KIND_WEIGHTS))
    if grasp_type == "random":
        grasp_type = str(rng.choice(GRASP_TYPES, p=_GRASP_WEIGHTS))
    if grasp_type not in GRASP_TYPES:
        raise InvalidInputError(f"grasp_type must be one of {GRASP_TYPES} or 'random'")
    model = hand_model if hand_model is not None else _default_model()
    obj = make_object(object_kind, seed)
    info = analyse_object(obj.mesh, seed=seed)
    t1 = time.perf_counter()
    betas = np.zeros(10)
    betas[0] = rng.normal(0, 1.5)
    betas[1:6] = rng.normal(0, 0.7, 5)
    grasp = synthesize_grasp(
        model, obj.mesh, grasp_type, seed=seed, betas=torch.as_tensor(betas), info=info,
        check_stability=check_stability,
    )  # fmt: skip
    t2 = time.perf_counter()
    cam, view, up, fov, fill = _choose_camera(grasp, obj.mesh, image_size, rng)
    gravity_sd = None
    if hold:
        cam, gravity_sd, up = _holding_roll(grasp, obj.mesh, view, up, fov, fill, image_size)
    t3 = time.perf_counter()
    hand = _layer(grasp.vertices, grasp.faces, cam)
    objl = _layer(np.asarray(obj.mesh.vertices), np.asarray(obj.mesh.faces), cam)
    h_hit, o_hit = hand.face_ids >= 0, objl.face_ids >= 0
    hand_vis = h_hit & (hand.depth <= objl.depth)
    obj_vis = o_hit & (objl.depth < hand.depth)
    depth = np.minimum(hand.depth, objl.depth)
    with torch.no_grad():
        kp3 = model(grasp.params.to(torch.float64)).keypoints[0].numpy()
    kp2 = cam.project(torch.as_tensor(kp3))[0].numpy()
    t4 = time.perf_counter()
    if photo:
        light = _unit(view + 0.7 * up + 0.5 * _random_unit(rng))
        scale = float(np.max(obj.mesh.extents))

        def albedo(p):
            return object_albedo(p, obj.color, obj.secondary, obj.texture, scale)

        image = shade_photo(hand, objl, cam.center.numpy(), light, skin_tone(rng), albedo, rng)
    else:
        image = np.full((image_size, image_size, 3), 128, np.uint8)
    t5 = time.perf_counter()
    timings = {"object": t1 - t0, "grasp": t2 - t1, "camera": t3 - t2, "render": t4 - t3,
               "photo": t5 - t4, "total": t5 - t0}  # fmt: skip
    return SynthScene(int(seed), obj, grasp, cam, image, hand_vis, obj_vis, h_hit, o_hit, depth,
                 kp3, kp2, timings, model, gravity_sd)  # fmt: skip


_MODEL = {}


def _default_model():
    if "open" not in _MODEL:
        from easyhoi.hand import load_hand_model

        _MODEL["open"] = load_hand_model("open")
    return _MODEL["open"]


__all__ = ["SynthScene", "frame_camera", "make_scene"]
