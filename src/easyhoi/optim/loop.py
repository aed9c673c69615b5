"""The optimizer's loop machinery shared by the three stages: stage bookkeeping
(:class:`StageLoop`), early stopping and the coarse-to-fine phase loop (:func:`run_phases`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from easyhoi.errors import OptimizationError

__all__ = [
    "Patience",
    "Phase",
    "StageLoop",
    "early_stop",
    "phase_sizes",
    "restore",
    "run_phases",
    "snapshot",
]


def phase_sizes(max_iters: int, phases: int) -> list[int]:
    """Split ``max_iters`` into ``phases`` near-equal parts (earlier phases get the remainder)."""
    base, rest = divmod(int(max_iters), phases)
    return [base + (1 if i < rest else 0) for i in range(phases)]


def check_finite_loss(stage: str, terms: dict) -> None:
    """Raise :class:`OptimizationError` naming ``stage`` when a loss term is NaN or infinite."""
    for k, v in terms.items():
        if not math.isfinite(float(v)):
            raise OptimizationError(
                f"stage {stage!r}: loss term {k!r} became {float(v)} (diverged); try a smaller "
                "learning rate or check the input masks and meshes"
            )


class Patience:
    """Early stopping: exhausted once ``patience`` steps pass without a ``min_delta`` gain.

    ``patience = 0`` never stops (the paper preset runs its full schedule).
    """

    def __init__(self, patience: int, min_delta: float):
        self.patience = int(patience)
        self.min_delta = float(min_delta)
        self.reset()

    def reset(self) -> None:
        self.best = math.inf
        self.since_best = 0

    def exhausted(self, value: float) -> bool:
        """Record ``value``; True when the caller should stop."""
        if value < self.best - self.min_delta:
            self.best, self.since_best = value, 0
        else:
            self.since_best += 1
        return bool(self.patience) and self.since_best >= self.patience


class StageLoop:
    """Bookkeeping shared by the stages: history, progress callback, best state, stopping.

    Args:
        name (str): Stage name (for the callback and errors).
        max_iters (int): Iteration cap (for the callback).
        history_every (int): Record every this many iterations.
        progress (callable or None): ``progress(stage, iteration, max_iters, terms)``.
    """

    def __init__(self, name: str, max_iters: int, history_every: int, progress=None):
        self.name = name
        self.max_iters = max_iters
        self.every = max(1, int(history_every))
        self.progress = progress
        self.history: list[dict] = []
        self.best_score = math.inf
        self.best_state = None
        self.best_iter = -1

    def record(self, it: int, terms: dict, force: bool = False) -> None:
        """Check the terms for NaN; store and report them every ``history_every`` iterations."""
        plain = {k: float(v) for k, v in terms.items()}
        check_finite_loss(self.name, plain)
        if force or it % self.every == 0:
            self.history.append({"iter": int(it), **plain})
            if self.progress is not None:
                self.progress(self.name, int(it), int(self.max_iters), plain)

    def offer(self, score: float, state, it: int) -> bool:
        """Keep ``state`` when ``score`` is the lowest so far; returns True when kept."""
        if score < self.best_score:
            self.best_score, self.best_state, self.best_iter = float(score), state, int(it)
            return True
        return False

    def reset_best(self) -> None:
        self.best_score, self.best_state, self.best_iter = math.inf, None, -1

    @staticmethod
    def step(opt, loss: torch.Tensor) -> None:
        """One optimizer step on ``loss`` (gradients cleared first)."""
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    def restore_best(self, load) -> None:
        """``load(best_state)`` when a state was kept (the stage's variables go back to it)."""
        if self.best_state is not None:
            load(self.best_state)


def early_stop(loss: float, stop_loss: float, patience: Patience, total: float) -> str | None:
    """``"stop_loss"`` once ``loss < stop_loss``, else ``"patience"`` once ``total`` stopped
    improving (:meth:`Patience.exhausted`), else None."""
    if loss < stop_loss:
        return "stop_loss"
    if patience.exhausted(total):
        return "patience"
    return None


def snapshot(tensors) -> tuple[torch.Tensor, ...]:
    """Detached copies of ``tensors``: a state for :meth:`StageLoop.offer`."""
    return tuple(t.detach().clone() for t in tensors)


def restore(tensors, state) -> None:
    """Copy a :func:`snapshot` back into ``tensors`` in place."""
    with torch.no_grad():
        for t, s in zip(tensors, state, strict=True):
            t.copy_(s)


@dataclass
class Phase:
    """One coarse-to-fine phase of :func:`run_phases`.

    ``context`` is what the stage's ``begin(fraction)`` built for it (the render size, masks and
    camera at that resolution); ``patience`` is the phase's own early-stopping counter.
    """

    index: int
    fraction: float
    iterations: int
    context: object
    patience: Patience


def run_phases(
    loop: StageLoop,
    fractions: Sequence[float],
    max_iters: int,
    opt: torch.optim.Optimizer | None,
    patience: tuple[int, float],
    begin: Callable[[float], object],
    step: Callable[[Phase, int], tuple[torch.Tensor | None, str | None]],
    load: Callable[[object], None],
    *,
    reset_best: bool = True,
) -> tuple[int, str, Phase]:
    """The coarse-to-fine loop of every stage.

    ``max_iters`` is split over the render ``fractions`` (:func:`phase_sizes`); each phase calls
    ``begin(fraction)`` once, then ``step(phase, iteration)`` per iteration, which records and
    offers the state to ``loop`` and returns ``(loss, reason)``: a non-empty ``reason`` ends the
    phase, else one optimizer step is taken on ``loss``. At the end of a phase the best state
    offered in it (``reset_best``: in that phase only; else since the stage's own resets) is
    loaded back with ``load``, so each phase starts from the previous phase's best.

    With ``opt`` None (nothing to optimise) a single phase of 0 iterations at the first
    fraction runs, stop reason ``"nothing_to_optimise"``.

    Returns:
        (iterations run, stop reason of the last phase, the last :class:`Phase`).
    """
    sizes = phase_sizes(max_iters, len(fractions)) if opt is not None else [0]
    it, reason, phase = 0, "max_iters", None
    for index, (frac, n_iters) in enumerate(zip(fractions, sizes, strict=False)):
        phase = Phase(index, frac, n_iters, begin(frac), Patience(*patience))
        if reset_best:
            loop.reset_best()
        reason = "max_iters" if opt is not None else "nothing_to_optimise"
        for _ in range(n_iters):
            loss, stop = step(phase, it)
            if stop:
                reason = stop
                break
            loop.step(opt, loss)
            it += 1
        loop.restore_best(load)
    return it, reason, phase
