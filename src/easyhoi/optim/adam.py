"""Adam, step for step the arithmetic of ``torch.optim.Adam`` on the CPU, without its start-up.

Every ``torch.optim`` optimizer imports ``torch._dynamo`` (the compiler front end) when it is
built and at its first step: about a second of CPU per process on a small machine, more than a
stage of the fast preset costs. This class does the same update as ``torch.optim.Adam``'s
single-tensor path (the one it takes for CPU tensors; no weight decay, no AMSGrad), in the same
order of floating-point operations, so the optimizer's results are the same bits (a test
compares the two over many steps).

Update for a parameter ``p`` with gradient ``g`` at step ``t`` (1-based)::

    m = lerp(m, g, 1 - beta1)            v = beta2 v + (1 - beta2) g^2
    p -= lr / (1 - beta1^t) * m / (sqrt(v) / sqrt(1 - beta2^t) + eps)
"""

from __future__ import annotations

from collections.abc import Iterable

import torch

from easyhoi.errors import InvalidInputError

__all__ = ["Adam"]


class Adam:
    """Adam over parameter groups, with the interface the optimizer stages use.

    Args:
        params: Tensors, or dicts ``{"params": [...], "lr": ..., "betas": ..., "eps": ...}``
            (per-group values override the defaults), like ``torch.optim.Adam``.
        lr: Learning rate.
        betas: Decay rates of the first and second moment averages.
        eps: Added to the denominator.
    """

    def __init__(
        self,
        params: Iterable,
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ):
        defaults = {"lr": float(lr), "betas": tuple(float(b) for b in betas), "eps": float(eps)}
        groups = list(params)
        if not groups:
            raise InvalidInputError("Adam got an empty parameter list")
        if not isinstance(groups[0], dict):
            groups = [{"params": groups}]
        self.param_groups: list[dict] = []
        for g in groups:
            group = {**defaults, **g, "params": list(g["params"])}
            b1, b2 = group["betas"]
            if group["lr"] < 0 or group["eps"] < 0 or not (0 <= b1 < 1 and 0 <= b2 < 1):
                raise InvalidInputError(
                    f"invalid Adam settings: lr {group['lr']}, betas {group['betas']}, "
                    f"eps {group['eps']}"
                )
            for p in group["params"]:
                if not isinstance(p, torch.Tensor) or not p.is_leaf:
                    raise InvalidInputError("Adam optimises leaf tensors")
            self.param_groups.append(group)
        self.state: dict[torch.Tensor, dict] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Forget the gradients (None, or zeros in place with ``set_to_none=False``)."""
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    p.grad.detach_().zero_()

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient."""
        for group in self.param_groups:
            lr, (beta1, beta2), eps = group["lr"], group["betas"], group["eps"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                grad = p.grad
                state = self.state.get(p)
                if state is None:
                    # the step counter is a float tensor like torch's (its rounding is part of
                    # the arithmetic), kept on the CPU as torch keeps it (it is read every step)
                    dtype = torch.float64 if torch.get_default_dtype() == torch.float64 else None
                    state = {
                        "step": torch.tensor(0.0, dtype=dtype or torch.float32, device="cpu"),
                        "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                        "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
                    }
                    self.state[p] = state
                exp_avg, exp_avg_sq = state["exp_avg"], state["exp_avg_sq"]
                state["step"] += 1
                exp_avg.lerp_(grad, 1 - beta1)
                exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
                step = state["step"].item()
                bias_correction1 = 1 - beta1**step
                bias_correction2 = 1 - beta2**step
                step_size = lr / bias_correction1
                denom = (exp_avg_sq.sqrt() / bias_correction2**0.5).add_(eps)
                p.addcdiv_(exp_avg, denom, value=-step_size)
