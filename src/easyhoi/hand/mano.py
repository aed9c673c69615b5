"""MANO, from a model file the user supplies (MANO is licensed and never shipped).

Get ``MANO_RIGHT.pkl`` by registering at https://mano.is.tue.mpg.de (non-commercial research
licence), then pass its path or folder (``--mano-dir`` on the command line) or set the
environment variable ``EASYHOI_MANO_DIR``. The file is read with a restricted unpickler
(:mod:`easyhoi.hand.safe_pickle`): chumpy is not needed and nothing in the file is executed.

The forward pass is MANO's: shape blend shapes, joints regressed from the shaped template,
pose-corrective blend shapes driven by ``(R_j - I)`` of the 15 finger joints (135 features),
then linear blend skinning (:class:`~easyhoi.hand.base.HandModel`). The mesh used for inside
tests is closed: MANO's single wrist opening is closed by a fan over its boundary loop
(1538 -> 1552 faces, no new vertex); the open mesh is kept as ``faces_open``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand.base import TIP_ORDER, HandModel
from easyhoi.hand.safe_pickle import load_mano_pickle
from easyhoi.structures import JOINT_PARENTS, NUM_BETAS, NUM_JOINTS, NUM_POSE, HandParams

__all__ = [
    "MANOHand",
    "MANONotFoundError",
    "MANO_ENV_VAR",
    "FINGERTIP_CONVENTIONS",
    "find_mano_file",
    "validate_mano_data",
    "left_to_right_mano",
    "close_boundary_loops",
]

MANO_ENV_VAR = "EASYHOI_MANO_DIR"
NUM_VERTICES = 778
NUM_FACES = 1538

#: Fingertip vertex ids (thumb, index, middle, ring, pinky) of the two common conventions.
FINGERTIP_CONVENTIONS: dict[str, tuple[int, ...]] = {
    "smplx": (744, 320, 443, 554, 671),
    "alternate": (745, 317, 444, 556, 673),
}

_SCHEMA: dict[str, tuple[int, ...]] = {
    "v_template": (NUM_VERTICES, 3),
    "shapedirs": (NUM_VERTICES, 3, NUM_BETAS),
    "posedirs": (NUM_VERTICES, 3, 135),
    "J_regressor": (NUM_JOINTS, NUM_VERTICES),
    "weights": (NUM_VERTICES, NUM_JOINTS),
    "kintree_table": (2, NUM_JOINTS),
    "f": (NUM_FACES, 3),
    "hands_components": (NUM_POSE, NUM_POSE),
    "hands_mean": (NUM_POSE,),
}

_HOW_TO = (
    "MANO is licensed and not shipped with easyhoi: register at https://mano.is.tue.mpg.de, "
    "download the MANO model, then pass the folder holding MANO_RIGHT.pkl (--mano-dir on the "
    f"command line, path= in Python) or set the environment variable {MANO_ENV_VAR}"
)


class MANONotFoundError(InvalidInputError):
    """No MANO model file where one was asked for; the message says how to supply one."""


def find_mano_file(path: str | Path | None = None) -> Path:
    """Locate a MANO pickle.

    Args:
        path (str, Path or None): A ``.pkl`` file, or a folder holding ``MANO_RIGHT.pkl`` (or
            ``MANO_LEFT.pkl``), directly or under ``models/``. ``None`` reads the folder from
            ``$EASYHOI_MANO_DIR``.

    Raises:
        MANONotFoundError: Nothing found; the message explains how to obtain and pass the file.
    """
    if path is None:
        env = os.environ.get(MANO_ENV_VAR, "").strip()
        if not env:
            raise MANONotFoundError(
                f"no MANO model given and ${MANO_ENV_VAR} is not set. {_HOW_TO}"
            )
        path = env
    path = Path(path).expanduser()
    if path.is_file():
        return path
    if path.is_dir():
        for sub in (path, path / "models"):
            for name in ("MANO_RIGHT.pkl", "MANO_LEFT.pkl"):
                if (sub / name).is_file():
                    return sub / name
        raise MANONotFoundError(f"the folder {path} holds no MANO_RIGHT.pkl. {_HOW_TO}")
    raise MANONotFoundError(f"the MANO model {path} does not exist. {_HOW_TO}")


def validate_mano_data(data: dict, source: str = "MANO file") -> dict[str, np.ndarray]:
    """Check a loaded MANO dictionary against the schema and return float64 / int64 arrays.

    ``J_regressor`` may be a scipy sparse matrix (as in the real files) or dense; it is
    returned dense. Raises :class:`InvalidInputError` naming the key that is missing or
    malformed.
    """
    out: dict[str, np.ndarray] = {}
    for key, shape in _SCHEMA.items():
        if key not in data:
            raise InvalidInputError(f"{source} lacks the key {key!r}; is it a MANO model file?")
        value = data[key]
        value = value.toarray() if sp.issparse(value) else value
        try:
            arr = np.asarray(value)
        except Exception:  # noqa: BLE001
            arr = np.asarray(None)
        if arr.dtype.kind not in "biuf":
            raise InvalidInputError(f"{source}: {key!r} is not numeric (got {type(value)})")
        if arr.shape != shape:
            raise InvalidInputError(f"{source}: {key!r} must have shape {shape}, got {arr.shape}")
        if not np.isfinite(arr.astype(np.float64)).all():
            raise InvalidInputError(f"{source}: {key!r} contains NaN or infinite values")
        out[key] = arr.astype(np.int64 if key in ("f", "kintree_table") else np.float64)
    parents = tuple(int(p) for p in out["kintree_table"][0, 1:])
    if parents != JOINT_PARENTS[1:]:
        raise InvalidInputError(
            f"{source}: kintree_table parents {parents} differ from MANO's {JOINT_PARENTS[1:]}"
        )
    if out["f"].min() < 0 or out["f"].max() >= NUM_VERTICES:
        raise InvalidInputError(f"{source}: faces index vertices outside [0, {NUM_VERTICES})")
    return out


def left_to_right_mano(data: dict[str, np.ndarray], fix_shapedirs: bool = True) -> dict:
    """Convert a validated MANO_LEFT dictionary into the equivalent right-hand model.

    The left model is mirrored through x -> -x: template x negated, faces reversed, pose
    correctives and pose PCA conjugated by ``M = diag(-1, 1, 1)``. A pose feature entry
    ``(R - I)[a, b]`` of the left hand equals ``m_a m_b`` times the right one, and an offset's
    coordinate ``c`` changes sign with ``m_c``. The released MANO_LEFT ``shapedirs`` carry the
    wrong sign on x (docs/method.md section 5): the corrected left directions have x negated and
    mirroring negates x again, so with ``fix_shapedirs`` (the released files) they are kept
    as stored; pass ``False`` for a file whose shapedirs were already corrected.
    """
    m = np.array([-1.0, 1.0, 1.0])
    feat_sign = np.tile(np.outer(m, m).ravel(), 15)  # (135,)
    flip = np.tile(np.array([1.0, -1.0, -1.0]), 15)  # axis-angle conjugation by M
    out = dict(data)
    out["v_template"] = data["v_template"] * m
    out["shapedirs"] = data["shapedirs"] if fix_shapedirs else data["shapedirs"] * m[:, None]
    out["posedirs"] = data["posedirs"] * m[:, None] * feat_sign
    out["f"] = data["f"][:, [0, 2, 1]]
    out["hands_components"] = data["hands_components"] * flip
    out["hands_mean"] = data["hands_mean"] * flip
    return out


def close_boundary_loops(faces: np.ndarray) -> tuple[np.ndarray, list[list[int]]]:
    """Close every opening of a consistently wound triangle mesh with a vertex fan.

    Boundary edges are the edges used by one face; following them in the faces' direction
    gives each opening's loop ``l_0 .. l_{n-1}`` (started at its smallest vertex). Its fan
    ``(l_0, l_{i+1}, l_i)`` for ``i = 1 .. n-2`` traverses every boundary edge backwards, so the
    added ``n - 2`` faces have the winding of the rest of the mesh.

    Returns:
        closed: (F + sum(n - 2), 3) int64, the input faces followed by the fans.
        loops: the boundary loops (vertex ids in boundary-edge order).
    """
    faces = np.asarray(faces, dtype=np.int64)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    uniq, counts = np.unique(directed, axis=0, return_counts=True)
    if (counts > 1).any():
        raise InvalidInputError(
            "the mesh's winding is inconsistent or non-manifold (a directed edge is used twice)"
        )
    present = {(int(a), int(b)) for a, b in uniq}
    nxt: dict[int, int] = {}
    for a, b in present:
        if (b, a) not in present:
            if a in nxt:
                raise InvalidInputError(f"the mesh boundary is not a set of simple loops at {a}")
            nxt[a] = b
    loops: list[list[int]] = []
    todo = set(nxt)
    while todo:
        start = min(todo)
        loop = [start]
        todo.discard(start)
        v = nxt[start]
        while v != start:
            if v not in todo:
                raise InvalidInputError(f"the mesh boundary is not a set of simple loops at {v}")
            loop.append(v)
            todo.discard(v)
            v = nxt[v]
        loops.append(loop)
    fans = [(loop[0], loop[i + 1], loop[i]) for loop in loops for i in range(1, len(loop) - 1)]
    closed = np.concatenate([faces, np.asarray(fans, dtype=np.int64).reshape(-1, 3)])
    return closed, loops


def _resolve_tips(tips: str | Sequence[int]) -> tuple[int, ...]:
    if isinstance(tips, str):
        if tips not in FINGERTIP_CONVENTIONS:
            raise InvalidInputError(
                f"unknown fingertip convention {tips!r}; use one of "
                f"{sorted(FINGERTIP_CONVENTIONS)} or 5 vertex ids ({', '.join(TIP_ORDER)})"
            )
        return FINGERTIP_CONVENTIONS[tips]
    ids = tuple(int(i) for i in tips)
    if len(ids) != 5 or min(ids) < 0 or max(ids) >= NUM_VERTICES:
        raise InvalidInputError(f"fingertip ids must be 5 vertex ids in [0, 778), got {ids}")
    return ids


class MANOHand(HandModel):
    """The MANO hand model, read from a user-supplied file (right hands; left by mirroring).

    Args:
        path (str, Path or None): ``MANO_RIGHT.pkl`` (or ``MANO_LEFT.pkl``, converted to the right
            model), a folder holding it, or ``None`` to use ``$EASYHOI_MANO_DIR``.
        flat_hand_mean (bool): True (default): ``HandParams.pose`` is relative to the flat hand.
            False: MANO's ``hands_mean`` is added to it (the pose is relative to the mean hand).
        tips (str or sequence of 5 ints): Fingertip vertices (thumb, index, middle, ring, pinky):
            ``"smplx"`` (744, 320, 443, 554, 671; default), ``"alternate"`` (745, 317, 444, 556,
            673) or explicit ids.
        side ("right", "left" or None): Which hand the file holds; ``None`` guesses from the file
            name ("LEFT" -> left).
        fix_left_shapedirs (bool): For a left file, whether its shapedirs have MANO_LEFT's x-sign
            error (see :func:`left_to_right_mano`).

    Buffers: ``v_template`` (778, 3), ``shapedirs`` (778, 3, 10), ``posedirs`` (135, 2334),
    ``J_regressor`` (16, 778) dense, ``skin_weights`` (778, 16), ``faces`` (1552, 3) closed,
    ``faces_open`` (1538, 3), ``tip_vertex_ids`` (5,), ``hands_components`` (45, 45),
    ``hands_mean`` (45,); float buffers are float64 and cast to the parameters' dtype.
    """

    name = "mano"

    def __init__(
        self,
        path: str | Path | None = None,
        *,
        flat_hand_mean: bool = True,
        tips: str | Sequence[int] = "smplx",
        side: str | None = None,
        fix_left_shapedirs: bool = True,
    ):
        super().__init__()
        file = find_mano_file(path)
        if side is None:
            side = "left" if "left" in file.name.lower() else "right"
        if side not in ("right", "left"):
            raise InvalidInputError(f"side must be 'right', 'left' or None, got {side!r}")
        data = validate_mano_data(load_mano_pickle(file), source=str(file))
        if side == "left":
            data = left_to_right_mano(data, fix_shapedirs=fix_left_shapedirs)
        self.source = file
        self.source_side = side
        self.flat_hand_mean = bool(flat_hand_mean)
        closed, loops = close_boundary_loops(data["f"])
        self.boundary_loops = loops
        f64 = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
        self.register_buffer("v_template", f64(data["v_template"]))
        self.register_buffer("shapedirs", f64(data["shapedirs"]))
        posedirs = data["posedirs"].reshape(NUM_VERTICES * 3, 135).T.copy()
        self.register_buffer("posedirs", f64(posedirs))
        self.register_buffer("J_regressor", f64(data["J_regressor"]))
        self.register_buffer("skin_weights", f64(data["weights"]))
        self.register_buffer("faces", torch.as_tensor(closed, dtype=torch.long))
        self.register_buffer("faces_open", torch.as_tensor(data["f"], dtype=torch.long))
        self.register_buffer("tip_vertex_ids", torch.tensor(_resolve_tips(tips)))
        self.register_buffer("hands_components", f64(data["hands_components"]))
        self.register_buffer("hands_mean", f64(data["hands_mean"]))

    # -- HandModel hooks ----------------------------------------------------------------------
    def shaped(self, betas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Shaped rest pose: (B, 10) betas -> vertices (B, 778, 3), joints (B, 16, 3)."""
        dt = betas.dtype
        verts = self.v_template.to(dt) + torch.einsum("bl,vcl->bvc", betas, self.shapedirs.to(dt))
        joints = torch.einsum("jv,bvc->bjc", self.J_regressor.to(dt), verts)
        return verts, joints

    def pose_offsets(self, rotmats: torch.Tensor) -> torch.Tensor:
        """Pose correctives (B, 778, 3) from (B, 16, 3, 3) rotations: ``posedirs @ (R_j - I)``."""
        B = rotmats.shape[0]
        eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
        feat = (rotmats[:, 1:] - eye).reshape(B, 135)
        return (feat @ self.posedirs.to(rotmats.dtype)).reshape(B, NUM_VERTICES, 3)

    def forward(self, params: HandParams, vertex_ids: torch.Tensor | None = None):
        """Pose the hand (see :meth:`HandModel.forward`); adds ``hands_mean`` unless flat."""
        if not self.flat_hand_mean and isinstance(params, HandParams):
            mean = self._side_pose(self.hands_mean.to(params.pose.dtype)[None], params.side)
            params = replace(params, pose=params.pose + mean)
        return super().forward(params, vertex_ids)

    # -- pose PCA -----------------------------------------------------------------------------
    @staticmethod
    def _side_pose(pose: torch.Tensor, side: str) -> torch.Tensor:
        if side == "right":
            return pose
        flip = torch.tensor([1.0, -1.0, -1.0], dtype=pose.dtype, device=pose.device)
        return (pose.reshape(-1, 15, 3) * flip).reshape(-1, NUM_POSE)

    def pose_from_pca(self, coeffs: torch.Tensor, side: str = "right") -> torch.Tensor:
        """Articulation from MANO's pose PCA.

        Args:
            coeffs: (B, k) tensor, ``1 <= k <= 45``, coefficients of the first k components.
            side: the hand the pose is for (left poses are mirrored components).

        Returns:
            (B, 45) ``HandParams.pose`` for this model: ``coeffs @ hands_components[:k]``. With
            ``flat_hand_mean=False`` the forward pass adds ``hands_mean``, as MANO does for PCA
            poses; with the default flat mean the components act around the flat hand.
        """
        coeffs = torch.as_tensor(coeffs)
        if coeffs.ndim != 2 or not 1 <= coeffs.shape[1] <= NUM_POSE:
            raise InvalidInputError(
                f"PCA coefficients must be (B, k<=45), got {tuple(coeffs.shape)}"
            )
        k = coeffs.shape[1]
        pose = coeffs @ self.hands_components[:k].to(coeffs.dtype)
        return self._side_pose(pose, side)

    def pca_from_pose(self, pose: torch.Tensor, k: int = NUM_POSE, side: str = "right"):
        """Least-squares inverse of :meth:`pose_from_pca`: (B, 45) pose -> (B, k) coefficients."""
        pose = torch.as_tensor(pose)
        if pose.ndim != 2 or pose.shape[1] != NUM_POSE or not 1 <= k <= NUM_POSE:
            raise InvalidInputError(f"pose must be (B, 45) and 1 <= k <= 45, got {pose.shape}, {k}")
        comps = self.hands_components[:k].to(pose.dtype)  # (k, 45)
        sol = torch.linalg.lstsq(comps.T, self._side_pose(pose, side).T)
        return sol.solution.T
