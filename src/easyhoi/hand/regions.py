"""Hand region labels derived geometrically from any MANO-layout hand model.

Only the model's rest mesh (zero pose, zero shape), skin weights, rest joints and fingertip
vertices are used, so the same derivation serves the built-in OpenHand and a user's MANO.

Derivation
    1. Palm frame from the rest joints: finger direction ``f`` = wrist -> middle1, lateral
       direction ``l`` = pinky1 -> index1 (towards the thumb), palm normal ``n`` = the normal of
       the least-squares plane through the wrist and the four finger bases, oriented as
       ``l x f`` (for a right hand that side is the palm; for MANO's frame ``n ~ -y``).
    2. Palmar direction of every bone (joint j -> its child, the distal bones -> fingertip):
       for the four fingers ``n`` made orthogonal to the bone; for the thumb (which is rotated
       out of the palm plane) the sum of ``n`` and the direction from the thumb joint towards
       the index base, both made orthogonal to the thumb bone: the pad of an opposable thumb
       faces between the palm normal and the index finger. The wrist uses ``n``.
    3. ``palmar_faces``: a face is palmar when its rest normal points along the palmar
       direction of its dominant bone (largest summed skin weight of its three vertices).
    4. ``contact_vertices`` (the ObMan notion of contact zones, ~15 % of the vertices): per
       digit the ``round(1.8 % V)`` vertices of its middle and distal segments whose normals
       point most along the bone's palmar direction (finger pads), and the palm-centre vertices
       (wrist-dominated, normal within 60 degrees of ``n``) nearest, in the palm plane, to the
       palm centre ``0.4 * wrist + 0.6 * mean(finger bases)``, filling up to ``round(15 % V)``.
       For MANO's 778 vertices that is 5 x 14 pad vertices + 47 palm vertices = 117.
    5. ``tip_vertices`` are the model's fingertip ids; ``vertex_part`` the argmax of the skin
       weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.structures import HandParams

if TYPE_CHECKING:  # the model type only: base.py imports this module
    from easyhoi.hand.base import HandModel


@dataclass(frozen=True)
class HandRegions:
    """Fixed labels on a hand model's closed mesh.

    Attributes:
        palmar_faces: (F,) bool, True for faces on the palm / finger-pad side (ray hits on the
            other, dorsal side are discarded by the contact stage).
        contact_vertices: (C,) long, the contact zones (finger pads and palm, the ObMan notion).
        tip_vertices: (5,) long, fingertip vertices (thumb, index, middle, ring, pinky).
        vertex_part: (V,) long, the joint (0..15) that dominates each vertex's skinning.
    """

    palmar_faces: torch.Tensor
    contact_vertices: torch.Tensor
    tip_vertices: torch.Tensor
    vertex_part: torch.Tensor


#: Joint ids of the five digits (base, middle, distal joint), MANO order.
DIGIT_JOINTS = {"thumb": (13, 14, 15), "index": (1, 2, 3), "middle": (4, 5, 6),
                "ring": (10, 11, 12), "pinky": (7, 8, 9)}  # fmt: skip
_FINGER_BASES = (1, 4, 10, 7)
CONTACT_FRACTION = 0.15
PAD_FRACTION = 0.018


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True).clip(1e-12)


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return v - (v @ axis) * axis


def rest_geometry(model: HandModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rest vertices (V, 3), faces (F, 3), skin weights (V, 16) and joints (16, 3) as float64."""
    with torch.no_grad():
        betas = torch.zeros(1, 10, dtype=torch.float64, device=model.faces.device)
        v, j = model.shaped(betas)
    return (
        v[0].double().cpu().numpy(),
        model.faces.cpu().numpy().astype(np.int64),
        model.skin_weights.detach().double().cpu().numpy(),
        j[0].double().cpu().numpy(),
    )


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of a mesh."""
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return _unit(vn)


def palm_frame(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finger direction ``f``, lateral direction ``l`` (towards the thumb), palmar normal ``n``."""
    f = _unit(joints[4] - joints[0])
    lat = _unit(_perp(joints[1] - joints[7], f))
    pts = joints[[0, *_FINGER_BASES]]
    _, _, vt = np.linalg.svd(pts - pts.mean(axis=0))
    n = vt[2]
    if n @ np.cross(lat, f) < 0:
        n = -n
    return f, lat, n


