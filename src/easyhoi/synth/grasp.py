"""Grasp synthesis by optimization with a MANO-layout hand (the built-in OpenHand by default).

Three steps (all seeded, all in metres, world = the object's frame):

1. **Approach.** A grasp type fixes a hand-frame anchor and two hand-frame axes that are mapped
   onto world directions (:func:`~easyhoi.synth.synergy.frame_rotation`). The object's axes are
   its principal axes; its *grip axis* is the one most surface normals are perpendicular to (a
   can's or mug's axis, a box's longest side).

   * ``"power"`` (oblique power wrap): the palm-centre contact zone faces a sampled surface
     point ``s`` (sides of the grip axis preferred, near the middle), palm normal along the
     inward surface normal, 4 mm off the surface; the grip axis runs 17-40 degrees off the
     hand's lateral axis (hypothenar towards the index base) so the fingers wrap around the
     thinner cross-section and the thumb crosses over from the other side.
   * ``"precision"`` (pinch / tripod): the point where the thumb pad meets the index and middle
     pads in the closed pinch lies 12 mm inside one end ``e`` of the object (a principal
     direction), the pinch axis along the thinnest direction across that end, the hand coming
     from outside along ``e``; ring and pinky stay curled.
   * ``"lateral"`` (key pinch): fingers curled; the radial side of the index middle phalanx
     lies 3 mm off a large face near an end; the thumb closes on the other side.

   The hand (open posture) is then backed off along the approach direction until no vertex is
   deeper than 0.5 mm inside (batched line search on the SDF grid).
2. **Closing** (iterative, per finger, batched): every closing digit moves along its grasp
   synergy (:func:`~easyhoi.synth.synergy.synergy`, open -> closed posture) in 40 increments
   evaluated in one batched forward pass; when a segment comes within 1.5 mm of the surface, its
   joint and the joints proximal to it freeze and the distal joints keep closing (up to three
   phases), as in GraspIt's auto-grasp.
3. **Refinement** (gradient-based, Adam, 40 iterations): residual rotation and translation and
   the 45 articulation parameters minimise

   ``w_pen * sum_v relu(-d(v))^2 + w_att * sum_g relu(min_{v in pad_g} d(v))^2
   + w_reg * |theta - theta_closed|^2``

   with ``d`` each vertex's exact signed distance at the last refresh (every 5 iterations)
   plus its motion since along the closest surface point's normal (a tangent-plane model; a
   40^3 :func:`~easyhoi.geometry.sdf.build_sdf_grid` grid, used for steps 1-2, misses thin
   parts and sharp edges), and ``pad_g`` the contact-zone vertices of each closing digit (the
   palm too for power grasps, the index middle phalanx for lateral ones).

Steps 1-3 are repeated with a new approach (up to ``attempts``) while the grasp penetrates by
more than 2 mm or a required digit does not touch; the best attempt is kept.

The result reports the penetration depth (:func:`easyhoi.metrics.penetration_depth`), the
number of hand vertices within ``contact_threshold`` of the surface (exact distances), which
digits touch, and optionally the simulation displacement
(:func:`easyhoi.metrics.simulation_displacement`, palm facing down; slow on curved objects
because of the V-HACD decomposition).

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
from easyhoi.geometry.sdf import SDFGrid, build_sdf_grid, exact_signed_distance
from easyhoi.hand.base import HandModel
from easyhoi.hand.regions import DIGIT_JOINTS
from easyhoi.metrics.interaction import penetration_depth
from easyhoi.structures import HandParams
from easyhoi.synth.grasp_steps import (  # noqa: F401  (moved from this module)
    _back_off,
    _close,
    _refine,
    _sdf,
    _signed_distance_planes,
)
from easyhoi.synth.synergy import HandPoser, axis_rotation, frame_rotation, pad_ids, synergy

logger = logging.getLogger(__name__)

GRASP_TYPES = ("power", "precision", "lateral")
_DIGITS = tuple(DIGIT_JOINTS)  # thumb, index, middle, ring, pinky


@dataclass(frozen=True)
class Grasp:
    """A synthesized grasp.

    Attributes:
        params (HandParams): Hand (batch 1) in the object's world frame, metres.
        vertices ((V, 3) float64): Posed hand vertices (world, metres).
        faces ((F, 3) int64): Closed hand mesh.
        grasp_type (str): One of :data:`GRASP_TYPES`.
        penetration_cm (float): Deepest hand vertex inside the object (exact), cm.
        contact_count (int): Hand vertices with signed distance <= ``contact_threshold`` (inside
            counts).
        contact_digits (tuple of str): Digits ("thumb", ..., "pinky", "palm") with a vertex within
            the threshold.
        stability_cm (float or None): Simulation displacement (cm) when requested.
        seconds (float): Wall time of the synthesis (stability check excluded).
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
    grid = build_sdf_grid(
        mesh, resolution=resolution, padding=0.035 / extent, dtype=torch.float64, exact_band=4.0
    )
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


