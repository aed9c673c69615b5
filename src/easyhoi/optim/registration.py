"""Contact registration of stage 2: contact points from the mutual-occlusion regions, then ICP.

:func:`contact_points` extracts hand and object contact points (object frame) along the camera
rays through M_front = M^_o minus M_o and M_back = M^_h minus M_h (restricted to M^_o), by depth
peeling both meshes: nearest hit for front pixels, farthest for back pixels, palmar hand faces
only; only rays meeting both surfaces count. :func:`register_contacts` runs a translation-only
ICP (:func:`easyhoi.geometry.icp.icp`) of the hand points onto the object points. How the
result moves the hand: :mod:`easyhoi.optim.contact`.
"""

from __future__ import annotations

import numpy as np
import torch

from easyhoi.config import ContactStageConfig
from easyhoi.geometry.icp import icp
from easyhoi.optim.state import Scene
from easyhoi.render.raster import depth_map, peel_pixels
from easyhoi.structures import Camera

__all__ = [
    "MIN_CONTACT_POINTS",
    "contact_points",
    "register_contacts",
]

#: Smallest number of contact points on each side for a registration to run.
MIN_CONTACT_POINTS = 3


def _pixel_uv(mask: torch.Tensor) -> torch.Tensor:
    rows, cols = torch.nonzero(mask, as_tuple=True)
    return torch.stack([cols, rows], dim=-1).to(torch.float64) + 0.5


def _pick(frags, keep: torch.Tensor, farthest: bool) -> torch.Tensor:
    """(N,) index of the nearest / farthest kept layer per ray; -1 where none is kept."""
    K = keep.shape[1]
    idx = torch.arange(K, device=keep.device).expand_as(keep)
    if farthest:
        score = torch.where(keep, idx, torch.full_like(idx, -1))
        best = score.max(dim=1).values
    else:
        score = torch.where(keep, idx, torch.full_like(idx, K))
        best = score.min(dim=1).values
        best = torch.where(best == K, torch.full_like(best, -1), best)
    return best


def _hits(frags, keep, farthest):
    sel = _pick(frags, keep, farthest)
    ok = sel >= 0
    rows = torch.nonzero(ok, as_tuple=True)[0]
    return frags.points.detach()[rows, sel[ok]], ok


def contact_points(
    scene: Scene,
    hand_verts: torch.Tensor,
    camera: Camera,
    masks: dict,
    cfg: ContactStageConfig,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Hand and object contact points from the mutual-occlusion regions (module docstring).

    Args:
        scene: Scene
        hand_verts: (V, 3) hand vertices in the object frame (object units).
        camera: Camera at the render resolution.
        masks: dict from :meth:`Scene.masks_at` at that resolution.
        cfg: ContactStageConfig

    Returns:
        hand_points: (N, 3) float64, object frame.
        object_points: (N, 3) float64, object frame (one per ray, same rays as the hand points).
        info: dict with pixel and point counts.
    """
    v = hand_verts.detach()
    faces = scene.hand_model.faces
    front = (masks["amodal"] > 0.5) & ~(masks["object"] > 0.5)
    zh = depth_map(v, faces, camera.detach())
    back = torch.isfinite(zh) & ~(masks["hand"] > 0.5) & (masks["amodal"] > 0.5)
    info = {"front_pixels": int(front.sum()), "back_pixels": int(back.sum())}
    hand_pts, obj_pts = [], []
    palmar = scene.regions.palmar_faces
    cam = camera.detach()
    for mask, farthest in ((front, False), (back, True)):
        if not bool(mask.any()):
            continue
        uv = _pixel_uv(mask).to(cam.K.dtype)
        fo = peel_pixels(scene.object_verts, scene.object_faces, cam, uv, cfg.peel_layers)
        fh = peel_pixels(v, faces, cam, uv, cfg.peel_layers)
        keep_h = fh.face_ids >= 0
        if cfg.palmar_only:
            keep_h = keep_h & palmar[fh.face_ids.clamp(min=0)]
        p_o, ok_o = _hits(fo, fo.face_ids >= 0, farthest)
        p_h, ok_h = _hits(fh, keep_h, farthest)
        both = ok_o & ok_h  # rays that meet both surfaces
        obj_pts.append(p_o[both[ok_o]])
        hand_pts.append(p_h[both[ok_h]])
    src = torch.cat(hand_pts).double().cpu().numpy() if hand_pts else np.zeros((0, 3))
    tgt = torch.cat(obj_pts).double().cpu().numpy() if obj_pts else np.zeros((0, 3))
    info.update({"hand_points": len(src), "object_points": len(tgt)})
    return src, tgt, info


def register_contacts(
    scene: Scene,
    hand_verts: torch.Tensor,
    camera: Camera,
    masks: dict,
    cfg: ContactStageConfig,
) -> tuple[np.ndarray | None, np.ndarray | None, dict]:
    """Contact registration at one resolution: :func:`contact_points` (same parameters), then
    translation ICP.

    Returns:
        D: (3,) ICP translation (object frame) or None when too few contact points.
        anchor: (3,) centroid of the hand contact points or None.
        info: dict with point counts and the ICP RMSE history.
    """
    src, tgt, info = contact_points(scene, hand_verts, camera, masks, cfg)
    if len(src) < MIN_CONTACT_POINTS or len(tgt) < MIN_CONTACT_POINTS:
        info["skipped"] = "too few contact points"
        return None, None, info
    res = icp(
        src,
        tgt,
        mode="translation",
        max_iters=max(1, cfg.icp_iters),
        tol=cfg.icp_tolerance,
        trim_fraction=cfg.icp_trim_fraction,
    )
    info.update({
        "centroid_shift": [float(x) for x in tgt.mean(axis=0) - src.mean(axis=0)],
        "icp_iterations": int(res.iterations),
        "rmse_first": float(res.rmse[0]),
        "rmse_last": float(res.rmse[-1]),
        "translation": [float(x) for x in res.t],
    })  # fmt: skip
    return res.t, src.mean(axis=0), info