def bone_axes(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """(16, 3) unit bone directions (joint -> child; distal -> fingertip; wrist -> middle1).

    Args:
        joints: (16, 3) rest joints. tips: (5, 3) fingertip positions (thumb..pinky).
    """
    axes = np.zeros((16, 3))
    axes[0] = joints[4] - joints[0]
    for k, (a, b, c) in enumerate(DIGIT_JOINTS.values()):
        axes[a] = joints[b] - joints[a]
        axes[b] = joints[c] - joints[b]
        axes[c] = tips[k] - joints[c]
    return _unit(axes)


def palmar_directions(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """(16, 3) unit palmar (pad) direction of every bone, orthogonal to the bone (step 2)."""
    _, _, n = palm_frame(joints)
    axes = bone_axes(joints, tips)
    out = np.zeros((16, 3))
    out[0] = n
    for j in range(1, 16):
        d = _unit(_perp(n, axes[j]))
        if j in DIGIT_JOINTS["thumb"]:
            d = d + _unit(_perp(joints[1] - joints[j], axes[j]))
        out[j] = _unit(_perp(d, axes[j]))
    return out


def flexion_axes(model: HandModel) -> np.ndarray:
    """(15, 3) rest-frame rotation axes (joints 1..15) along which a positive angle flexes.

    ``bone x palmar``: rotating a bone about it moves the bone's far end towards the palmar side.
    For the four fingers of OpenHand and MANO this is close to +z.
    """
    verts, _, _, joints = rest_geometry(model)
    tips = verts[model.tip_vertex_ids.cpu().numpy()]
    return _unit(np.cross(bone_axes(joints, tips), palmar_directions(joints, tips)))[1:]


def compute_regions(model: HandModel) -> HandRegions:
    """Palmar faces, contact vertices, fingertips and vertex parts of a hand model.

    Args:
        model: a MANO-layout :class:`~easyhoi.hand.base.HandModel` (right hand).
    Returns:
        :class:`HandRegions` (see the module docstring for the derivation).
    """
    verts, faces, weights, joints = rest_geometry(model)
    if weights.shape != (len(verts), 16):
        raise InvalidInputError(f"skin weights must be (V, 16), got {weights.shape}")
    tip_ids = model.tip_vertex_ids.cpu().numpy().astype(np.int64)
    tips = verts[tip_ids]
    pdir = palmar_directions(joints, tips)
    _, _, n = palm_frame(joints)

    tri = verts[faces]
    fnorm = _unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    face_part = weights[faces].sum(axis=1).argmax(axis=1)
    palmar = np.einsum("fc,fc->f", fnorm, pdir[face_part]) > 0

    part = weights.argmax(axis=1)
    vnorm = vertex_normals(verts, faces)
    score = np.einsum("vc,vc->v", vnorm, pdir[part])
    V = len(verts)
    target = int(round(CONTACT_FRACTION * V))
    per_digit = int(round(PAD_FRACTION * V))
    chosen: list[np.ndarray] = []
    for b, c in (j[1:] for j in DIGIT_JOINTS.values()):
        cand = np.nonzero(np.isin(part, (b, c)) & (score > 0.3))[0]
        order = np.argsort(-score[cand], kind="stable")
        chosen.append(cand[order[:per_digit]])
    n_pad = sum(len(c) for c in chosen)
    centre = 0.4 * joints[0] + 0.6 * joints[list(_FINGER_BASES)].mean(axis=0)
    cand = np.nonzero((part == 0) & (vnorm @ n > 0.5))[0]
    rel = verts[cand] - centre
    planar = np.linalg.norm(rel - np.outer(rel @ n, n), axis=1)
    chosen.append(cand[np.argsort(planar, kind="stable")[: max(target - n_pad, 0)]])
    contact = np.unique(np.concatenate(chosen))

    return HandRegions(
        palmar_faces=torch.from_numpy(palmar),
        contact_vertices=torch.from_numpy(contact.astype(np.int64)),
        tip_vertices=torch.from_numpy(tip_ids),
        vertex_part=torch.from_numpy(part.astype(np.int64)),
    )


def grasp_pose(model: HandModel, amount: float = 1.0) -> torch.Tensor:
    """(1, 45) a power-grasp-like pose: every joint flexed about its :func:`flexion_axes`.

    ``amount = 1`` bends the finger joints by 0.5 / 0.8 / 0.5 rad (base / middle / distal) and
    the thumb by 0.3 / 0.4 / 0.4 rad.
    """
    axes = flexion_axes(model)
    angles = np.zeros(15)
    for name, js in DIGIT_JOINTS.items():
        angles[[j - 1 for j in js]] = (0.3, 0.4, 0.4) if name == "thumb" else (0.5, 0.8, 0.5)
    return torch.from_numpy((axes * (amount * angles)[:, None]).reshape(1, 45))


def _draw(ax, verts, faces, colours, rot, points=()):
    """Painter's-algorithm orthographic render of a mesh onto a matplotlib axis."""
    from matplotlib.collections import PolyCollection

    p = verts @ rot.T
    tri = p[faces]
    fn = _unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    order = np.argsort(tri[:, :, 2].mean(axis=1), kind="stable")
    order = order[fn[order, 2] > 0]
    shade = 0.45 + 0.55 * np.clip(fn[order] @ _unit(np.array([0.3, 0.4, 0.85])), 0, 1)
    cols = np.clip(colours[order] * shade[:, None], 0, 1)
    ax.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=cols, edgecolors="none"))
    vn = vertex_normals(verts, faces) @ rot.T
    for ids, style, front_only in points:
        ids = ids[vn[ids, 2] > 0.1] if front_only else ids
        ax.plot(p[ids, 0], p[ids, 1], style, markersize=3 if style.endswith(".") else 8)
    ax.set_xlim(p[:, 0].min() - 0.01, p[:, 0].max() + 0.01)
    ax.set_ylim(p[:, 1].min() - 0.01, p[:, 1].max() + 0.01)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def plot_regions(model: HandModel, path: str | Path) -> Path:
    """Render the region labels to a PNG: rest hand from the palm and the back, and a grasp.

    Palmar faces are orange, dorsal faces blue, contact vertices red dots, fingertips black
    stars. Views are orthographic in the model's frame (palm normal towards the viewer).

    Args:
        model: a MANO-layout hand model. path: output ``.png`` path (folders are created).
    Returns:
        the written path.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    reg = model.regions
    verts, faces, _, joints = rest_geometry(model)
    f, lat, n = palm_frame(joints)
    colours = np.where(reg.palmar_faces.numpy()[:, None], [1.0, 0.6, 0.25], [0.35, 0.5, 0.85])
    marks = ((reg.contact_vertices.numpy(), "r.", True), (reg.tip_vertices.numpy(), "k*", False))
    palm_view = np.stack([f, np.cross(n, f), n])  # rows: image right, image up, to the viewer
    back_view = np.stack([f, np.cross(-n, f), -n])
    params = HandParams(
        torch.zeros(1, 3, dtype=torch.float64),
        torch.zeros(1, 3, dtype=torch.float64),
        grasp_pose(model),
    )
    with torch.no_grad():
        posed = model(params).vertices[0].double().numpy()
    u = _unit(f + 0.6 * lat)
    tilt = np.stack([u, np.cross(n, u), n])
    fig, axs = plt.subplots(1, 3, figsize=(15, 5))
    _draw(axs[0], verts, faces, colours, palm_view, marks)
    _draw(axs[1], verts, faces, colours, back_view, marks)
    _draw(axs[2], posed, faces, colours, tilt, marks)
    titles = ("rest, palm side", "rest, back", "grasp pose, palm side")
    for ax, title in zip(axs, titles, strict=True):
        ax.set_title(title)
    fig.suptitle(
        f"{model.name}: {int(reg.palmar_faces.sum())}/{len(faces)} palmar faces, "
        f"{len(reg.contact_vertices)} contact vertices"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


__all__ = [
    "DIGIT_JOINTS",
    "bone_axes",
    "compute_regions",
    "flexion_axes",
    "grasp_pose",
    "palm_frame",
    "palmar_directions",
    "plot_regions",
    "vertex_normals",
]