#: Digits that must touch for a grasp to be accepted without another attempt.
_REQUIRED = {
    "power": {"thumb", "index", "middle", "ring"},
    "precision": {"thumb", "index"},
    "lateral": {"thumb", "index"},
}


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
    info: _ObjectInfo, poser: HandPoser, opened: np.ndarray, closed: np.ndarray, grasp_type: str,
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
        anchor = v_open[pad_ids(model, 0)].mean(axis=0)
        return R, s + 0.004 * n - R @ anchor, n
    # precision / lateral: near an end e of the object, across its thinnest direction u
    e_axis = grip_axis if rng.random() < 0.6 else mid_axis
    e = e_axis * rng.choice([-1.0, 1.0])
    u = thin_axis if e_axis is not thin_axis else mid_axis
    ext = float(((pts - c) @ e).max())
    if grasp_type == "precision":
        thumb = v_closed[pad_ids(model, 15)].mean(axis=0)
        anchor = thumb
        pinch = v_half[pad_ids(model, 3)].mean(axis=0) - v_half[pad_ids(model, 15)].mean(axis=0)
        m = c + (ext - min(0.012, 0.45 * ext)) * e
        R = frame_rotation(pinch, anchor - wrist, u * rng.choice([-1.0, 1.0]), -e)
        R = axis_rotation(u, rng.uniform(-0.3, 0.3)) @ R
        return R, m - R @ anchor, e
    # lateral: the object between the radial side of the index and the thumb pad
    idx = np.nonzero(part == 2)[0]
    anchor = v_open[idx[np.argsort(-v_open[idx, 2])[:8]]].mean(axis=0)
    towards_thumb = v_open[pad_ids(model, 15)].mean(axis=0) - anchor
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
    attempts: int = 3,
) -> Grasp:
    """Synthesize a grasp of ``mesh`` (watertight, metres) by the hand ``model``.

    Args:
        model (HandModel): Right-hand MANO-layout model (``load_hand_model("open")``).
        mesh (trimesh.Trimesh): Watertight object in metres (world frame).
        grasp_type: {"power", "precision", "lateral"}
        seed (int): Seeds the approach (surface point, roll, ends).
        betas ((10,) tensor, optional): Hand shape (zeros by default).
        info (optional): Precomputed :func:`analyse_object` of ``mesh`` (reuse across grasps).
        iterations (int): Adam refinement iterations (0 disables the refinement).
        contact_threshold (float): Metres; vertices within it count as contacts.
        check_stability (bool): Also run :func:`easyhoi.metrics.simulation_displacement` (35 steps)
            with gravity along the palm normal (palm facing down: the fingers alone must hold the
            object). Slow on curved objects (V-HACD decomposition).
        w_pen, w_att, w_reg (float): Refinement loss weights.
        attempts (int): Approaches tried at most: a grasp is accepted at once when no vertex is more
            than 2 mm inside and the grasp type's required digits touch; otherwise the best of the
            attempts (penetration in mm + 3 per missing digit) is returned.

    Returns:
        Grasp
    """
    if grasp_type not in GRASP_TYPES:
        raise InvalidInputError(f"grasp_type must be one of {GRASP_TYPES}, got {grasp_type!r}")
    if not isinstance(attempts, int) or attempts < 1:
        raise InvalidInputError(f"attempts must be a positive integer, got {attempts!r}")
    start = time.perf_counter()
    rng = np.random.default_rng([seed, GRASP_TYPES.index(grasp_type), 4099])
    info = info if info is not None else analyse_object(mesh, seed=seed)
    betas = torch.zeros(10, dtype=torch.float64) if betas is None else torch.as_tensor(betas)
    poser = HandPoser(model, betas)
    opened, closed = synergy(model, grasp_type)
    part = model.regions.vertex_part.numpy()
    best = None
    for _ in range(attempts):
        R, T, back = _approach(info, poser, opened, closed, grasp_type, rng)
        Rt = torch.as_tensor(R)
        with torch.no_grad():
            canon = poser.canonical(torch.as_tensor(opened.reshape(1, 45)))[0]
        T = _back_off(info.grid, canon, Rt, torch.as_tensor(T), back, tol=0.0005)
        Tt = torch.as_tensor(T)
        pose_c = _close(poser, info.grid, opened, closed, _closing_digits(grasp_type), Rt, Tt,
                        num_steps=40, contact_tol=0.0015)  # fmt: skip
        pose0 = torch.as_tensor(pose_c.reshape(45))
        pose, Rt, Tt = _refine(poser, mesh, pose0, Rt, Tt, _pad_groups(model, grasp_type),
                               iterations, w_pen, w_att, w_reg)  # fmt: skip
        params = poser.params(pose, Rt, Tt)
        with torch.no_grad():
            out = model(params)
        verts = out.vertices[0].double().numpy()
        faces = out.faces.numpy().astype(np.int64)
        d = exact_signed_distance(mesh, verts)
        close = d <= contact_threshold
        touching = [n for n, js in DIGIT_JOINTS.items() if close[np.isin(part, js)].any()]
        if close[part == 0].any():
            touching.append("palm")
        missing = len(_REQUIRED[grasp_type] - set(touching))
        score = max(-float(d.min()), 0.0) * 1000 + 3.0 * missing  # mm + 3 per missing digit
        if best is None or score < best[0]:
            best = (score, params, verts, faces, close, tuple(touching), Rt)
        if score <= 2.0:
            break
    _, params, verts, faces, close, touching, Rt = best
    pen = penetration_depth((verts, faces), mesh)
    seconds = time.perf_counter() - start
    stability = None
    if check_stability:
        from easyhoi.metrics.simulation import simulation_displacement

        palm_down = Rt.numpy() @ np.array([0.0, -1.0, 0.0])  # pulls the object out of the palm
        sim = simulation_displacement((verts, faces), mesh, gravity_dir=palm_down)
        stability = float(sim.displacement)
    return Grasp(params, verts, faces, grasp_type, pen, int(close.sum()), touching, stability,
                 seconds)  # fmt: skip


__all__ = ["GRASP_TYPES", "Grasp", "analyse_object", "frame_rotation", "synthesize_grasp"]
