"""Grasp synthesis by optimization with a MANO-layout hand (the built-in OpenHand by default).

Three steps (all seeded, all in metres, world = the object's frame):

1. **Approach.** A grasp type fixes a hand-frame anchor and two hand-frame axes that are mapped
   onto world directions (:func:`frame_rotation`):

   * ``"power"`` (power wrap): the palm-centre contact point faces the object at a sampled
     surface point ``s`` (palm normal along the inward surface normal), the hand's lateral axis
     (thumb side) along the object's long axis, so that the fingers wrap around the thinner
     cross-section; the palm is placed ``gap`` (4 mm) off the surface.
   * ``"precision"`` (pinch / tripod): the midpoint of the thumb and index fingertips sits ``depth``
     inside the object's outline near one of its ends ``e`` (a principal direction), the pinch
     axis (thumb -> index) along the object's thinnest direction across that end, the hand
     coming from outside along ``e``. Ring and pinky stay curled.
   * ``"lateral"`` (key pinch): the fingers are curled; the radial side of the index finger's
     middle phalanx touches a large face of the object near an end; the thumb closes on the
     other side.

   The hand is then backed off along the approach direction until no vertex is deeper than
   ``backoff_tol`` inside the object (batched line search on the SDF grid).
2. **Closing** (iterative, per finger, batched): every closing digit flexes about
   :func:`~easyhoi.hand.regions.flexion_axes` with coupled joint ratios over ``num_steps``
   increments, evaluated in one batched forward pass; a segment that reaches the surface
   (signed distance < ``contact_tol``) freezes its joint and the joints proximal to it, and the
   distal joints keep closing (up to three phases), as in GraspIt's auto-grasp.
3. **Refinement** (gradient-based, Adam): global rotation and translation residuals and the 45
   articulation parameters minimise

   ``w_pen * sum_v relu(-d(v))^2 + w_att * sum_g softmin_{v in pad_g}(relu(d(v)))^2
   + w_reg * |theta - theta_close|^2``

   with ``d`` the trilinear lookup in a :func:`~easyhoi.geometry.sdf.build_sdf_grid` grid of the
   object and ``pad_g`` the contact-zone vertices of each closing digit (and the palm for power
   grasps).

The result reports the exact penetration depth (:func:`easyhoi.metrics.penetration_depth`), the
number of hand vertices within ``contact_threshold`` of the surface, which digits touch, and
optionally the simulation displacement (:func:`easyhoi.metrics.simulation_displacement`, slow on
curved objects because of the V-HACD decomposition).

Timing: these are small tensors; with several processes sharing few cores, PyTorch's intra-op
threads can slow them down a hundredfold, so callers may want ``torch.set_num_threads(1)``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.sdf import SDFGrid, build_sdf_grid, exact_signed_distance, query
from easyhoi.geometry.transforms import axis_angle_to_matrix, matrix_to_axis_angle
from easyhoi.hand.base import HandModel
from easyhoi.hand.lbs import forward_kinematics
from easyhoi.hand.regions import DIGIT_JOINTS, flexion_axes
from easyhoi.metrics.interaction import penetration_depth
from easyhoi.structures import HandParams

logger = logging.getLogger(__name__)

GRASP_TYPES = ("power", "precision", "lateral")
_DIGITS = tuple(DIGIT_JOINTS)  # thumb, index, middle, ring, pinky
#: Flexion ratios of (base, middle, distal) joints while closing.
_RATIO = {"thumb": (0.6, 1.0, 1.0), "finger": (1.0, 1.1, 0.8)}


@dataclass(frozen=True)
class Grasp:
    """A synthesized grasp.

    Attributes
    ----------
    params : HandParams
        Hand (batch 1) in the object's world frame, metres.
    vertices : (V, 3) float64
        Posed hand vertices (world, metres).
    faces : (F, 3) int64
        Closed hand mesh.
    grasp_type : str
        One of :data:`GRASP_TYPES`.
    penetration_cm : float
        Deepest hand vertex inside the object (exact), cm.
    contact_count : int
        Hand vertices with signed distance <= ``contact_threshold`` (inside counts).
    contact_digits : tuple of str
        Digits ("thumb", ..., "pinky", "palm") with a vertex within the threshold.
    stability_cm : float or None
        Simulation displacement (cm) when requested.
    seconds : float
        Wall time of the synthesis (stability check excluded).
    """

    params: HandParams
    vertices: np.ndarray
    faces: np.ndarray
    grasp_type: str
    penetration_cm: float
    contact_count: int
    contact_digits: tuple[str, ...]
    stability_cm: float | None
    seconds: float


# ----------------------------------------------------------------------------------------------
# Fast batched posing (same maths as HandModel.forward, without keypoints and mirroring)
# ----------------------------------------------------------------------------------------------


class _Poser:
    """Poses one shaped right hand for many articulations at once.

    ``world = R @ v_canonical(theta) + T`` with ``v_canonical`` the hand at zero global
    orientation and zero translation.
    """

    def __init__(self, model: HandModel, betas: torch.Tensor):
        with torch.no_grad():
            v, j = model.shaped(betas.reshape(1, -1).double())
        self.betas = betas.reshape(-1).double()
        self.v_rest, self.j_rest = v, j  # (1, V, 3), (1, 16, 3)
        self.weights = model.skin_weights.double()
        self.parents = model.parents
        self.model = model

    def canonical(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, 45) articulation -> (B, V, 3) canonical vertices."""
        B = pose.shape[0]
        full = torch.cat([torch.zeros(B, 3, dtype=pose.dtype), pose], dim=1).reshape(B, 16, 3)
        rot = axis_angle_to_matrix(full)
        v_rest = self.v_rest.expand(B, -1, -1)
        offsets = self.model.pose_offsets(rot)
        if offsets is not None:
            v_rest = v_rest + offsets
        _, transforms = forward_kinematics(rot, self.j_rest.expand(B, -1, -1), self.parents)
        T = (self.weights @ transforms[:, :, :3, :].reshape(B, 16, 12)).reshape(B, -1, 3, 4)
        return (T[..., :3] @ v_rest[..., None])[..., 0] + T[..., 3]

    def subset(self, ids: np.ndarray):
        """A function (B, 45) -> (B, len(ids), 3) posing only the vertices ``ids``."""
        ids = torch.as_tensor(ids)
        weights, v_rest = self.weights[ids], self.v_rest[:, ids]

        def pose_fn(pose: torch.Tensor) -> torch.Tensor:
            B = pose.shape[0]
            full = torch.cat([torch.zeros(B, 3, dtype=pose.dtype), pose], 1).reshape(B, 16, 3)
            rot = axis_angle_to_matrix(full)
            _, tf = forward_kinematics(rot, self.j_rest.expand(B, -1, -1), self.parents)
            T = (weights @ tf[:, :, :3, :].reshape(B, 16, 12)).reshape(B, -1, 3, 4)
            return (T[..., :3] @ v_rest.expand(B, -1, -1)[..., None])[..., 0] + T[..., 3]

        return pose_fn

    def params(self, pose: torch.Tensor, R: torch.Tensor, T: torch.Tensor) -> HandParams:
        """HandParams whose model output equals ``R @ canonical(pose) + T``."""
        j0 = self.j_rest[0, 0]
        go = matrix_to_axis_angle(R[None])
        transl = T + R @ j0 - j0
        return HandParams(go, transl[None], pose.reshape(1, 45), self.betas[None])


