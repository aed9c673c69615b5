"""Occlusion-aware soft masks of two meshes (hand and object) seen by one camera.

Coverage is soft (differentiable, :func:`easyhoi.render.soft.soft_silhouette`); the depth order
is hard, from the z-buffers of :func:`easyhoi.render.raster.depth_map`:

* ``hand_visible = hand * [z_hand_ext <= z_object]``
* ``object_visible = object * [z_object_ext < z_hand]``

where ``z_mesh`` is the mesh's z-buffer (``inf`` where it is missed) and ``z_mesh_ext`` equals
``z_mesh`` on the mesh's hard footprint and, outside it, the nearest depth of the footprint within
the soft fringe (a min-filter of radius ``ceil(cull_margin)`` px). The extension lets the soft
fringe of the front mesh spread over the back mesh (so a hand boundary in front of the object
receives gradients) while the fringe of the back mesh stays hidden. Where both meshes are hit the
two indicators partition the pixels exactly (ties go to the hand). The indicators carry no
gradient: gradients flow through the coverage only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import torch

from easyhoi.render._common import get_backend, numba_call
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import (
    DEFAULT_CULL_EPS,
    DEFAULT_NEAR,
    DEFAULT_SIGMA,
    cull_margin,
    soft_silhouette,
)
from easyhoi.structures import Camera


@dataclass(frozen=True)
class HOIMasks:
    """Soft masks of a hand and an object.

    Attributes:
        hand: (H, W) complete (amodal) soft hand silhouette.
        object: (H, W) complete (amodal) soft object silhouette.
        hand_visible: (H, W) soft hand coverage where the hand is in front of the object.
        object_visible: (H, W) soft object coverage where the object is in front of the hand.
        hand_depth: (H, W) hand z-buffer (camera z), ``inf`` where missed; no gradient.
        object_depth: (H, W) object z-buffer, ``inf`` where missed; no gradient.
    """

    hand: torch.Tensor
    object: torch.Tensor
    hand_visible: torch.Tensor
    object_visible: torch.Tensor
    hand_depth: torch.Tensor
    object_depth: torch.Tensor

    def detach(self) -> HOIMasks:
        return replace(self, **{f.name: getattr(self, f.name).detach() for f in fields(self)})


def extend_depth(z: torch.Tensor, radius: int) -> torch.Tensor:
    """Fill missed pixels (``inf``) of a z-buffer with the minimum depth within ``radius`` px.

    A square min-filter of side ``2 radius + 1`` (clipped at the image border), applied only
    where ``z`` is ``inf``; hit pixels keep their depth. No gradient.
    """
    radius = int(radius)
    if radius <= 0:
        return z
    z = z.detach()
    zmin = torch.empty_like(z)
    use_numba = get_backend() == "numba" and z.device.type == "cpu" and z.ndim == 2
    if not (use_numba and numba_call("min_filter", z.contiguous().numpy(), radius, zmin.numpy())):
        # separable max-pool of -z
        m = -z[None, None]
        m = torch.nn.functional.max_pool2d(m, (2 * radius + 1, 1), stride=1, padding=(radius, 0))
        m = torch.nn.functional.max_pool2d(m, (1, 2 * radius + 1), stride=1, padding=(0, radius))
        zmin = -m[0, 0]
    return torch.where(torch.isfinite(z), z, zmin)


def hoi_masks(
    hand_verts,
    hand_faces,
    object_verts,
    object_faces,
    camera: Camera,
    sigma: float = DEFAULT_SIGMA,
    near: float = DEFAULT_NEAR,
    cull_eps: float = DEFAULT_CULL_EPS,
) -> HOIMasks:
    """Amodal and visible soft masks of a hand and an object.

    Args:
        hand_verts: (V_h, 3) world-space hand vertices.
        hand_faces: (F_h, 3) integer.
        object_verts: (V_o, 3) world-space object vertices.
        object_faces: (F_o, 3) integer.
        camera: the camera (its tensors may require gradients).
        sigma, near, cull_eps: as in :func:`easyhoi.render.soft.soft_silhouette`.

    Returns:
        :class:`HOIMasks`. An empty mesh contributes zero coverage and an all-``inf`` depth.

    Raises:
        InvalidInputError: as :func:`~easyhoi.render.soft.soft_silhouette`.
    """
    hand = soft_silhouette(hand_verts, hand_faces, camera, sigma, near, cull_eps)
    obj = soft_silhouette(object_verts, object_faces, camera, sigma, near, cull_eps)
    dev = camera.K.device
    zh = depth_map(torch.as_tensor(hand_verts, device=dev).detach(), hand_faces, camera.detach(),
                   near)  # fmt: skip
    zo = depth_map(torch.as_tensor(object_verts, device=dev).detach(), object_faces,
                   camera.detach(), near)  # fmt: skip
    radius = math.ceil(cull_margin(sigma, cull_eps))
    zh_ext, zo_ext = extend_depth(zh, radius), extend_depth(zo, radius)
    hand_vis = hand * (zh_ext <= zo).to(hand.dtype)
    obj_vis = obj * (zo_ext < zh).to(obj.dtype)
    return HOIMasks(hand, obj, hand_vis, obj_vis, zh, zo)
