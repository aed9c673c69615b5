"""Core data structures: the pinhole camera, hand parameters and hand-model outputs.

Conventions (see docs/architecture.md):
- metres everywhere inside the library;
- camera in the OpenCV convention: x right, y down, z forward; ``K`` in pixels;
  extrinsics map world to camera, ``x_cam = R @ x_world + t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Literal

import numpy as np
import torch

from easyhoi.checks import check_finite, check_last_dim, check_shape
from easyhoi.errors import InvalidInputError

Side = Literal["right", "left"]

NUM_JOINTS = 16
NUM_KEYPOINTS = 21
NUM_POSE = 45
NUM_BETAS = 10

#: Parent of each of the 16 MANO joints (0 wrist; 1-3 index; 4-6 middle; 7-9 pinky;
#: 10-12 ring; 13-15 thumb).
JOINT_PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)

#: Names of the 16 joints in MANO order.
JOINT_NAMES: tuple[str, ...] = (
    "wrist",
    "index1", "index2", "index3",
    "middle1", "middle2", "middle3",
    "pinky1", "pinky2", "pinky3",
    "ring1", "ring2", "ring3",
    "thumb1", "thumb2", "thumb3",
)  # fmt: skip

#: Fingertip order appended after the 16 joints (indices 16..20 before reordering).
TIP_NAMES: tuple[str, ...] = ("thumb_tip", "index_tip", "middle_tip", "ring_tip", "pinky_tip")

#: Index into [16 joints + 5 tips] that yields the 21 keypoints in OpenPose order.
OPENPOSE_ORDER: tuple[int, ...] = (
    0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20,
)  # fmt: skip

#: OpenPose keypoint names (wrist, then thumb, index, middle, ring, pinky, base to tip).
KEYPOINT_NAMES: tuple[str, ...] = tuple(
    (list(JOINT_NAMES) + list(TIP_NAMES))[i] for i in OPENPOSE_ORDER
)


def _all_finite(*tensors: torch.Tensor) -> bool:
    """True when every value of the (small) tensors is finite; one check instead of three."""
    if all(x.device.type == "cpu" and x.dtype in _NUMPY_FLOATS for x in tensors):
        return all(bool(np.isfinite(x.detach().numpy()).all()) for x in tensors)
    return all(bool(torch.isfinite(x.detach()).all()) for x in tensors)


def _focals(K: torch.Tensor) -> tuple[float, float]:
    """(fx, fy) of an intrinsics matrix as Python floats."""
    if K.device.type == "cpu" and K.dtype in _NUMPY_FLOATS:
        k = K.detach().numpy()
        return float(k[0, 0]), float(k[1, 1])
    return float(K[0, 0].detach()), float(K[1, 1].detach())


_NUMPY_FLOATS = (torch.float32, torch.float64)


def _as_tensor(x, dtype=None, device=None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(dtype=dtype or x.dtype, device=device or x.device)
    return torch.as_tensor(np.asarray(x), dtype=dtype or torch.float32, device=device)


# ----------------------------------------------------------------------------------------------
# Camera
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Camera:
    """A pinhole camera (OpenCV convention) with world-to-camera extrinsics.

    Attributes:
        K: (3, 3) float intrinsics in pixels, ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
        R: (3, 3) float world-to-camera rotation.
        t: (3,) float world-to-camera translation, ``x_cam = R @ x_world + t``.
        width, height: image size in pixels. Pixel centres are at integer + 0.5 coordinates:
            pixel (row i, column j) covers ``u in [j, j+1)``, ``v in [i, i+1)``.

    Tensors may require gradients (stage 1 optimizes the camera); every method is
    differentiable with respect to them.
    """

    K: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    width: int
    height: int

    def __post_init__(self):
        K = _as_tensor(self.K)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", _as_tensor(self.R, dtype=K.dtype, device=K.device))
        object.__setattr__(self, "t", _as_tensor(self.t, dtype=K.dtype, device=K.device))
        check_shape(self.K, (3, 3), "Camera.K")
        check_shape(self.R, (3, 3), "Camera.R")
        check_shape(self.t, (3,), "Camera.t")
        if not _all_finite(self.K, self.R, self.t):
            for name in ("K", "R", "t"):
                check_finite(getattr(self, name).detach(), f"Camera.{name}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InvalidInputError(
                f"camera image size must be positive, got {self.width}x{self.height}"
            )
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        fx, fy = _focals(self.K)
        if fx <= 0 or fy <= 0:
            raise InvalidInputError(
                f"camera focal lengths must be positive, got fx={fx:.4g}, fy={fy:.4g}"
            )

    @classmethod
    def _trusted(cls, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor, width: int, height: int):
        """A camera built without validation, from parts derived from a validated camera.

        For the internal derivations (:meth:`detach`, :meth:`resized`, same-type :meth:`to`)
        whose results are valid whenever their source is: they run in every optimizer
        iteration, where re-checking the same numbers cost more than the rendering around them.
        """
        cam = object.__new__(cls)
        object.__setattr__(cam, "K", K)
        object.__setattr__(cam, "R", R)
        object.__setattr__(cam, "t", t)
        object.__setattr__(cam, "width", width)
        object.__setattr__(cam, "height", height)
        return cam

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def from_focal(
        cls,
        focal: float | tuple[float, float],
        width: int,
        height: int,
        R=None,
        t=None,
        principal: tuple[float, float] | None = None,
        dtype: torch.dtype = torch.float32,
        device=None,
    ) -> Camera:
        """Camera with focal length(s) in pixels; principal point at the image centre by default.

        ``device``: where its tensors live (None: the CPU, or where ``R`` and ``t`` are).
        """
        fx, fy = (focal, focal) if np.isscalar(focal) else focal
        cx, cy = principal if principal is not None else (width / 2.0, height / 2.0)
        kw = dict(dtype=dtype, device=device)
        K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], **kw)
        R = torch.eye(3, **kw) if R is None else _as_tensor(R, **kw)
        t = torch.zeros(3, **kw) if t is None else _as_tensor(t, **kw)
        if device is None:
            K = K.to(R.device)
        return cls(K, R, t, width, height)

    @classmethod
    def from_fov(cls, fov_deg: float, width: int, height: int, R=None, t=None, **kw) -> Camera:
        """Camera whose vertical field of view is ``fov_deg`` degrees."""
        if not 0 < fov_deg < 180:
            raise InvalidInputError(f"field of view must be in (0, 180) degrees, got {fov_deg}")
        f = 0.5 * height / math.tan(math.radians(fov_deg) / 2)
        return cls.from_focal(f, width, height, R, t, **kw)

    @classmethod
    def hamer_convention(cls, width: int, height: int, **kw) -> Camera:
        """Full-image camera of HaMeR: ``f = 5000 / 256 * max(W, H)``, centred principal point."""
        return cls.from_focal(5000.0 / 256.0 * max(width, height), width, height, **kw)

    @classmethod
    def look_at(
        cls,
        eye,
        target,
        up=(0.0, -1.0, 0.0),
        focal: float = 500.0,
        width: int = 256,
        height: int = 256,
        dtype: torch.dtype = torch.float32,
    ) -> Camera:
        """Camera at ``eye`` looking at ``target``; ``up`` is the world direction shown as image up.

        The default ``up = (0, -1, 0)`` keeps a world whose y axis points down (as the camera's)
        upright in the image.
        """
        eye = np.asarray(eye, dtype=np.float64)
        target = np.asarray(target, dtype=np.float64)
        z = target - eye
        n = np.linalg.norm(z)
        if n < 1e-12:
            raise InvalidInputError("look_at: eye and target coincide")
        z /= n
        down = -np.asarray(up, dtype=np.float64)
        x = np.cross(down, z)
        if np.linalg.norm(x) < 1e-9:
            raise InvalidInputError("look_at: up is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])  # rows: camera axes in world coordinates
        t = -R @ eye
        return cls.from_focal(focal, width, height, R=R, t=t, dtype=dtype)

    # -- properties ---------------------------------------------------------------------------
    @property
    def fx(self) -> torch.Tensor:
        return self.K[0, 0]

    @property
    def fy(self) -> torch.Tensor:
        return self.K[1, 1]

    @property
    def center(self) -> torch.Tensor:
        """(3,) camera centre in world coordinates, ``-R^T t``."""
        return -self.R.T @ self.t

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return (self.height, self.width)

    # -- geometry -----------------------------------------------------------------------------
    def world_to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """(..., 3) world points -> (..., 3) camera-frame points."""
        check_last_dim(points, 3, "points")
        return points @ self.R.T + self.t

    def camera_to_world(self, points: torch.Tensor) -> torch.Tensor:
        """(..., 3) camera-frame points -> (..., 3) world points."""
        check_last_dim(points, 3, "points")
        return (points - self.t) @ self.R

    def project(self, points: torch.Tensor, eps: float = 1e-9) -> tuple[torch.Tensor, torch.Tensor]:
        """Project world points to pixels.

        Args:
            points: (..., 3) world points.
        Returns:
            uv: (..., 2) pixel coordinates (u right, v down; pixel centres at +0.5).
            depth: (...,) camera-frame z (positive in front of the camera).
        """
        pc = self.world_to_camera(points)
        x, y, z = pc.unbind(-1)
        near = z.abs() < eps
        # on the CPU, the selection only where it selects (the same values and gradients
        # without it); elsewhere asking would wait for the device
        zs = z if z.device.type == "cpu" and not bool(near.any()) else torch.where(near, eps, z)
        fx, skew, cx, _, fy, cy, _, _, _ = self.K.flatten().unbind()  # one op, not five
        u = fx * x / zs + skew * y / zs + cx
        v = fy * y / zs + cy
        return torch.stack([u, v], dim=-1), z

    def unproject(self, uv: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """(..., 2) pixels and (...,) camera z-depths -> (..., 3) world points."""
        check_last_dim(uv, 2, "uv")
        y = (uv[..., 1] - self.K[1, 2]) / self.K[1, 1]
        x = (uv[..., 0] - self.K[0, 2] - self.K[0, 1] * y) / self.K[0, 0]
        pc = torch.stack([x * depth, y * depth, depth], dim=-1)
        return self.camera_to_world(pc)

    def rays(self, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rays through pixel coordinates.

        Args:
            uv: (..., 2) pixel coordinates (use ``pixel_centers`` for whole pixels).
        Returns:
            origins: (..., 3) the camera centre in world coordinates, broadcast.
            directions: (..., 3) unit world-space directions.
        """
        one = torch.ones_like(uv[..., 0])
        p = self.unproject(uv, one)
        o = self.center.expand_as(p)
        d = p - o
        return o, d / d.norm(dim=-1, keepdim=True)

    def pixel_centers(self, dtype: torch.dtype | None = None) -> torch.Tensor:
        """(H, W, 2) pixel-centre coordinates (u, v)."""
        dtype = dtype or self.K.dtype
        v, u = torch.meshgrid(
            torch.arange(self.height, dtype=dtype, device=self.K.device) + 0.5,
            torch.arange(self.width, dtype=dtype, device=self.K.device) + 0.5,
            indexing="ij",
        )
        return torch.stack([u, v], dim=-1)

    def resized(self, width: int, height: int) -> Camera:
        """The same camera for an image resampled to ``width`` x ``height``."""
        checked = type(width) is int and type(height) is int and width > 0 and height > 0
        if checked and width == self.width and height == self.height:
            return self
        sx, sy = width / self.width, height / self.height
        S = torch.diag(torch.tensor([sx, sy, 1.0], dtype=self.K.dtype, device=self.K.device))
        if not checked:  # the validating constructor converts or rejects the size
            return replace(self, K=S @ self.K, width=width, height=height)
        # positive finite scales of a valid K keep its focal lengths finite and positive
        return type(self)._trusted(S @ self.K, self.R, self.t, width, height)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Camera:
        """The same camera for the ``width`` x ``height`` window of its image whose top-left
        pixel is (``x0``, ``y0``): the principal point moves by the offset, nothing else."""
        for name, v in (("x0", x0), ("y0", y0), ("width", width), ("height", height)):
            if type(v) is not int:
                raise InvalidInputError(f"crop {name} must be an int, got {v!r}")
        if width <= 0 or height <= 0:
            raise InvalidInputError(f"crop size must be positive, got {width}x{height}")
        shift = torch.tensor([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]],
                             dtype=self.K.dtype, device=self.K.device)  # fmt: skip
        return type(self)._trusted(shift @ self.K, self.R, self.t, width, height)

    def detach(self) -> Camera:
        K, R, t = self.K, self.R, self.t
        if not (K.requires_grad or R.requires_grad or t.requires_grad):
            return self
        return type(self)._trusted(K.detach(), R.detach(), t.detach(), self.width, self.height)

    def to(self, dtype: torch.dtype | None = None, device=None) -> Camera:
        kw = dict(dtype=dtype, device=device)
        K, R, t = self.K.to(**kw), self.R.to(**kw), self.t.to(**kw)
        if K is self.K and R is self.R and t is self.t:
            return self  # already of that type and on that device: nothing changed
        return replace(self, K=K, R=R, t=t)

    def to_dict(self) -> dict:
        """JSON-ready dictionary (lists of floats)."""
        d = self.detach()
        return {
            "K": d.K.tolist(),
            "R": d.R.tolist(),
            "t": d.t.tolist(),
            "width": self.width,
            "height": self.height,
            "convention": "opencv (x right, y down, z forward); x_cam = R @ x_world + t",
        }

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        try:
            return cls(d["K"], d["R"], d["t"], d["width"], d["height"])
        except KeyError as exc:
            raise InvalidInputError(f"camera dictionary lacks the key {exc}") from None