def frame_rotation(a1_hand, a2_hand, a1_world, a2_world) -> np.ndarray:
    """(3, 3) rotation mapping hand axis ``a1`` exactly onto world ``a1`` and ``a2`` as closely
    as possible onto world ``a2`` (both made orthogonal to ``a1``)."""

    def frame(a, b):
        a = np.asarray(a, float) / np.linalg.norm(a)
        b = np.asarray(b, float) - (np.dot(b, a)) * a
        nb = np.linalg.norm(b)
        if nb < 1e-9:
            raise InvalidInputError("frame_rotation: the two axes are parallel")
        b = b / nb
        return np.stack([a, b, np.cross(a, b)], axis=1)

    return frame(a1_world, a2_world) @ frame(a1_hand, a2_hand).T


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    aa = torch.as_tensor(np.asarray(axis, float) * angle / np.linalg.norm(axis))
    return axis_angle_to_matrix(aa).numpy()


# ----------------------------------------------------------------------------------------------
# Object analysis
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _ObjectInfo:
    grid: SDFGrid
    centre: np.ndarray  # (3,)
    axes: np.ndarray  # (3, 3) rows: grip axis, then the other principal axes, longer first
    points: np.ndarray  # (N, 3) surface samples
    normals: np.ndarray  # (N, 3)


