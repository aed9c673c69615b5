"""Importers for files written by the paper's tools (HaMeR, LISA / SAM masks, image-to-3D meshes).

HaMeR conventions (what :func:`load_hamer_hand` assumes)
--------------------------------------------------------
Per hand, HaMeR predicts MANO parameters as rotation matrices: ``global_orient`` (1, 3, 3),
``hand_pose`` (15, 3, 3), ``betas`` (10,), and a camera translation ``pred_cam_t_full`` (3,)
for the full image under the focal convention ``f = 5000 / 256 * max(W, H)`` with the principal
point at the image centre (:meth:`~easyhoi.structures.Camera.hamer_convention`). Its MANO
layer is a right hand posed with ``flat_hand_mean=True``: ``hand_pose`` is relative to the flat
hand, which is exactly :class:`~easyhoi.structures.HandParams`' ``pose``. A file written with
``flat_hand_mean=False`` must be converted by passing ``pose_offset`` (the 45 MANO
``hands_mean`` values, added to the pose).

The MANO output has no translation: HaMeR places the hand in the camera frame by adding
``cam_t`` to every vertex and joint (the MANO model's own origin, not the wrist, is moved to
``cam_t``). That is the meaning of ``HandParams.transl`` (added to every vertex and joint after
posing), so ``transl = cam_t`` and the returned camera has ``R = I``, ``t = 0``: the hand's
"world" is the camera frame.

Left hands (``is_right == 0``): HaMeR flips the crop, predicts a right hand, then mirrors the
vertices (x -> -x) and adds ``cam_t``, which already refers to the unflipped image. With our
convention ``side="left"`` evaluates ``mirror_x(right_hand(mirror_params(p)))`` (see
:func:`~easyhoi.hand.base.mirror_params`), the equivalent parameters are: axis-angle vectors
mirrored ``(x, y, z) -> (x, -y, -z)`` for the root and every joint, betas unchanged, and
``transl = cam_t`` unchanged. Vertex for vertex:
``hand(left params) == mirror_x(right_hand(HaMeR rotations, transl=0)) + cam_t``.

When a file holds only the crop camera ``pred_cam = (s, tx, ty)`` with ``box_center`` and
``box_size`` (HaMeR's weak perspective in the crop), the full-image translation is derived by
matching the weak perspective to the full perspective at the hand's depth:
``tz = 2 f / (s b)``, ``tx_full = tx' + 2 (cx - W/2) / (s b)``, ``ty_full = ty + 2 (cy - H/2) /
(s b)``, with ``tx' = -tx`` for a left hand (its crop was flipped).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
import trimesh

from easyhoi.errors import InvalidInputError, UnsafeFileError
from easyhoi.geometry.transforms import matrix_to_axis_angle
from easyhoi.hand.base import mirror_params
from easyhoi.structures import Camera, HandParams

#: canonical key -> accepted key names, first match wins (nested dicts are searched too).
HAMER_KEYS: dict[str, tuple[str, ...]] = {
    "global_orient": ("global_orient", "mano_global_orient", "root_orient", "global_orient_rotmat"),
    "hand_pose": ("hand_pose", "mano_hand_pose", "pose", "hand_pose_rotmat"),
    "betas": ("betas", "mano_betas", "shape"),
    "cam_t": ("pred_cam_t_full", "cam_t_full", "cam_t", "camera_translation", "transl"),
    "is_right": ("is_right", "right", "right_hand"),
    "pred_cam": ("pred_cam", "cam_crop"),
    "box_center": ("box_center",),
    "box_size": ("box_size",),
    "img_size": ("img_size", "image_size"),
}

_ROT_TOL = 1e-3


# ----------------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------------


def _read_file(path: Path) -> dict:
    if not path.is_file():
        raise InvalidInputError(f"HaMeR output file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except ValueError as exc:  # object arrays need pickle: refused
            raise UnsafeFileError(
                f"{path} holds pickled objects; only plain numeric arrays are accepted ({exc})"
            ) from None
        except Exception as exc:  # noqa: BLE001 - corrupt archive
            raise InvalidInputError(f"cannot read {path} as .npz: {exc}") from None
    if suffix == ".json":
        try:
            return json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InvalidInputError(f"cannot read {path} as JSON: {exc}") from None
    if suffix in (".pkl", ".pickle"):
        from easyhoi.hand.safe_pickle import load_restricted, to_plain

        try:
            data = to_plain(load_restricted(path, "hand-parameter pickle"))
        except (UnsafeFileError, InvalidInputError):
            raise
        except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt file
            raise InvalidInputError(f"{path} is not a readable pickle ({exc})") from None
        if not isinstance(data, dict):
            raise InvalidInputError(f"{path} must hold a dictionary, got {type(data).__name__}")
        return data
    raise InvalidInputError(f"unsupported HaMeR file type {suffix!r}; use .npz, .json or .pkl")


def _flatten(d: dict, out: dict | None = None, depth: int = 0) -> dict:
    """Nested dicts (``pred_mano_params``) -> one level; top-level keys win."""
    out = {} if out is None else out
    nested = []
    for k, v in d.items():
        if isinstance(v, dict):
            nested.append(v)
        elif str(k) not in out:
            out[str(k)] = v
    if depth < 4:
        for v in nested:
            _flatten(v, out, depth + 1)
    return out


def _get(flat: dict, key: str, required: bool = True):
    for name in HAMER_KEYS[key]:
        if name in flat:
            return flat[name]
    if required:
        raise InvalidInputError(
            f"HaMeR data lacks '{key}' (accepted names: {', '.join(HAMER_KEYS[key])}); "
            f"found keys: {', '.join(sorted(flat)) or 'none'}"
        )
    return None


def _array(x, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"HaMeR '{name}' is not numeric") from None
    if not np.isfinite(a).all():
        raise InvalidInputError(f"HaMeR '{name}' contains NaN or infinite values")
    return a


def _rows(a: np.ndarray, k: int, index: int, name: str) -> np.ndarray:
    """Entry ``index`` of ``a`` read as (num_hands, k) values (any leading batch layout)."""
    if a.size == 0 or a.size % k:
        raise InvalidInputError(f"HaMeR '{name}' must hold {k} values per hand, got {a.shape}")
    rows = a.reshape(-1, k)
    if not -rows.shape[0] <= index < rows.shape[0]:
        raise InvalidInputError(
            f"hand index {index} out of range: '{name}' holds {rows.shape[0]} hand(s)"
        )
    return rows[index]


def _rotations(a: np.ndarray, n: int, index: int, name: str) -> torch.Tensor:
    """``n`` rotations per hand -> (n, 3) float64 axis-angle.

    Matrices when the last two dims are (3, 3) ((n, 3, 3) or (B, n, 3, 3)), axis-angle
    otherwise ((n, 3), (3n,), (B, n, 3), (B, 3n)).
    """
    if a.ndim >= 2 and a.shape[-2:] == (3, 3) and a.size % (9 * n) == 0:
        m = _rows(a, 9 * n, index, name).reshape(n, 3, 3)
        err = float(np.abs(np.swapaxes(m, -1, -2) @ m - np.eye(3)).max())
        if err > _ROT_TOL or (np.linalg.det(m) <= 0).any():
            raise InvalidInputError(
                f"HaMeR '{name}' holds matrices that are not rotations (|R^T R - I| = {err:.2g})"
            )
        return matrix_to_axis_angle(torch.as_tensor(m, dtype=torch.float64))
    aa = _rows(a, 3 * n, index, name).reshape(n, 3)
    return torch.as_tensor(aa, dtype=torch.float64)


def crop_to_full_translation(
    pred_cam: np.ndarray,
    box_center: np.ndarray,
    box_size: float,
    image_size: tuple[int, int],
    focal: float,
    is_right: bool = True,
) -> np.ndarray:
    """Full-image camera translation (3,) from HaMeR's weak-perspective crop camera.

    Args:
        pred_cam: (3,) (s, tx, ty) in the (flipped, for a left hand) crop.
        box_center: (2,) crop centre (u, v) pixels; box_size : crop side in pixels.
        image_size: (width, height); focal : full-image focal length in pixels.
    """
    s, tx, ty = (float(x) for x in np.asarray(pred_cam, dtype=np.float64).reshape(3))
    if s <= 0:
        raise InvalidInputError(f"weak-perspective scale must be > 0, got {s}")
    bs = s * float(box_size)
    W, H = image_size
    cx, cy = (float(x) for x in np.asarray(box_center, dtype=np.float64).reshape(2))
    tx = tx if is_right else -tx
    return np.array([tx + 2 * (cx - W / 2) / bs, ty + 2 * (cy - H / 2) / bs, 2 * focal / bs])


def load_hamer_hand(
    source: str | Path | dict,
    image_size: tuple[int, int] | None = None,
    index: int = 0,
    pose_offset: np.ndarray | None = None,
) -> tuple[HandParams, Camera]:
    """Read one hand predicted by HaMeR (see module docs for every convention).

    Args:
        source: path to ``.npz`` / ``.json`` / ``.pkl`` (safe unpickler: numpy content only), or a
            dict. Key names and aliases: :data:`HAMER_KEYS`; nested dicts (``pred_mano_params``) are
            searched. Arrays may carry a leading batch dimension (one entry per hand).
        image_size: (width, height) of the full image; taken from ``img_size`` in the data when
            None (both given and different -> error).
        index: which hand of a batched file.
        pose_offset: (45,) added to the pose (for files relative to MANO's mean hand).

    Returns:
        params: HandParams, batch 1, float32, ``side`` from ``is_right`` (default right); ``transl
            = cam_t``.
        camera: Camera.hamer_convention(W, H) with R = I, t = 0.
    """
    if isinstance(source, dict):
        raw = source
    elif isinstance(source, str | Path):
        raw = _read_file(Path(source))
    else:
        raise InvalidInputError(f"expected a path or a dict, got {type(source).__name__}")
    flat = _flatten(raw)

    size_in_file = _get(flat, "img_size", required=False)
    if size_in_file is not None:
        wh = _rows(_array(size_in_file, "img_size"), 2, index, "img_size")
        size_in_file = (int(round(wh[0])), int(round(wh[1])))
    if image_size is None:
        if size_in_file is None:
            raise InvalidInputError("image_size (width, height) is required: the data has none")
        image_size = size_in_file
    W, H = (int(x) for x in image_size)
    if size_in_file is not None and size_in_file != (W, H):
        raise InvalidInputError(
            f"image_size {W}x{H} (width x height) differs from the file's img_size "
            f"{size_in_file[0]}x{size_in_file[1]}"
        )
    camera = Camera.hamer_convention(W, H)

    is_right_raw = _get(flat, "is_right", required=False)
    is_right = True
    if is_right_raw is not None:
        r = np.asarray(is_right_raw).reshape(-1)
        if not -r.size <= index < r.size:
            raise InvalidInputError(f"'is_right' has no entry for hand {index}")
        is_right = bool(float(r[index]) > 0.5)

    go = _rotations(_array(_get(flat, "global_orient"), "global_orient"), 1, index,
                    "global_orient")  # fmt: skip
    pose = _rotations(_array(_get(flat, "hand_pose"), "hand_pose"), 15, index, "hand_pose")
    betas = _rows(_array(_get(flat, "betas"), "betas"), 10, index, "betas")

    cam_t = _get(flat, "cam_t", required=False)
    if cam_t is not None:
        cam_t = _rows(_array(cam_t, "cam_t"), 3, index, "cam_t")
    else:
        pc, bc, bsz = (_get(flat, k, required=False) for k in ("pred_cam", "box_center",
                                                                 "box_size"))  # fmt: skip
        if pc is None or bc is None or bsz is None:
            raise InvalidInputError(
                "HaMeR data lacks the camera translation: give 'pred_cam_t_full' (or "
                "'cam_t'), or 'pred_cam' with 'box_center' and 'box_size'"
            )
        cam_t = crop_to_full_translation(
            _rows(_array(pc, "pred_cam"), 3, index, "pred_cam"),
            _rows(_array(bc, "box_center"), 2, index, "box_center"),
            float(_rows(_array(bsz, "box_size"), 1, index, "box_size")[0]),
            (W, H),
            float(camera.fx),
            is_right,
        )

    pose = pose.reshape(1, 45)
    if pose_offset is not None:
        off = _array(pose_offset, "pose_offset").reshape(-1)
        if off.shape != (45,):
            raise InvalidInputError(f"pose_offset must have 45 values, got {off.shape}")
        pose = pose + torch.as_tensor(off)
    t = torch.as_tensor(cam_t, dtype=torch.float64)[None]
    if is_right:
        p = HandParams(go.reshape(1, 3), t, pose, torch.as_tensor(betas)[None], "right")
    else:
        # HaMeR's right-hand prediction, placed so that its mirror lands at cam_t
        right = HandParams(go.reshape(1, 3), t * torch.tensor([-1.0, 1.0, 1.0], dtype=t.dtype),
                           pose, torch.as_tensor(betas)[None], "right")  # fmt: skip
        p = mirror_params(right)
    return p.to(dtype=torch.float32), camera


# ----------------------------------------------------------------------------------------------
# masks and meshes
# ----------------------------------------------------------------------------------------------


def load_mask_png(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool mask from a PNG written by LISA, SAM or an editor.

    Accepts 0/255, 0/1 and inverted masks (the foreground is the level touching the image
    border less), grey, colour or alpha; ``size`` = (width, height) of the image, a mismatch
    raises :class:`InvalidInputError`. Delegates to :func:`easyhoi.io.image.load_mask`.
    """
    from easyhoi.io.image import load_mask

    return load_mask(path, size=size)


#: Largest object mesh accepted (faces). Image-to-3D tools write 10^4-10^5 faces; the SDF grid,
#: ray casting and simulation cost grow with the face count, and a scanner's multi-million-face
#: mesh would run for minutes: decimate it first (any mesh tool's quadric decimation).
MAX_OBJECT_FACES = 500_000
#: Largest object mesh file (bytes), checked before parsing.
MAX_OBJECT_FILE_BYTES = 256 * 1024 * 1024


def load_object_mesh(path: str | Path) -> trimesh.Trimesh:
    """Object mesh written by InstantMesh, Tripo3D or any tool (OBJ, GLB/GLTF, PLY, STL, OFF).

    Scenes are flattened into one mesh (node transforms applied); the mesh is validated
    (non-empty, finite, valid faces) by :func:`easyhoi.geometry.mesh.load_mesh`.

    Returns:
        trimesh.Trimesh with ``metadata["easyhoi"] = {"source", "watertight", "winding_consistent",
        "num_vertices", "num_faces"}``; a mesh that is not watertight is returned as is (repair it
        with the watertight post-processing before the SDF-based stages).
    """
    from easyhoi.errors import InputTooLargeError
    from easyhoi.geometry.mesh import load_mesh
    from easyhoi.limits import declared_face_count

    p = Path(path)
    if p.is_file() and p.stat().st_size > MAX_OBJECT_FILE_BYTES:
        raise InputTooLargeError(
            f"object mesh {p} is {p.stat().st_size / 2**20:.0f} MiB; files over "
            f"{MAX_OBJECT_FILE_BYTES // 2**20} MiB are refused (decimate the mesh first)"
        )
    # the face count the file declares is checked before parsing, the parsed one after
    declared = declared_face_count(p) if p.is_file() else None
    mesh = None if declared is not None and declared > MAX_OBJECT_FACES else load_mesh(path)
    faces = declared if mesh is None else len(mesh.faces)
    if faces > MAX_OBJECT_FACES:
        raise InputTooLargeError(
            f"object mesh {p} has {faces:,} faces; at most {MAX_OBJECT_FACES:,} are "
            "accepted (decimate the mesh first, e.g. quadric decimation to 50,000 faces)"
        )
    mesh.metadata["easyhoi"] = {
        "source": str(path),
        "watertight": bool(mesh.is_watertight),
        "winding_consistent": bool(mesh.is_winding_consistent),
        "num_vertices": int(len(mesh.vertices)),
        "num_faces": int(len(mesh.faces)),
    }
    return mesh
