"""Offline single-view object reconstruction from the amodal silhouette and the hand.

:class:`SilhouetteReconstructor` (registered as ``("object", "silhouette")``) is the offline
stand-in for an image-to-3D model (InstantMesh, Tripo3D). It fits shape hypotheses to the amodal
outline (:mod:`easyhoi.perception.shapes`: surface of revolution, also with a handle, slab,
cuboid, superquadric, generalised cylinder, inflation) and keeps the one the evidence favours:
silhouette fit, straight internal edges, and the thickness the holding hand's grip allows. With
the hand's keypoints the object also gets a metric size (the hand's size is known).

Output frame (as InstantMesh's): centred at the bounding-box centre, x right and y down as in the
image, z away from the camera (right-handed), unit max extent. ``mesh.metadata["easyhoi"]``
records the ``method`` (the winning family), the ``shape`` record (every family's score and
reasons), the map back to pixels ``u = x * pixels_per_unit + center_px[0]`` (pixel centres at
integer + 0.5, likewise ``v``; ``depth_center_px`` for z) and, with hand keypoints,
``meters_per_unit`` (metric size) and the ``hand_cues``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from easyhoi.errors import BackendError, InvalidInputError
from easyhoi.io.native_output import silenced
from easyhoi.perception.base import register
from easyhoi.perception.shapes.common import signed_distance_2d
from easyhoi.perception.shapes.inflation import (
    half_thickness_sq,
    implicit_slab_mesh,
    local_thickness,
)
from easyhoi.perception.shapes.revolution import revolution_mesh

# ----------------------------------------------------------------------------------------------
# input checks and crops
# ----------------------------------------------------------------------------------------------


def _check_mask(mask, image=None) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 2:
        raise InvalidInputError(f"object mask must have shape (H, W), got {m.shape}")
    m = m > 0.5 if m.dtype.kind == "f" else m.astype(bool)
    if image is not None:
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InvalidInputError(f"image must have shape (H, W, 3), got {img.shape}")
        if img.shape[:2] != m.shape:
            raise InvalidInputError(
                f"object mask is {m.shape[0]}x{m.shape[1]} but the image is "
                f"{img.shape[0]}x{img.shape[1]}"
            )
    if m.sum() < 16:
        raise InvalidInputError(
            f"object mask has {int(m.sum())} pixels; at least 16 are needed to build a mesh"
        )
    return m


@dataclass(frozen=True)
class ObjectCrop:
    """A square, background-free crop of the object (what an image-to-3D model consumes).

    Attributes:
        image: (S, S, 3) uint8 RGB, white outside the mask.
        mask: (S, S) bool.
        box: (u0, v0, u1, v1) int, the crop window in the source image (may exceed it; pixels
            outside the source are white / False).
    """

    image: np.ndarray
    mask: np.ndarray
    box: tuple[int, int, int, int]


def object_crop(image: np.ndarray, mask: np.ndarray, pad: float = 0.1) -> ObjectCrop:
    """Square crop around the mask with a white background.

    Args:
        image: (H, W, 3) uint8
        mask: (H, W) bool
        pad (float): Margin on each side as a fraction of the mask's larger bounding-box side, >= 0.
    """
    m = _check_mask(mask, image)
    if not (np.isfinite(pad) and pad >= 0):
        raise InvalidInputError(f"pad must be a finite number >= 0, got {pad}")
    img = np.asarray(image)
    rows, cols = np.nonzero(m)
    v0, v1, u0, u1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    side = int(np.ceil(max(v1 - v0, u1 - u0) * (1 + 2 * pad)))
    cu, cv = (u0 + u1) // 2, (v0 + v1) // 2
    bu, bv = cu - side // 2, cv - side // 2
    out = np.full((side, side, 3), 255, dtype=np.uint8)
    out_m = np.zeros((side, side), dtype=bool)
    H, W = m.shape
    su0, sv0, su1, sv1 = max(bu, 0), max(bv, 0), min(bu + side, W), min(bv + side, H)
    sub_m = m[sv0:sv1, su0:su1]
    dst = (slice(sv0 - bv, sv1 - bv), slice(su0 - bu, su1 - bu))
    out_m[dst] = sub_m
    out[dst][sub_m] = img[sv0:sv1, su0:su1][sub_m]
    return ObjectCrop(out, out_m, (int(bu), int(bv), int(bu + side), int(bv + side)))


# ----------------------------------------------------------------------------------------------
# shared helpers
# ----------------------------------------------------------------------------------------------


def canonical_mesh(verts_px: np.ndarray, faces: np.ndarray, meta: dict) -> trimesh.Trimesh:
    """(V, 3) pixel-unit (u, v, z) vertices and (F, 3) faces -> the canonical frame.

    Repairs the surface if it is not closed (pymeshfix), orients it outwards, centres it on
    its bounding box and scales it to unit max extent; ``meta`` plus ``pixels_per_unit``,
    ``center_px`` (u, v) and ``depth_center_px`` go to ``metadata["easyhoi"]``.
    """
    mesh = trimesh.Trimesh(verts_px, faces, process=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        # merging coincident vertices can join two sheets where a thin slab's faces meet at
        # its rim (both at the mid-surface there): the surface as built may be closed already
        raw = trimesh.Trimesh(verts_px, faces, process=False)
        if raw.is_watertight and raw.is_winding_consistent:
            raw.remove_unreferenced_vertices()
            mesh = raw
        else:
            mesh = _repair(mesh)  # TODO: swap for geometry.watertight.make_watertight
    if mesh.volume < 0:
        mesh.invert()
    lo, hi = mesh.bounds
    center = 0.5 * (lo + hi)
    scale = float((hi - lo).max())
    if not np.isfinite(scale) or scale <= 0:
        raise BackendError("silhouette reconstruction produced a degenerate mesh")
    mesh.vertices = (mesh.vertices - center) / scale
    meta = dict(meta, pixels_per_unit=scale, center_px=[float(center[0]), float(center[1])])
    meta["depth_center_px"] = float(center[2])
    mesh.metadata["easyhoi"] = meta
    return mesh


def _repair(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    import pymeshfix

    # MeshFix warns on stderr when it cannot fix everything; the check below decides
    with silenced(2):
        v, f = pymeshfix.clean_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    fixed = trimesh.Trimesh(v, f, process=True)
    if not fixed.is_watertight:
        raise BackendError("could not make the reconstructed object mesh watertight")
    return fixed


# ----------------------------------------------------------------------------------------------
# the backend
# ----------------------------------------------------------------------------------------------


@register("object", "silhouette")
class SilhouetteReconstructor:
    """Object mesh from the amodal silhouette and the holding hand (see module docs).

    Args:
        families: shape families to try (:data:`easyhoi.perception.shapes.FAMILIES`).
    """

    def __init__(self, families: tuple[str, ...] | None = None):
        from easyhoi.perception.shapes import FAMILIES

        fam = FAMILIES if families is None else tuple(families)
        unknown = [f for f in fam if f not in FAMILIES]
        if not fam or unknown:
            raise InvalidInputError(
                f"families must be a non-empty subset of {FAMILIES}, got {families!r}"
            )
        self.families = fam

    def reconstruct(
        self,
        image: np.ndarray | None,
        mask: np.ndarray,
        *,
        visible_mask: np.ndarray | None = None,
        hand_mask: np.ndarray | None = None,
        hand_keypoints2d: np.ndarray | None = None,
        hand_keypoints3d: np.ndarray | None = None,
    ) -> trimesh.Trimesh:
        """Closed mesh of the object seen as ``mask``.

        Args:
            image: (H, W, 3) uint8 hand-free photo or None (edge evidence of boxes).
            mask: (H, W) bool amodal object mask.
            visible_mask: (H, W) bool visible object mask (the rest of ``mask`` is inferred).
            hand_mask: (H, W) bool visible hand (the outline behind it is unknown).
            hand_keypoints2d, hand_keypoints3d: (21, 2) pixels and (21, 3) metres (camera-aligned,
                any translation) of the holding hand: grip thickness and metric size.

        Returns:
            trimesh.Trimesh, watertight, outward winding, canonical frame (module docs).
        """
        m = _check_mask(mask, image)
        return shape_mesh(m, image, self.families, visible_mask, hand_mask, hand_keypoints2d,
                          hand_keypoints3d)  # fmt: skip


def shape_mesh(
    mask: np.ndarray,
    image: np.ndarray | None,
    families: tuple[str, ...] | None = None,
    visible_mask=None,
    hand_mask=None,
    hand_keypoints2d=None,
    hand_keypoints3d=None,
    front: np.ndarray | None = None,
    method: str | None = None,
) -> trimesh.Trimesh:
    """The winning shape hypothesis as a canonical mesh (see :meth:`SilhouetteReconstructor.\
reconstruct`); ``front`` is a depth model's front surface, ``method`` overrides the recorded
    method name (default: the winning family)."""
    from easyhoi.perception.shapes import FAMILIES, fit_shape, hand_cues

    m = _check_mask(mask, image)
    vis = _optional_mask(visible_mask, m.shape, "visible_mask")
    occ = _optional_mask(hand_mask, m.shape, "hand_mask")
    cues = hand_cues(hand_keypoints2d, hand_keypoints3d, m, occ)
    img = None if image is None else np.asarray(image)
    fam = FAMILIES if families is None else families
    verts, faces, info = fit_shape(m, img, vis, occ, cues, fam, front=front)
    meta = dict(method=method or info["shape"], shape=info)
    if cues is not None:
        meta["hand_cues"] = cues.to_dict()
    mesh = canonical_mesh(verts, faces, meta)
    md = mesh.metadata["easyhoi"]
    if cues is not None:
        md["meters_per_unit"] = md["pixels_per_unit"] / cues.px_per_m
        md["grip_depth_m"] = cues.grip_depth_m
    return mesh


def _optional_mask(m, shape, name) -> np.ndarray | None:
    if m is None:
        return None
    a = np.asarray(m)
    if a.shape != shape:
        raise InvalidInputError(f"{name} is {a.shape} but the object mask is {shape}")
    return a > 0.5 if a.dtype.kind == "f" else a.astype(bool)


__all__ = [
    "ObjectCrop",
    "SilhouetteReconstructor",
    "canonical_mesh",
    "half_thickness_sq",
    "implicit_slab_mesh",
    "local_thickness",
    "object_crop",
    "revolution_mesh",
    "shape_mesh",
    "signed_distance_2d",
]


def hand_inputs(reconstructor, detection, model, hand_mask, object_mask) -> dict:
    """Keyword arguments of ``reconstructor.reconstruct`` that describe the holding hand.

    Only the ones its signature accepts (other backends keep the two-argument protocol). The
    keypoints come from the fitted hand model (metric, known size) in the camera's frame,
    projected for the 2D ones; without a fit, from the detection.
    """
    import inspect

    try:
        accepted = set(inspect.signature(reconstructor.reconstruct).parameters)
    except (TypeError, ValueError):
        return {}
    k2, k3 = _hand_keypoints(detection, model)
    out = dict(visible_mask=object_mask, hand_mask=hand_mask, hand_keypoints2d=k2,
               hand_keypoints3d=k3)  # fmt: skip
    return {k: v for k, v in out.items() if k in accepted}


def _hand_keypoints(detection, model):
    if detection.params is not None and detection.camera is not None:
        import torch

        with torch.no_grad():
            kp = model(detection.params).keypoints[0]
            cam = detection.camera
            k3 = cam.world_to_camera(kp.to(cam.K.dtype))
            k2 = cam.project(kp.to(cam.K.dtype))[0]
        return k2.detach().cpu().numpy().reshape(-1, 2), k3.detach().cpu().numpy().reshape(-1, 3)
    k2 = np.asarray(detection.keypoints2d, dtype=np.float64)
    k3 = detection.keypoints3d
    return (k2 if k2.shape == (21, 2) else None), (None if k3 is None else np.asarray(k3))