def analyse_object(mesh: trimesh.Trimesh, resolution: int = 40, seed: int = 0) -> _ObjectInfo:
    """SDF grid (reaching 3 cm past the object), principal axes and surface samples."""
    from easyhoi.geometry.sampling import sample_surface

    extent = float(np.max(mesh.extents))
    grid = build_sdf_grid(mesh, resolution=resolution, padding=0.035 / extent, dtype=torch.float64)
    pts, _, nrm = sample_surface(mesh, 3000, seed=seed)
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    spread = np.ptp((pts - centre) @ vt.T, axis=0)
    axes = vt[np.argsort(-spread)]
    # the grip axis is the principal axis most surface normals are perpendicular to (a can's or
    # a mug's axis, a box's longest side): put it first
    grip = int(np.argmin(np.abs(nrm @ axes.T).mean(axis=0)))
    order = [grip] + [i for i in range(3) if i != grip]
    return _ObjectInfo(grid, centre, axes[order], pts, nrm)


# ----------------------------------------------------------------------------------------------
# Grasp synergies: an open and a closed posture per grasp type, closing is the path between them
# ----------------------------------------------------------------------------------------------

_CURLED = (0.9, 1.2, 0.7)


def _digit_pose(axes: np.ndarray, values: dict) -> np.ndarray:
    """(15, 3) articulation with each listed digit flexed by its (base, middle, distal) angles."""
    p = np.zeros((15, 3))
    for d, v in values.items():
        for j, a in zip(DIGIT_JOINTS[d], v, strict=True):
            p[j - 1] = axes[j - 1] * a
    return p


def _pad_ids(model: HandModel, joint: int) -> np.ndarray:
    reg = model.regions
    cv, part = reg.contact_vertices.numpy(), reg.vertex_part.numpy()
    return cv[part[cv] == joint]


def _fit_thumb(poser, base: np.ndarray, target_ids, free: tuple[str, ...], iters: int = 150):
    """Thumb articulation (and a common flexion scale of the ``free`` digits) bringing the thumb's
    distal pad onto the centroid of ``target_ids`` (gradient descent on 9 + 1 parameters)."""
    pad = _pad_ids(poser.model, 15)
    ids = np.concatenate([pad, target_ids])
    sub = poser.subset(ids)
    n_pad = len(pad)
    base_t = torch.as_tensor(base)
    free_rows = [j - 1 for d in free for j in DIGIT_JOINTS[d]]
    scale_mask = torch.zeros(15, 1, dtype=torch.float64)
    scale_mask[free_rows] = 1.0
    th = torch.zeros(9, dtype=torch.float64, requires_grad=True)
    log_s = torch.zeros(1, dtype=torch.float64, requires_grad=bool(free))
    opt = torch.optim.Adam([th, log_s], lr=0.05)
    for _ in range(iters):
        opt.zero_grad()
        p = base_t * (1 + scale_mask * (torch.exp(log_s) - 1))
        p = torch.cat([p[:12], th.reshape(3, 3)])
        v = sub(p.reshape(1, 45))[0]
        gap = v[:n_pad].mean(0) - v[n_pad:].mean(0)
        loss = 1e4 * gap.pow(2).sum() + 2e-3 * th.pow(2).sum()
        loss.backward()
        opt.step()
    with torch.no_grad():
        p = base_t * (1 + scale_mask * (torch.exp(log_s) - 1))
        p[12:] = th.reshape(3, 3)
    return p.numpy()


