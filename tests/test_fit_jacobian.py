"""The keypoint fit's Jacobian, taken part by part: the same bits as
torch.autograd.functional.jacobian of all residuals, and no import of torch's symbolic-shape
module (sympy) in a fresh process."""

from __future__ import annotations

import functools
import subprocess
import sys

import torch

from easyhoi.hand import fit as fit_mod
from easyhoi.hand.fit import fit_keypoints
from easyhoi.hand.openhand import OpenHand
from easyhoi.structures import Camera, HandParams


def _reference(fs, x):
    """The definition: the stacked residuals from a separate forward pass and the vectorised
    autograd Jacobian of all of them at once."""

    def f(z):
        return torch.cat([g(z) for g in fs], dim=1)

    r = f(x).detach()
    J = torch.autograd.functional.jacobian(lambda z: f(z).sum(0), x, vectorize=True)
    return r, J.permute(1, 0, 2)


def _target(model, seed):
    g = torch.Generator().manual_seed(seed)
    dt = torch.float64
    params = HandParams(
        0.3 * torch.randn(2, 3, generator=g, dtype=dt),
        torch.tensor([[0.02, -0.01, 0.55], [-0.05, 0.03, 0.62]], dtype=dt),
        0.25 * torch.randn(2, 45, generator=g, dtype=dt),
        torch.zeros(2, 10, dtype=dt),
    )
    kp = model(params).keypoints
    cam = Camera.from_focal(700.0, 640, 480, dtype=dt)
    uv, _ = cam.project(kp)
    return kp, uv + torch.randn(uv.shape, generator=g, dtype=dt), cam


def test_jacobian_equals_autograd_functional_bit_for_bit():
    model = OpenHand(dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    w = torch.rand(2, 21, 2, generator=g, dtype=torch.float64)
    kp3, _, _ = _target(model, 1)

    def keypoints(x, kp_weights):
        params = HandParams(x[:, :3], x[:, 3:6], x[:, 6:51], torch.zeros(2, 10, dtype=x.dtype))
        kp = model(params, vertex_ids=torch.zeros(0, dtype=torch.long)).keypoints
        return ((kp - kp3) * kp_weights[..., :1]).reshape(2, -1)

    def prior(x, kp_weights):
        return torch.cat([x[:, 6:51] * 0.3, torch.relu(x[:, 6:9] - 0.01)], dim=1)

    x = 0.1 * torch.randn(2, 51, generator=g, dtype=torch.float64)
    x[:, 3:6] += torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)
    fs = [functools.partial(keypoints, kp_weights=w), functools.partial(prior, kp_weights=w)]
    r, J = fit_mod._residuals_and_jacobian(fs, x)
    r_ref, J_ref = _reference(fs, x)
    assert J.shape == (2, 63 + 45 + 3, 51)
    assert torch.equal(r, r_ref) and torch.equal(J, J_ref)
    assert J.abs().max() > 0.1  # a real Jacobian (the pose rows hold the identity)


def test_fit_equals_fit_with_reference_jacobian(monkeypatch):
    model = OpenHand(dtype=torch.float64)
    kp3, uv, cam = _target(model, 2)
    rel = kp3 - kp3.mean(1, keepdim=True)
    new = fit_keypoints(model, rel, keypoints2d=uv, camera=cam, relative_3d=True)
    monkeypatch.setattr(fit_mod, "_residuals_and_jacobian", _reference)
    old = fit_keypoints(model, rel, keypoints2d=uv, camera=cam, relative_3d=True)
    for name in ("global_orient", "transl", "pose", "betas"):
        assert torch.equal(getattr(new.params, name), getattr(old.params, name))
    assert new.error_2d.max() < 10.0  # it fitted (pixels, noisy targets)


def test_fit_imports_no_sympy():
    child = (
        "import sys, torch\n"
        "from easyhoi.hand.openhand import OpenHand\n"
        "from easyhoi.hand.fit import fit_keypoints\n"
        "m = OpenHand(dtype=torch.float64)\n"
        "fit_keypoints(m, 0.05 * torch.randn(1, 21, 3, dtype=torch.float64))\n"
        "print('sympy' in sys.modules, 'torch.fx.experimental.symbolic_shapes' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    assert out.split() == ["False", "False"]
