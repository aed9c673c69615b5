"""A tiny MANO-layout hand for tests that need any HandModel but not a skin mesh.

Its vertices are the 16 joints plus 5 fingertips (rigidly skinned); beta0 scales the hand by 5%
per unit, beta1 lengthens the fingers. Geometry numbers are our own rough adult-hand values
(metres); fingers point along +x, the palm faces -y, the thumb lies toward +z.
"""

from __future__ import annotations

import torch

from easyhoi.hand.base import HandModel

# rest joints (16) and tips (5: thumb, index, middle, ring, pinky)
_J = [
    (0.0, 0.0, 0.0),
    (0.095, 0.0, 0.025), (0.135, 0.0, 0.027), (0.160, 0.0, 0.028),
    (0.095, 0.0, 0.003), (0.140, 0.0, 0.003), (0.168, 0.0, 0.003),
    (0.082, 0.0, -0.036), (0.112, 0.0, -0.040), (0.130, 0.0, -0.042),
    (0.090, 0.0, -0.017), (0.132, 0.0, -0.019), (0.158, 0.0, -0.020),
    (0.025, -0.010, 0.030), (0.050, -0.015, 0.055), (0.075, -0.018, 0.075),
]  # fmt: skip
_TIPS = [(0.100, -0.020, 0.095), (0.182, 0.0, 0.029), (0.194, 0.0, 0.003),
         (0.182, 0.0, -0.021), (0.150, 0.0, -0.043)]  # fmt: skip
_TIP_PARENT = [15, 3, 6, 12, 9]
_FINGER_BASE = [13, 1, 4, 10, 7]


class ToyHand(HandModel):
    name = "toy"

    def __init__(self):
        super().__init__()
        pts = torch.tensor(_J + _TIPS, dtype=torch.float64)
        self.register_buffer("rest", pts)
        w = torch.zeros(21, 16, dtype=torch.float64)
        for j in range(16):
            w[j, j] = 1.0
        for i, p in enumerate(_TIP_PARENT):
            w[16 + i, p] = 1.0
        self.register_buffer("skin_weights", w)
        self.register_buffer("faces", torch.tensor([[0, 1, 4]], dtype=torch.long))
        self.register_buffer("tip_vertex_ids", torch.arange(16, 21))
        finger = torch.zeros(21, 1, dtype=torch.float64)
        for f in range(5):
            base = _FINGER_BASE[f]
            finger_joints = [base, base + 1, base + 2, 16 + f]
            for j in finger_joints:
                finger[j] = 1.0
        self.register_buffer("finger_mask", finger)

    def shaped(self, betas):
        dt = betas.dtype
        rest = self.rest.to(dt)
        scale = (1 + 0.05 * betas[:, :1])[:, :, None]  # (B, 1, 1)
        base = rest[[1, 4, 7, 10, 13]].mean(0)
        stretch = 0.05 * betas[:, 1:2, None] * self.finger_mask.to(dt) * (rest - base)
        v = (rest + stretch) * scale
        return v, v[:, :16]