# ----------------------------------------------------------------------------------------------
# Hand parameters and outputs
# ----------------------------------------------------------------------------------------------


def _batched(x, size: int, batch: int | None, name: str, dtype) -> torch.Tensor:
    x = _as_tensor(x, dtype=dtype)
    if x.ndim == 1:
        x = x.unsqueeze(0)
    check_shape(x, (batch, size), name)
    return x


@dataclass(frozen=True)
class HandParams:
    """Parameters of a MANO-layout hand (batched).

    Attributes:
        global_orient: (B, 3) axis-angle rotation of the wrist (root) joint.
        transl: (B, 3) translation added to every vertex and joint.
        pose: (B, 45) articulation: 15 joints x axis-angle, MANO joint order 1..15, relative to
            the model's flat rest pose (MANO's ``flat_hand_mean=True`` meaning).
        betas: (B, 10) shape coefficients.
        side: "right" or "left". Left hands are evaluated as mirrored right hands (x negated).
    """

    global_orient: torch.Tensor
    transl: torch.Tensor
    pose: torch.Tensor
    betas: torch.Tensor = None  # type: ignore[assignment]
    side: Side = "right"

    def __post_init__(self):
        go = _as_tensor(self.global_orient)
        dtype = go.dtype
        go = _batched(go, 3, None, "HandParams.global_orient", dtype)
        B = go.shape[0]
        object.__setattr__(self, "global_orient", go)
        object.__setattr__(self, "transl", _batched(self.transl, 3, B, "HandParams.transl", dtype))
        object.__setattr__(self, "pose", _batched(self.pose, NUM_POSE, B, "HandParams.pose", dtype))
        betas = torch.zeros(B, NUM_BETAS, dtype=dtype) if self.betas is None else self.betas
        object.__setattr__(self, "betas", _batched(betas, NUM_BETAS, B, "HandParams.betas", dtype))
        if self.side not in ("right", "left"):
            raise InvalidInputError(f"hand side must be 'right' or 'left', got {self.side!r}")

    @classmethod
    def zeros(cls, batch: int = 1, dtype=torch.float32, side: Side = "right") -> HandParams:
        z = lambda n: torch.zeros(batch, n, dtype=dtype)  # noqa: E731
        return cls(z(3), z(3), z(NUM_POSE), z(NUM_BETAS), side)

    @property
    def batch_size(self) -> int:
        return self.global_orient.shape[0]

    @property
    def full_pose(self) -> torch.Tensor:
        """(B, 16, 3) axis-angle of all 16 joints (root first)."""
        return torch.cat([self.global_orient, self.pose], dim=1).reshape(-1, NUM_JOINTS, 3)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "side"}

    def detach(self) -> HandParams:
        return replace(self, **{k: v.detach() for k, v in self.tensors().items()})

    def to(self, dtype=None, device=None) -> HandParams:
        return replace(
            self, **{k: v.to(dtype=dtype, device=device) for k, v in self.tensors().items()}
        )

    def clone(self) -> HandParams:
        return replace(self, **{k: v.detach().clone() for k, v in self.tensors().items()})

    def to_dict(self) -> dict:
        d = {k: v.detach().tolist() for k, v in self.tensors().items()}
        d["side"] = self.side
        d["layout"] = "MANO: global_orient 3 + pose 45 (15 joints axis-angle, flat mean) + betas 10"
        return d

    @classmethod
    def from_dict(cls, d: dict, dtype=torch.float32) -> HandParams:
        try:
            return cls(
                torch.tensor(d["global_orient"], dtype=dtype),
                torch.tensor(d["transl"], dtype=dtype),
                torch.tensor(d["pose"], dtype=dtype),
                torch.tensor(d["betas"], dtype=dtype) if "betas" in d else None,
                d.get("side", "right"),
            )
        except KeyError as exc:
            raise InvalidInputError(f"hand parameter dictionary lacks the key {exc}") from None


@dataclass(frozen=True)
class HandOutput:
    """Posed hand produced by a :class:`~easyhoi.hand.base.HandModel`.

    Attributes:
        vertices: (B, V, 3) posed vertices (metres).
        joints: (B, 16, 3) posed joints in MANO order.
        keypoints: (B, 21, 3) 16 joints + 5 fingertips in OpenPose order.
        faces: (F, 3) long, the closed (watertight) triangle mesh, counter-clockwise seen from
            outside (outward normals).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    keypoints: torch.Tensor
    faces: torch.Tensor
    extra: dict = field(default_factory=dict)

    def detach(self) -> HandOutput:
        return replace(
            self,
            vertices=self.vertices.detach(),
            joints=self.joints.detach(),
            keypoints=self.keypoints.detach(),
        )

    def to_trimesh(self, index: int = 0):
        """The ``index``-th hand of the batch as a ``trimesh.Trimesh``."""
        import trimesh

        return trimesh.Trimesh(
            self.vertices[index].detach().cpu().double().numpy(),
            self.faces.cpu().numpy(),
            process=False,
        )
