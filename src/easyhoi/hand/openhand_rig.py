"""Rigging of the OpenHand rest mesh: skin weights, fingertips, shape basis, joint regressor.

Everything here is a deterministic function of the rest mesh and the skeleton of
:mod:`easyhoi.hand.openhand_build`.

Skin weights
    Every joint owns one or more bone segments: a digit joint the segment to its child joint
    (the distal joint: to the fingertip), the wrist the segments from the wrist to the five digit
    bases plus a short stub behind the wrist. With ``d_j`` the distance of a vertex to joint
    ``j``'s segments, ``w_j ∝ exp(-d_j² / (2 σ²))`` (σ = 6 mm), normalised, entries below 1e-3
    dropped. Across a joint the weight of the two adjacent bones then blends like a Gaussian of
    the axial offset from the joint (width σ), independent of the local radius.

Shape basis (``shapedirs``, (V, 3, 10), one unit = 5 % of the quantity)
    0 overall size (scaling about the wrist); 1 digit length (each digit stretched along its
    axis from its base, palm unchanged); 2 palm width (palm spread across the hand about the
    centre line, digits translated with their bases); 3 finger thickness (radial scaling about
    each digit bone); 4 palm thickness (palm scaled along the palm normal); 5 thumb length;
    6-9 no effect (reserved, kept for MANO's layout). Each field is blended by the skin weights,
    so it is smooth across joints.

Joint regressor (16, V)
    Joint ``j`` is an affine combination of the vertices in a thin slab across its bone at the
    joint (those skinned to the joint, its parent or its child and close to the axis): the
    weights closest to uniform that reproduce the rest joint exactly. Joints then follow every
    shape direction that is locally affine (all of the above), so ``J = J_regressor @ v`` stays
    inside the fingers.
"""

from __future__ import annotations

import numpy as np

from easyhoi.errors import BackendError
from easyhoi.hand.openhand_build import DIGIT_JOINTS, DIGITS, Digit
from easyhoi.structures import JOINT_PARENTS

SKIN_SIGMA = 0.006
SHAPE_STEP = 0.05
TIP_DIGITS = ("thumb", "index", "middle", "ring", "pinky")  # base.TIP_ORDER


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def bone_segments(joints: np.ndarray, tips: dict[str, np.ndarray]) -> list[list[tuple]]:
    """Segments owned by each of the 16 joints (list of (a, b) point pairs)."""
    segs: list[list[tuple]] = [[] for _ in range(16)]
    segs[0].append((np.array([0.012, 0.0, 0.0]), joints[0]))
    for name in DIGITS:
        j0, j1, j2 = DIGIT_JOINTS[name]
        segs[0].append((joints[0], joints[j0]))
        segs[j0].append((joints[j0], joints[j1]))
        segs[j1].append((joints[j1], joints[j2]))
        segs[j2].append((joints[j2], tips[name]))
    return segs


def skin_weights(
    vertices: np.ndarray, joints: np.ndarray, tips: dict[str, np.ndarray]
) -> np.ndarray:
    """(V, 16) linear-blend-skinning weights, rows summing to 1 (see module docstring)."""
    segs = bone_segments(joints, tips)
    d = np.stack(
        [np.min([_segment_distance(vertices, a, b) for a, b in s], axis=0) for s in segs], axis=1
    )
    logits = -(d**2) / (2 * SKIN_SIGMA**2)
    w = np.exp(logits - logits.max(axis=1, keepdims=True))
    w /= w.sum(axis=1, keepdims=True)
    w[w < 1e-3] = 0.0
    return w / w.sum(axis=1, keepdims=True)


def tip_vertex_ids(
    vertices: np.ndarray, weights: np.ndarray, joints: np.ndarray, tips: dict[str, np.ndarray]
) -> np.ndarray:
    """(5,) the vertex farthest along each distal bone among the vertices it dominates."""
    part = weights.argmax(axis=1)
    ids = []
    for name in TIP_DIGITS:
        j = DIGIT_JOINTS[name][2]
        axis = tips[name] - joints[j]
        axis /= np.linalg.norm(axis)
        cand = np.nonzero(part == j)[0]
        if len(cand) == 0:
            raise BackendError(f"no OpenHand vertex is skinned to the {name} distal bone")
        ids.append(cand[np.argmax((vertices[cand] - joints[j]) @ axis)])
    return np.asarray(ids, dtype=np.int64)


