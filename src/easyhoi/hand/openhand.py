"""OpenHand: the built-in, freely licensed MANO-layout hand model.

A procedurally built adult right hand (:mod:`easyhoi.hand.openhand_build`, rigged by
:mod:`easyhoi.hand.openhand_rig`) with MANO's kinematic tree, joint order and parameter layout,
so that the same pose vector bends the same joints the same way as on MANO.

Convention (MANO's canonical right-hand frame, metres):
    * the fingers point along -x (wrist joint at the origin, middle fingertip at x ~ -0.188);
    * the palm faces -y (the back of the hand faces +y);
    * the thumb is on the +z side (pinky towards -z); the thumb's CMC joint (joint 13) sits at
      the base of the palm, its metacarpal tilted 44 degrees towards +z and 12 degrees towards
      the palm, out of the palm plane;
    * flexion of the four fingers is a positive rotation about +z (the rest fingers lie nearly
      along -x, so ``+z`` axis-angle curls them towards the palm, -y); spreading
      (abduction) is a rotation about y; twist about x. The thumb flexes about an axis tilted
      with its metacarpal (see :func:`easyhoi.hand.regions.flexion_axes`).
    * Unlike MANO's template, whose origin lies near the middle of the palm, OpenHand's wrist
      joint is at the origin, so the same ``transl`` places the two models' wrists differently;
      compare hands through their joints.

Rest (zero-pose) shape: wrist-to-middle-fingertip 18.8 cm, palm width 8.1 cm at the
knuckles, finger thickness 1.7-2.0 cm, volume about 335 cm^3, about 1.9k vertices / 3.8k
faces, one closed, watertight, outward-oriented surface.

Shape parameters (10, each unit 5 %): 0 size, 1 digit length, 2 palm width, 3 finger
thickness, 4 palm thickness, 5 thumb length, 6-9 no effect. Vertices are
``v_template + shapedirs @ betas`` and joints ``J_regressor @ v`` (linear, differentiable).

Building takes a second or two; the arrays are cached in-process and on disk under
``$EASYHOI_CACHE`` (default ``~/.cache/easyhoi``) keyed by the builder's version and source
hash. The disk cache is optional: any failure to read or write it only logs and rebuilds.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
from pathlib import Path

import numpy as np
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.hand import openhand_build, openhand_rig
from easyhoi.hand.base import HandModel
from easyhoi.structures import NUM_BETAS

logger = logging.getLogger(__name__)

_ARRAY_KEYS = ("v_template", "faces", "joints", "skin_weights", "shapedirs", "J_regressor", "tips")


def build_openhand_arrays() -> dict[str, np.ndarray]:
    """Build the OpenHand model from scratch (no cache).

    Returns:
        dict with ``v_template`` (V, 3), ``faces`` (F, 3) int64, ``joints`` (16, 3) rest joints,
        ``skin_weights`` (V, 16), ``shapedirs`` (V, 3, 10), ``J_regressor`` (16, V) and
        ``tips`` (5,) int64 fingertip vertex ids (thumb, index, middle, ring, pinky).
    """
    skeleton = openhand_build.default_skeleton()
    verts, faces = openhand_build.build_mesh(skeleton)
    joints, tip_points = openhand_build.rest_joints(skeleton)
    tips = dict(zip(openhand_rig.TIP_DIGITS, tip_points, strict=True))
    weights = openhand_rig.skin_weights(verts, joints, tips)
    return {
        "v_template": verts,
        "faces": faces,
        "joints": joints,
        "skin_weights": weights,
        "shapedirs": openhand_rig.shape_basis(verts, weights, skeleton, joints, tips),
        "J_regressor": openhand_rig.joint_regressor(verts, weights, joints, tips),
        "tips": openhand_rig.tip_vertex_ids(verts, weights, joints, tips),
    }


def cache_key() -> str:
    """Builder version plus a hash of the builder sources (changes invalidate the disk cache)."""
    h = hashlib.sha1()
    for mod in (openhand_build, openhand_rig):
        h.update(Path(mod.__file__).read_bytes())
    return f"{openhand_build.BUILDER_VERSION}-{h.hexdigest()[:12]}"


def cache_dir() -> Path:
    """``$EASYHOI_CACHE`` or ``~/.cache/easyhoi``."""
    env = os.environ.get("EASYHOI_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "easyhoi"


@functools.lru_cache(maxsize=1)
def openhand_arrays() -> dict[str, np.ndarray]:
    """The model arrays, from the disk cache when possible (see :func:`build_openhand_arrays`)."""
    path = cache_dir() / f"openhand-{cache_key()}.npz"
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in _ARRAY_KEYS}
        logger.debug("loaded OpenHand from %s", path)
        return arrays
    except (OSError, KeyError, ValueError) as exc:
        logger.debug("OpenHand cache unavailable (%s); building", exc)
    arrays = build_openhand_arrays()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    except OSError as exc:
        logger.info("could not write the OpenHand cache to %s: %s", path, exc)
    return arrays


class OpenHand(HandModel):
    """The built-in open hand model (right hand; left hands by mirroring, see the base class).

    Args:
        dtype: floating dtype of the buffers (outputs follow the parameters' dtype).

    Buffers:
        v_template (V, 3), shapedirs (V, 3, 10), J_regressor (16, V), faces (F, 3) long,
        skin_weights (V, 16), tip_vertex_ids (5,) long.
    """

    name = "openhand"

    def __init__(self, dtype: torch.dtype = torch.float32):
        super().__init__()
        if not dtype.is_floating_point:
            raise InvalidInputError(f"OpenHand dtype must be a floating type, got {dtype}")
        a = openhand_arrays()
        self.register_buffer("v_template", torch.tensor(a["v_template"], dtype=dtype))
        self.register_buffer("shapedirs", torch.tensor(a["shapedirs"], dtype=dtype))
        self.register_buffer("J_regressor", torch.tensor(a["J_regressor"], dtype=dtype))
        self.register_buffer("faces", torch.tensor(a["faces"], dtype=torch.long))
        self.register_buffer("skin_weights", torch.tensor(a["skin_weights"], dtype=dtype))
        self.register_buffer("tip_vertex_ids", torch.tensor(a["tips"], dtype=torch.long))

    def shaped(self, betas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest-pose geometry for shape coefficients.

        Args:
            betas: (B, 10) shape coefficients.
        Returns:
            vertices (B, V, 3) and joints (B, 16, 3) of the flat rest pose, in ``betas.dtype``.
        """
        if betas.ndim != 2 or betas.shape[1] != NUM_BETAS:
            raise InvalidInputError(f"betas must have shape (B, {NUM_BETAS}), got {betas.shape}")
        dtype = betas.dtype
        v = self.v_template.to(dtype) + torch.einsum("vck,bk->bvc", self.shapedirs.to(dtype), betas)
        j = torch.einsum("jv,bvc->bjc", self.J_regressor.to(dtype), v)
        return v, j
