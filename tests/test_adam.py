"""easyhoi's Adam against torch.optim.Adam: the same bits over many steps, no torch._dynamo."""

import subprocess
import sys

import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.optim.adam import Adam


def _problem(dtype, seed: int):
    g = torch.Generator().manual_seed(seed)
    target = torch.randn(7, 3, generator=g, dtype=dtype)
    a = torch.randn(7, 3, generator=g, dtype=dtype)
    b = torch.randn(5, generator=g, dtype=dtype)
    return target, a, b


def _loss(a, b, target):
    return ((a - target) ** 2).sum() + (b.sin() * a[:5, 0]).sum() + (b**4).mean()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_same_bits_as_torch_adam(dtype):
    target, a0, b0 = _problem(dtype, 3)
    runs = []
    for cls in (Adam, torch.optim.Adam):
        a, b = a0.clone().requires_grad_(), b0.clone().requires_grad_()
        opt = cls([{"params": [a], "lr": 0.05}, {"params": [b], "lr": 0.01, "eps": 1e-6}],
                  betas=(0.8, 0.99))  # fmt: skip
        for i in range(60):
            if i == 30:
                opt.param_groups[-1]["lr"] = 0.003  # changed mid-run, as the refine stage does
            opt.zero_grad(set_to_none=True)
            _loss(a, b, target).backward()
            if i % 7 == 3:
                b.grad = None  # a parameter without a gradient is left alone that step
            opt.step()
        runs.append((a.detach(), b.detach()))
    torch.testing.assert_close(runs[0][0], runs[1][0], rtol=0, atol=0)
    torch.testing.assert_close(runs[0][1], runs[1][1], rtol=0, atol=0)
    assert not torch.equal(runs[0][0], a0)  # it did move


def test_minimises_a_quadratic():
    x = torch.tensor([3.0, -2.0], requires_grad=True)
    opt = Adam([x], lr=0.1)
    for _ in range(300):
        opt.zero_grad()
        (x**2).sum().backward()
        opt.step()
    assert x.abs().max() < 1e-2


def test_zero_grad_in_place_and_bad_settings():
    x = torch.ones(2, requires_grad=True)
    opt = Adam([x])
    (x * 2).sum().backward()
    g = x.grad
    opt.zero_grad(set_to_none=False)
    assert x.grad is g and torch.equal(g, torch.zeros(2))
    with pytest.raises(InvalidInputError):
        Adam([])
    with pytest.raises(InvalidInputError):
        Adam([x], lr=-1.0)
    with pytest.raises(InvalidInputError):
        Adam([torch.ones(2, requires_grad=True) * 2])  # not a leaf


def test_no_dynamo_import():
    code = (
        "import sys, torch\n"
        "from easyhoi.optim.adam import Adam\n"
        "x = torch.ones(3, requires_grad=True)\n"
        "opt = Adam([x], lr=0.1)\n"
        "(x * x).sum().backward()\n"
        "opt.step()\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