_SYNERGIES: dict = {}


def synergy(model: HandModel, grasp_type: str) -> tuple[np.ndarray, np.ndarray]:
    """Open and closed (15, 3) articulations of a grasp type (cached per model).

    * power: flat hand -> fingers flexed (1.6, 1.76, 1.28) rad, thumb wrapped onto the index
      finger's middle phalanx of a fist (fitted).
    * precision: index and middle nearly straight, ring and pinky curled -> thumb pad meeting
      the index and middle fingertip pads (thumb and finger flexion fitted).
    * lateral: fingers curled, thumb extended -> thumb pad on the radial side of the index
      finger's middle phalanx (fitted).
    """
    key = (id(model), grasp_type)
    if key in _SYNERGIES:
        return _SYNERGIES[key]
    axes = flexion_axes(model)
    poser = _Poser(model, torch.zeros(10, dtype=torch.float64))
    part = model.regions.vertex_part.numpy()
    fingers = ("index", "middle", "ring", "pinky")
    if grasp_type == "power":
        opened = np.zeros((15, 3))
        closed = _digit_pose(axes, {d: (1.6, 1.76, 1.28) for d in fingers})
        fist = _digit_pose(axes, {d: (1.0, 1.2, 0.8) for d in fingers})
        thumb = _fit_thumb(poser, fist, np.nonzero(part == 2)[0], ())
        closed[12:] = thumb[12:]
    elif grasp_type == "precision":
        curled = {"ring": _CURLED, "pinky": _CURLED}
        opened = _digit_pose(axes, {"index": (0.2, 0.25, 0.1), "middle": (0.2, 0.25, 0.1),
                                    **curled})  # fmt: skip
        base = _digit_pose(axes, {"index": (0.5, 0.6, 0.3), "middle": (0.5, 0.6, 0.3), **curled})
        target = np.concatenate([_pad_ids(model, 3), _pad_ids(model, 6)])
        closed = _fit_thumb(poser, base, target, ("index", "middle"))
    elif grasp_type == "lateral":
        opened = _digit_pose(axes, {d: _CURLED for d in fingers})
        with torch.no_grad():
            v = poser.canonical(torch.as_tensor(opened.reshape(1, 45)))[0].numpy()
        idx = np.nonzero(part == 2)[0]
        radial = idx[np.argsort(-v[idx, 2])[:8]]
        closed = _fit_thumb(poser, opened, radial, ())
    else:
        raise InvalidInputError(f"grasp_type must be one of {GRASP_TYPES}, got {grasp_type!r}")
    _SYNERGIES[key] = (opened, closed)
    return opened, closed


def _closing_digits(grasp_type: str) -> tuple[str, ...]:
    return {
        "power": _DIGITS,
        "precision": ("thumb", "index", "middle"),
        "lateral": ("thumb",),
    }[grasp_type]


def _pad_groups(model: HandModel, grasp_type: str) -> list[np.ndarray]:
    """Contact-zone vertex groups that the refinement pulls onto the surface."""
    reg = model.regions
    cv = reg.contact_vertices.numpy()
    part = reg.vertex_part.numpy()
    groups = []
    for d in _closing_digits(grasp_type):
        groups.append(cv[np.isin(part[cv], DIGIT_JOINTS[d][1:])])
    if grasp_type == "power":
        groups.append(cv[part[cv] == 0])
    if grasp_type == "lateral":
        groups.append(np.nonzero(part == DIGIT_JOINTS["index"][1])[0])
    return groups


