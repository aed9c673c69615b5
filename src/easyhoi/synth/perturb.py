"""Perturbation models standing in for the large models of the pipeline.

Each :class:`Perturbation` bundles three error models; :data:`PERTURBATION_LEVELS` names four:

=========  ==========================  ==============================  =========================
level      hand estimator              object reconstruction           masks
=========  ==========================  ==============================  =========================
none       exact                       oracle shape, canonical frame   exact
                                       (centred, unit extent), no
                                       rotation, scale 1
low        0.04 rad joints, 2 deg      oracle shape, random rotation,  1 px boundary jitter
           global, 2 % depth, 2 %      scale in [0.5, 2]
           size
hamer      0.10 rad joints, 5 deg      smooth deformation (2 % of the  2 px jitter, 1 hole,
           global, 5 % depth, 4 %      extent), random rotation,       2 px bleeding
           size (MPJPE ~ 1 cm,         scale in [0.5, 2]
           root-aligned)
high       0.20 rad joints, 10 deg     convex hull, random rotation,   4 px jitter, 3 holes,
           global, 10 % depth, 8 %     scale in [0.5, 2]               5 px bleeding
           size
=========  ==========================  ==============================  =========================

Hand errors act on the hand expressed in the estimator's camera: articulation noise is Gaussian
on the 45 axis-angle parameters; global rotation noise rotates the hand about its wrist by a
random axis and a Gaussian angle; the depth error moves the hand along the camera ray through the
wrist by a relative Gaussian factor (the wrist still projects to the same pixel, as with
HaMeR's fixed-focal-length translation); the size error changes shape coefficient 0 (5 % per
unit on OpenHand). HaMeR's published accuracy is about 1 cm MPJPE after root alignment; the
"hamer" level is calibrated to that (measured by the tests on 20 seeds).

Object errors: the GT mesh is moved to a canonical frame ``x_can = s * Rc @ (x_world - c)``
(``c`` the bounding-box centre, ``s`` = ``scale / max extent``) recorded in the input's meta,
then distorted: ``"smooth"`` displaces vertices along their normals by a sum of random low
frequency sinusoids (wavelengths >= about the object's size) with RMS ``amplitude * extent``;
``"coarse"`` replaces the mesh by its convex hull (or a heavy decimation).

Mask errors: boundary jitter moves the boundary by a smooth random field of RMS ``jitter_px``
pixels (threshold of the signed distance transform plus the field); holes remove discs inside;
bleeding grows the mask into the other region (hand into object and vice versa) by ``bleed_px``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.masks import mask_iou as _mask_iou
from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle, random_rotations
from easyhoi.structures import Camera, HandParams


@dataclass(frozen=True)
class HandNoise:
    """Hand estimator error. Angles in radians; ``depth`` and ``size`` relative (std);
    ``keypoints`` the 2D keypoint detector's error (std per coordinate, as a fraction of the
    hand's size in the photo) on visible joints, :data:`OCCLUDED_KEYPOINT_FACTOR` times more on
    joints the object hides."""

    articulation: float = 0.0
    rotation: float = 0.0
    depth: float = 0.0
    size: float = 0.0
    keypoints: float = 0.0


@dataclass(frozen=True)
class ObjectNoise:
    """Object reconstruction error.

    Attributes:
        rotate (bool): Random (uniform) rotation of the canonical frame.
        scale_range ((2,) float): The canonical mesh's max extent is drawn log-uniformly in this
            range.
        shape: {"oracle", "smooth", "coarse"}
        amplitude (float): RMS normal displacement of ``"smooth"`` as a fraction of the max extent.
        coarse: {"hull", "decimate"}
        coarse_faces (int): Face budget of ``coarse="decimate"``.
    """

    rotate: bool = False
    scale_range: tuple[float, float] = (1.0, 1.0)
    shape: str = "oracle"
    amplitude: float = 0.0
    coarse: str = "hull"
    coarse_faces: int = 200


@dataclass(frozen=True)
class MaskNoise:
    """Segmentation error, in pixels of the image."""

    jitter_px: float = 0.0
    holes: int = 0
    hole_radius_px: float = 3.0
    bleed_px: int = 0


@dataclass(frozen=True)
class Perturbation:
    """Errors of the hand estimator, the object reconstruction and the segmenters."""

    name: str = "custom"
    hand: HandNoise = field(default_factory=HandNoise)
    object: ObjectNoise = field(default_factory=ObjectNoise)
    mask: MaskNoise = field(default_factory=MaskNoise)


_SCALES = (0.5, 2.0)

#: The named levels (see the module docstring).
PERTURBATION_LEVELS: dict[str, Perturbation] = {
    "none": Perturbation("none"),
    "low": Perturbation(
        "low",
        HandNoise(
            articulation=0.04, rotation=np.radians(2), depth=0.02, size=0.02, keypoints=0.015
        ),
        ObjectNoise(rotate=True, scale_range=_SCALES),
        MaskNoise(jitter_px=1.0),
    ),
    "hamer": Perturbation(
        "hamer",
        HandNoise(articulation=0.10, rotation=np.radians(5), depth=0.05, size=0.04, keypoints=0.03),
        ObjectNoise(rotate=True, scale_range=_SCALES, shape="smooth", amplitude=0.02),
        MaskNoise(jitter_px=2.0, holes=1, hole_radius_px=3.0, bleed_px=2),
    ),
    "high": Perturbation(
        "high",
        HandNoise(
            articulation=0.20, rotation=np.radians(10), depth=0.10, size=0.08, keypoints=0.06
        ),
        ObjectNoise(rotate=True, scale_range=_SCALES, shape="coarse", coarse="hull"),
        MaskNoise(jitter_px=4.0, holes=3, hole_radius_px=4.0, bleed_px=5),
    ),
}


def get_perturbation(level) -> Perturbation:
    """A :class:`Perturbation` from a level name or itself."""
    if isinstance(level, Perturbation):
        return level
    if level not in PERTURBATION_LEVELS:
        raise InvalidInputError(
            f"unknown perturbation level {level!r}; choose one of {tuple(PERTURBATION_LEVELS)}"
        )
    return PERTURBATION_LEVELS[level]


# ----------------------------------------------------------------------------------------------
# Hand
# ----------------------------------------------------------------------------------------------


def _root_joint(model, betas: torch.Tensor) -> torch.Tensor:
    with torch.no_grad():
        _, j = model.shaped(betas.reshape(1, -1))
    return j[0, 0]


def transform_hand(params: HandParams, R, t, model) -> HandParams:
    """Hand parameters after the rigid motion ``x -> R @ x + t`` of the posed hand.

    Args:
        params (HandParams): Batch 1, right hand.
        R: (3, 3), t : (3,)
        model (HandModel): Needed for the root joint position (it depends on the shape).
    """
    dtype = params.pose.dtype
    R = torch.as_tensor(np.asarray(R), dtype=dtype)
    t = torch.as_tensor(np.asarray(t), dtype=dtype)
    j0 = _root_joint(model, params.betas.to(dtype)).to(dtype)
    R_go = axis_angle_to_matrix(params.global_orient[0])
    go = matrix_to_axis_angle((R @ R_go)[None])
    transl = R @ (j0 + params.transl[0]) + t - j0
    return HandParams(go, transl[None], params.pose, params.betas, params.side)


def perturb_hand(params: HandParams, noise: HandNoise, model, rng: np.random.Generator):
    """Apply the hand estimator error to a hand expressed in a camera frame.

    Args:
        params (HandParams): GT hand in the camera frame (batch 1).
        noise: HandNoise
        model: HandModel
        rng: numpy Generator

    Returns:
        HandParams
    """
    dtype = params.pose.dtype
    pose = params.pose + torch.as_tensor(rng.normal(0, noise.articulation, (1, 45)), dtype=dtype)
    betas = params.betas.clone()
    betas[0, 0] = betas[0, 0] + float(rng.normal(0, noise.size)) / 0.05
    out = HandParams(params.global_orient, params.transl, pose, betas, params.side)
    # rotation about the wrist, then a move along the ray through the wrist
    j0 = _root_joint(model, betas.to(dtype)).to(dtype)
    wrist = (j0 + params.transl[0]).detach().numpy()
    axis = rng.normal(size=3)
    angle = float(rng.normal(0, noise.rotation))
    dR = axis_angle_to_matrix(torch.as_tensor(axis / np.linalg.norm(axis) * angle)).numpy()
    out = transform_hand(out, dR, wrist - dR @ wrist, model)
    scale = 1.0 + float(rng.normal(0, noise.depth))
    return transform_hand(out, np.eye(3), (scale - 1.0) * wrist, model)


#: Detector noise multiplier and confidence of a keypoint hidden by the object (detectors guess
#: hidden joints from the hand's shape: larger errors, and they report lower confidence).
OCCLUDED_KEYPOINT_FACTOR = 3.0
OCCLUDED_KEYPOINT_CONFIDENCE = 0.3


def detect_keypoints(scene, noise: HandNoise, rng: np.random.Generator):
    """A 2D keypoint detector's output on the scene: ``(keypoints (21, 2) pixels, confidence
    (21,))``, the GT keypoints plus Gaussian noise of ``noise.keypoints`` times the hand's size
    (the larger side of the GT keypoints' box), larger and less confident where hidden."""
    kp = np.asarray(scene.keypoints_2d, dtype=np.float64)
    with torch.no_grad():
        z = scene.camera.world_to_camera(torch.tensor(np.asarray(scene.keypoints_3d)))[:, 2].numpy()
    H, W = scene.depth.shape
    col = np.clip(kp[:, 0].astype(int), 0, W - 1)
    row = np.clip(kp[:, 1].astype(int), 0, H - 1)
    hidden = scene.object_mask[row, col] & (scene.depth[row, col] < z - 0.005)
    size = float(np.ptp(kp, axis=0).max())
    std = noise.keypoints * size * np.where(hidden, OCCLUDED_KEYPOINT_FACTOR, 1.0)
    out = kp + rng.normal(size=kp.shape) * std[:, None]
    conf = np.where(hidden, OCCLUDED_KEYPOINT_CONFIDENCE, 1.0)
    return out, conf


# ----------------------------------------------------------------------------------------------
# Object
# ----------------------------------------------------------------------------------------------


def smooth_deformation(mesh: trimesh.Trimesh, amplitude: float, rng: np.random.Generator):
    """Displace vertices along their normals by a random low-frequency field.

    The field is a sum of 8 sinusoids with random directions and wavelengths of 1-2.5 times
    the max extent, rescaled to RMS ``amplitude * max extent`` over the vertices.
    """
    v = np.asarray(mesh.vertices, float)
    extent = float(np.max(mesh.extents))
    k = rng.normal(size=(8, 3))
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    k *= (2 * np.pi / (extent * rng.uniform(1.0, 2.5, 8)))[:, None]
    field_ = np.sin(v @ k.T + rng.uniform(0, 2 * np.pi, 8)) @ rng.normal(size=8)
    field_ = field_ / max(np.sqrt(np.mean(field_**2)), 1e-12) * amplitude * extent
    out = trimesh.Trimesh(v + field_[:, None] * mesh.vertex_normals, mesh.faces, process=False)
    return out


def perturb_object(mesh: trimesh.Trimesh, noise: ObjectNoise, rng: np.random.Generator):
    """Object mesh in a canonical frame with reconstruction errors.

    Args:
        mesh (trimesh.Trimesh): GT object, world frame, metres.
        noise: ObjectNoise
        rng: numpy Generator

    Returns:
        mesh (trimesh.Trimesh): The canonical (possibly distorted) mesh.
        canonical_from_world ((4, 4) float64): The similarity ``x_can = s * Rc @ (x_world - c)``
            (before distortion).
    """
    v = np.asarray(mesh.vertices, float)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c = 0.5 * (lo + hi)
    a, b = noise.scale_range
    if not 0 < a <= b:
        raise InvalidInputError(f"scale_range must satisfy 0 < lo <= hi, got {noise.scale_range}")
    size = float(np.exp(rng.uniform(np.log(a), np.log(b))))
    s = size / float((hi - lo).max())
    if noise.rotate:
        gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
        Rc = random_rotations(1, gen)[0].numpy()
    else:
        Rc = np.eye(3)
    M = np.eye(4)
    M[:3, :3] = s * Rc
    M[:3, 3] = -s * Rc @ c
    out = trimesh.Trimesh(v @ M[:3, :3].T + M[:3, 3], np.asarray(mesh.faces), process=False)
    if noise.shape == "smooth":
        out = smooth_deformation(out, noise.amplitude, rng)
    elif noise.shape == "coarse":
        if noise.coarse == "hull":
            out = out.convex_hull
        else:
            from easyhoi.geometry.watertight import decimate

            out = decimate(out, int(noise.coarse_faces))
    elif noise.shape != "oracle":
        raise InvalidInputError(
            f"object shape error must be 'oracle', 'smooth' or 'coarse', got {noise.shape!r}"
        )
    return out, M


# ----------------------------------------------------------------------------------------------
# Masks
# ----------------------------------------------------------------------------------------------


def _signed_distance(mask: np.ndarray) -> np.ndarray:
    m = mask.astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, 5)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5)
    return inside - outside  # > 0 inside (pixel units, ~0.5 at the boundary)