def shape_basis(
    vertices: np.ndarray,
    weights: np.ndarray,
    skeleton: dict[str, Digit],
    joints: np.ndarray,
    tips: dict[str, np.ndarray],
) -> np.ndarray:
    """(V, 3, 10) displacement per unit shape coefficient (see module docstring)."""
    V = len(vertices)
    basis = np.zeros((V, 3, 10))
    basis[:, :, 0] = vertices
    digit_w = {n: weights[:, list(DIGIT_JOINTS[n])].sum(axis=1) for n in DIGITS}
    bases = {n: np.asarray(skeleton[n].base) for n in DIGITS}
    axes = {n: (tips[n] - bases[n]) / np.linalg.norm(tips[n] - bases[n]) for n in DIGITS}
    for n in DIGITS:
        along = ((vertices - bases[n]) @ axes[n])[:, None] * axes[n]
        basis[:, :, 1] += digit_w[n][:, None] * along
        if n == "thumb":
            basis[:, :, 5] += digit_w[n][:, None] * along
    zc = 0.5 * (bases["middle"][2] + bases["ring"][2])
    basis[:, 2, 2] = weights[:, 0] * (vertices[:, 2] - zc)
    for n in DIGITS:
        basis[:, 2, 2] += digit_w[n] * (bases[n][2] - zc)
    for n in DIGITS:
        for k, j in enumerate(DIGIT_JOINTS[n]):
            end = joints[DIGIT_JOINTS[n][k + 1]] if k < 2 else tips[n]
            a = (end - joints[j]) / np.linalg.norm(end - joints[j])
            rel = vertices - joints[j]
            radial = rel - (rel @ a)[:, None] * a
            basis[:, :, 3] += weights[:, j, None] * radial
    basis[:, 1, 4] = weights[:, 0] * (vertices[:, 1] + 0.0015)
    return SHAPE_STEP * basis


def joint_regressor(
    vertices: np.ndarray, weights: np.ndarray, joints: np.ndarray, tips: dict[str, np.ndarray]
) -> np.ndarray:
    """(16, V) affine vertex combinations reproducing the rest joints (see module docstring)."""
    part = weights.argmax(axis=1)
    children = {j: [c for c, p in enumerate(JOINT_PARENTS) if p == j] for j in range(16)}
    thumb = set(DIGIT_JOINTS["thumb"])
    reg = np.zeros((16, len(vertices)))
    for j in range(16):
        if j == 0:
            axis = np.array([-1.0, 0.0, 0.0])
            family = {0}
            radius = np.inf
        else:
            nxt = joints[children[j][0]] if children[j] else tips[_digit_of(j)]
            axis = (nxt - joints[j]) / np.linalg.norm(nxt - joints[j])
            family = {j, JOINT_PARENTS[j], *children[j]}
            radius = 0.022 if j in thumb else 0.016
        rel = vertices - joints[j]
        axial = rel @ axis
        radial = np.linalg.norm(rel - axial[:, None] * axis, axis=1)
        ok_part = np.isin(part, list(family)) & (radial < radius)
        for h in (0.003, 0.005, 0.008, 0.012):
            sel = np.nonzero(ok_part & (np.abs(axial) < h))[0]
            if len(sel) >= 12:
                break
        else:
            raise BackendError(f"too few OpenHand vertices around joint {j} for its regressor")
        A = np.vstack([vertices[sel].T, np.ones(len(sel))])  # (4, n)
        b = np.append(joints[j], 1.0)
        u = np.full(len(sel), 1.0 / len(sel))
        reg[j, sel] = u + A.T @ np.linalg.solve(A @ A.T, b - A @ u)
    return reg


def _digit_of(j: int) -> str:
    return next(n for n in DIGITS if j in DIGIT_JOINTS[n])