def _approach(
    info: _ObjectInfo, poser: _Poser, opened: np.ndarray, closed: np.ndarray, grasp_type: str,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """World rotation R, translation T and the unit back-off direction of the approach."""
    poses = torch.as_tensor(np.stack([opened, 0.5 * (opened + closed), closed]).reshape(3, 45))
    with torch.no_grad():
        v_open, v_half, v_closed = poser.canonical(poses).numpy()
    model = poser.model
    part = model.regions.vertex_part.numpy()
    wrist = poser.j_rest[0, 0].numpy()
    grip_axis, mid_axis, thin_axis = info.axes
    c, pts, nrm = info.centre, info.points, info.normals
    if grasp_type == "power":
        rel = (pts - c) @ grip_axis
        half = 0.5 * np.ptp(rel)
        side = 1.0 - np.abs(nrm @ grip_axis)
        w = side**4 * np.exp(-0.5 * (rel / (0.3 * half + 1e-9)) ** 2) + 1e-9
        i = rng.choice(len(pts), p=w / w.sum())
        s, n = pts[i], nrm[i]
        lateral = grip_axis * rng.choice([-1.0, 1.0])
        # oblique wrap: the object axis runs from the hypothenar towards the index base, at
        # 17-40 degrees from the hand's lateral axis, so the thumb crosses over the object
        phi = rng.uniform(0.3, 0.7)
        R = frame_rotation([0, -1, 0], [np.sin(phi), 0, np.cos(phi)], -n, lateral)
        anchor = v_open[_pad_ids(model, 0)].mean(axis=0)
        return R, s + 0.004 * n - R @ anchor, n
    # precision / lateral: near an end e of the object, across its thinnest direction u
    e_axis = grip_axis if rng.random() < 0.6 else mid_axis
    e = e_axis * rng.choice([-1.0, 1.0])
    u = thin_axis if e_axis is not thin_axis else mid_axis
    ext = float(((pts - c) @ e).max())
    if grasp_type == "precision":
        thumb = v_closed[_pad_ids(model, 15)].mean(axis=0)
        anchor = thumb
        pinch = v_half[_pad_ids(model, 3)].mean(axis=0) - v_half[_pad_ids(model, 15)].mean(axis=0)
        m = c + (ext - min(0.012, 0.45 * ext)) * e
        R = frame_rotation(pinch, anchor - wrist, u * rng.choice([-1.0, 1.0]), -e)
        R = _rot(u, rng.uniform(-0.3, 0.3)) @ R
        return R, m - R @ anchor, e
    # lateral: the object between the radial side of the index and the thumb pad
    idx = np.nonzero(part == 2)[0]
    anchor = v_open[idx[np.argsort(-v_open[idx, 2])[:8]]].mean(axis=0)
    towards_thumb = v_open[_pad_ids(model, 15)].mean(axis=0) - anchor
    sgn = rng.choice([-1.0, 1.0])
    m = c + (ext - min(0.018, 0.45 * ext)) * e
    near = np.abs((pts - m) @ e) < 0.01
    face = near & (((pts - c) @ (-sgn * u)) > 0)
    s = pts[face][np.argmax((pts[face] - c) @ (-sgn * u))] if face.any() else m
    R = frame_rotation(towards_thumb, anchor - wrist, sgn * u, -e)
    return R, s - 0.003 * sgn * u - R @ anchor, -sgn * u


# ----------------------------------------------------------------------------------------------
# Steps 1-3
# ----------------------------------------------------------------------------------------------


def _sdf(grid: SDFGrid, canon: torch.Tensor, R: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    return query(grid, canon @ R.T + T)


def _back_off(grid, canon, R, T, direction, tol: float, max_dist: float = 0.08) -> np.ndarray:
    """Smallest shift along ``direction`` that leaves no vertex deeper than ``tol`` inside."""
    shifts = torch.linspace(0.0, max_dist, 81, dtype=torch.float64)
    moved = canon[None] @ R.T + T + shifts[:, None, None] * torch.as_tensor(direction)
    depth = query(grid, moved).amin(dim=1)
    ok = torch.nonzero(depth > -tol)
    k = int(ok[0]) if len(ok) else len(shifts) - 1
    return T.numpy() + float(shifts[k]) * np.asarray(direction)


def _close(poser, grid, opened, closed, digits, R, T, num_steps, contact_tol):
    """Per-finger closing along the synergy with segment-wise freezing; returns (15, 3)."""
    part = poser.model.regions.vertex_part.numpy()
    vel = closed - opened
    alpha = np.zeros(15)
    active = {d: np.array([True, True, True]) for d in digits}
    seg_ids = {d: [np.nonzero(part == j)[0] for j in DIGIT_JOINTS[d]] for d in digits}
    steps = np.linspace(0.0, 1.0, num_steps + 1)[1:]
    for _ in range(3):
        if not any(a.any() for a in active.values()):
            break
        a = np.repeat(alpha[None], num_steps, axis=0)
        for d in digits:
            rows = [j - 1 for j in DIGIT_JOINTS[d]]
            a[:, rows] = np.minimum(a[:, rows] + steps[:, None] * active[d], 1.0)
        batch = opened[None] + a[..., None] * vel[None]
        with torch.no_grad():
            canon = poser.canonical(torch.as_tensor(batch.reshape(num_steps, 45)))
            d_all = _sdf(grid, canon, R, T)  # (S, V)
        for d in digits:
            if not active[d].any():
                continue
            rows = [j - 1 for j in DIGIT_JOINTS[d]]
            seg_min = torch.stack([d_all[:, ids].amin(dim=1) for ids in seg_ids[d]], 1).numpy()
            hit = seg_min < contact_tol  # (S, 3)
            first = np.nonzero(hit.any(axis=1))[0]
            if len(first) and first[0] > 0:
                alpha[rows] = a[first[0] - 1, rows]
            elif not len(first):
                alpha[rows] = a[-1, rows]
            if len(first):
                active[d][: int(np.nonzero(hit[first[0]])[0].max()) + 1] = False
            else:
                active[d][:] = False
    return opened + alpha[:, None] * vel


def synthesize_grasp(
    model: HandModel,
    mesh: trimesh.Trimesh,
    grasp_type: str = "power",
    seed: int = 0,
    betas: torch.Tensor | None = None,
    info: _ObjectInfo | None = None,
    iterations: int = 40,
    contact_threshold: float = 0.005,
    check_stability: bool = False,
    w_pen: float = 3e4,
    w_att: float = 3e3,
    w_reg: float = 1.0,
) -> Grasp:
    """Synthesize a grasp of ``mesh`` (watertight, metres) by the hand ``model``.

    Parameters
    ----------
    model : HandModel
        Right-hand MANO-layout model (``load_hand_model("open")``).
    mesh : trimesh.Trimesh
        Watertight object in metres (world frame).
    grasp_type : {"power", "precision", "lateral"}
    seed : int
        Seeds the approach (surface point, roll, ends).
    betas : (10,) tensor, optional
        Hand shape (zeros by default).
    info : optional
        Precomputed :func:`analyse_object` of ``mesh`` (reuse across grasps).
    iterations : int
        Adam refinement iterations (0 disables the refinement).
    contact_threshold : float
        Metres; vertices within it count as contacts.
    check_stability : bool
        Also run :func:`easyhoi.metrics.simulation_displacement` (35 steps) with gravity along
        the palm normal (palm facing down: the fingers alone must hold the object). Slow on
        curved objects (V-HACD decomposition).
    w_pen, w_att, w_reg : float
        Refinement loss weights.

    Returns
    -------
    Grasp
    """
    if grasp_type not in GRASP_TYPES:
        raise InvalidInputError(f"grasp_type must be one of {GRASP_TYPES}, got {grasp_type!r}")
    start = time.perf_counter()
    rng = np.random.default_rng([seed, GRASP_TYPES.index(grasp_type), 4099])
    info = info if info is not None else analyse_object(mesh, seed=seed)
    betas = torch.zeros(10, dtype=torch.float64) if betas is None else torch.as_tensor(betas)
    poser = _Poser(model, betas)
    opened, closed = synergy(model, grasp_type)
    R, T, back = _approach(info, poser, opened, closed, grasp_type, rng)
    Rt = torch.as_tensor(R)
    with torch.no_grad():
        canon = poser.canonical(torch.as_tensor(opened.reshape(1, 45)))[0]
    T = _back_off(info.grid, canon, Rt, torch.as_tensor(T), back, tol=0.0005)
    Tt = torch.as_tensor(T)
    pose_c = _close(poser, info.grid, opened, closed, _closing_digits(grasp_type), Rt, Tt,
                    num_steps=40, contact_tol=0.0015)  # fmt: skip
    pose0 = torch.as_tensor(pose_c.reshape(45))
    pose, Rt, Tt = _refine(poser, info.grid, mesh, pose0, Rt, Tt, _pad_groups(model, grasp_type),
                           iterations, w_pen, w_att, w_reg)  # fmt: skip
    params = poser.params(pose, Rt, Tt)
    with torch.no_grad():
        out = model(params)
    verts = out.vertices[0].double().numpy()
    faces = out.faces.numpy().astype(np.int64)
    d = exact_signed_distance(mesh, verts)
    pen = penetration_depth((verts, faces), mesh)
    close = d <= contact_threshold
    part = model.regions.vertex_part.numpy()
    touching = [n for n, js in DIGIT_JOINTS.items() if close[np.isin(part, js)].any()]
    if close[part == 0].any():
        touching.append("palm")
    seconds = time.perf_counter() - start
    stability = None
    if check_stability:
        from easyhoi.metrics.simulation import simulation_displacement

        palm_down = Rt.numpy() @ np.array([0.0, -1.0, 0.0])  # pulls the object out of the palm
        sim = simulation_displacement((verts, faces), mesh, gravity_dir=palm_down)
        stability = float(sim.displacement)
    return Grasp(params, verts, faces, grasp_type, pen, int(close.sum()), tuple(touching),
                 stability, seconds)  # fmt: skip


def _refine(poser, grid, mesh, pose0, R0, T0, groups, iterations, w_pen, w_att, w_reg):
    """Adam on (rotation residual, translation residual, articulation).

    The grid's interpolation error (large near thin parts and sharp edges) is cancelled by a
    per-vertex correction ``exact - grid`` refreshed every 10 iterations with the exact signed
    distance of ``mesh``.
    """
    if iterations <= 0:
        return pose0, R0, T0
    pose = pose0.clone().requires_grad_(True)
    drot = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    dt = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([{"params": [pose], "lr": 0.01},
                            {"params": [drot], "lr": 0.005},
                            {"params": [dt], "lr": 0.001}])  # fmt: skip
    groups = [torch.as_tensor(g) for g in groups if len(g)]
    correction = torch.zeros(())
    for it in range(iterations):
        opt.zero_grad()
        R = axis_angle_to_matrix(drot) @ R0
        x = poser.canonical(pose[None])[0] @ R.T + T0 + dt
        d = query(grid, x)
        if it % 10 == 0:
            exact = exact_signed_distance(mesh, x.detach().numpy())
            correction = torch.as_tensor(exact) - d.detach()
        d = d + correction
        pen = torch.relu(-d).pow(2).sum()
        att = sum(torch.relu(d[g].amin()).pow(2) for g in groups)
        reg = (pose - pose0).pow(2).sum()
        loss = w_pen * pen + w_att * att + w_reg * reg
        loss.backward()
        opt.step()
    with torch.no_grad():
        R = axis_angle_to_matrix(drot) @ R0
    return pose.detach(), R.detach(), (T0 + dt).detach()


__all__ = ["GRASP_TYPES", "Grasp", "analyse_object", "frame_rotation", "synthesize_grasp"]