def perturb_mask(mask: np.ndarray, noise: MaskNoise, rng: np.random.Generator, other=None):
    """A segmenter's version of ``mask`` (H, W) bool; ``other`` (H, W) bool is where it bleeds.

    Returns the original when the perturbed mask would be empty.
    """
    m = np.asarray(mask, bool)
    H, W = m.shape
    out = m.copy()
    if noise.jitter_px > 0 and m.any():
        sigma = max(2.0, 0.02 * max(H, W))
        k = int(2 * round(3 * sigma) + 1)
        f = cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32), (k, k), sigma)
        f = f / max(float(f.std()), 1e-12)
        out = _signed_distance(m) - 0.5 + noise.jitter_px * f > 0
    if noise.bleed_px > 0 and other is not None:
        size = 2 * int(noise.bleed_px) + 1
        grown = cv2.dilate(out.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
        out = out | (grown & np.asarray(other, bool))
    ys, xs = np.nonzero(out)
    for _ in range(noise.holes if len(ys) else 0):
        i = int(rng.integers(len(ys)))
        r = max(1, int(round(noise.hole_radius_px * rng.uniform(0.7, 1.3))))
        disc = np.zeros((H, W), np.uint8)
        cv2.circle(disc, (int(xs[i]), int(ys[i])), r, 1, -1)
        out = out & (disc == 0)
    return out if out.any() else m


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1 when both are empty: a perturbation of
    an empty mask leaves it as it is)."""
    return _mask_iou(a, b, empty=1.0)


# ----------------------------------------------------------------------------------------------
# HOIInput
# ----------------------------------------------------------------------------------------------


def make_hoi_input(scene, perturbation="none", seed: int = 0, rotate: bool | None = None):
    """Build the optimizer's :class:`~easyhoi.hoi.HOIInput` from a scene.

    Args:
        scene: SynthScene
        perturbation: str or Perturbation
        seed (int): Seeds every perturbation (independent streams for hand, object and each mask).
        rotate (bool, optional): Override the level's random canonical rotation.

    Returns:
        HOIInput: Hand in the estimator camera (= the GT camera's intrinsics, identity extrinsics);
            masks M_h (visible hand), M_o (visible object), M^_o (amodal object) after the mask
            errors; ``complete_hand_mask`` None. ``meta["keypoints2d"]`` and
            ``meta["keypoints2d_confidence"]``: the detector's keypoints
            (:func:`detect_keypoints`). ``meta["gt"]`` holds the ground truth:
            ``canonical_from_world`` (4x4), ``metres_per_unit``, ``hand_params_world``,
            ``hand_params_camera``, ``camera`` (world-to-camera), plus the level's name.
    """
    from dataclasses import replace

    from easyhoi.hoi import HOIInput

    p = get_perturbation(perturbation)
    if rotate is not None:
        p = replace(p, object=replace(p.object, rotate=bool(rotate)))
    streams = [np.random.default_rng([seed, 2024, k]) for k in range(5)]
    model = scene.hand_model
    cam = scene.camera
    gt_world = scene.hand_params.to(torch.float64)
    gt_cam = transform_hand(gt_world, cam.R.numpy(), cam.t.numpy(), model)
    est = perturb_hand(gt_cam, p.hand, model, streams[0])
    mesh, M = perturb_object(scene.object.mesh, p.object, streams[1])
    hand_m = perturb_mask(scene.hand_mask, p.mask, streams[2], other=scene.object_mask)
    obj_m = perturb_mask(scene.object_mask, p.mask, streams[3], other=scene.hand_mask)
    amodal = perturb_mask(scene.object_amodal, p.mask, streams[4], other=scene.hand_mask)
    keypoints, confidence = detect_keypoints(scene, p.hand, np.random.default_rng([seed, 2024, 5]))
    hand_camera = Camera(cam.K.clone(), torch.eye(3, dtype=cam.K.dtype),
                         torch.zeros(3, dtype=cam.K.dtype), cam.width, cam.height)  # fmt: skip
    meta = {
        "source": "easyhoi.synth",
        "scene_seed": int(scene.seed),
        "perturbation": p.name,
        "perturbation_seed": int(seed),
        "object_kind": scene.object.kind,
        "grasp_type": scene.grasp.grasp_type,
        "keypoints2d": keypoints.tolist(),
        "keypoints2d_confidence": confidence.tolist(),
        "gt": {
            "canonical_from_world": M.tolist(),
            "metres_per_unit": float(1.0 / np.linalg.norm(M[:3, 0])),
            "hand_params_world": gt_world.to_dict(),
            "hand_params_camera": gt_cam.to_dict(),
            "camera": cam.to_dict(),
        },
    }
    return HOIInput(
        image=scene.image,
        hand_mask=hand_m,
        object_mask=obj_m,
        amodal_mask=amodal,
        object_mesh=mesh,
        hand_params=est.to(torch.float32),
        hand_camera=hand_camera,
        hand_model="mano" if getattr(model, "name", "") == "mano" else "open",
        meta=meta,
    )


__all__ = [
    "PERTURBATION_LEVELS",
    "HandNoise",
    "MaskNoise",
    "ObjectNoise",
    "Perturbation",
    "detect_keypoints",
    "get_perturbation",
    "make_hoi_input",
    "mask_iou",
    "perturb_hand",
    "perturb_mask",
    "perturb_object",
    "smooth_deformation",
    "transform_hand",
]
