"""A run's settings, resolved once: configuration, hand model instance, seed and device.

Every entry point (the CLI commands, the batch worker, the web demo, library callers of
:func:`easyhoi.pipeline.reconstruct_photo`) builds one :class:`RunSettings` with
:func:`resolve_run` and passes it down: perception fits the hand with ``settings.hand_model``,
the optimizer poses the same instance, and the pictures of the result folder draw it. Nothing
below this point loads a hand model or picks a seed of its own, so a MANO folder given once
(``--mano-dir``) reaches every step, and ``optim.seed`` is the one seed of the run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from easyhoi.config import EasyHOIConfig, get_preset, with_overrides
from easyhoi.device import DEVICES, resolve_device
from easyhoi.errors import InvalidInputError

__all__ = ["DEVICES", "RunSettings", "resolve_run"]


@dataclass(frozen=True)
class RunSettings:
    """Everything one reconstruction needs besides its inputs.

    Attributes:
        config: The configuration tree; ``config.optim.seed`` is the run's seed.
        hand_model: The hand model instance (``config.hand_model``, in ``config.optim.dtype``),
            shared by perception, the optimizer and the pictures. Models are stateless layers,
            so one instance serves any number of photos.
        device: Where the large models live: "cpu", "cuda" or "cuda:N", already resolved
            ("auto" never appears here). The hand model stays on the CPU (perception fits it
            there).
        optim_device: Where the optimizer works on its own copy of the hand model: ``device``
            when the device was named, the CPU when it was "auto". Measured on an H200 the
            optimizer's problems (a few thousand vertices, renders of a few hundred pixels)
            are too small to fill a GPU: the fast preset took 2.2 times as long there as with
            the CPU's numba kernels (docs/gpu.md), while the large models gain from it.
    """

    config: EasyHOIConfig
    hand_model: object
    device: str = "cpu"
    optim_device: str = "cpu"

    @property
    def seed(self) -> int:
        """The run's seed (``config.optim.seed``): every random choice derives from it."""
        return self.config.optim.seed

    def with_seed(self, seed: int) -> RunSettings:
        """The same settings with another seed (checked like ``--set optim.seed=...``)."""
        return replace(self, config=with_overrides(self.config, {"optim.seed": seed}))


def resolve_run(
    config: EasyHOIConfig | None = None,
    *,
    seed: int | None = None,
    hand_model=None,
    device: str | None = None,
) -> RunSettings:
    """Resolve a run's settings once.

    Args:
        config: The configuration (None: the default preset).
        seed: Replaces ``config.optim.seed`` when given (None: keep the configuration's seed).
        hand_model: An already loaded hand model to use (None: load ``config.hand_model`` from
            ``config.mano_dir``, in ``config.optim.dtype``).
        device: "cpu", "cuda", "cuda:N" or "auto" (the large models on cuda when torch sees a
            GPU, the optimizer on the CPU); None uses ``config.device``. Resolved here, once
            (:func:`easyhoi.device.resolve_device`).

    Returns:
        The resolved :class:`RunSettings`.

    Raises:
        InvalidInputError: A bad seed or device, cuda asked for where torch sees no GPU, or an
            unknown hand model.
        MANONotFoundError: ``config.hand_model`` is "mano" and no MANO file is found.
        UnsafeFileError: The MANO file holds content that is refused.
    """
    cfg = get_preset() if config is None else config
    if not isinstance(cfg, EasyHOIConfig):
        raise InvalidInputError(f"config must be an EasyHOIConfig, got {type(cfg).__name__}")
    if seed is not None:
        cfg = with_overrides(cfg, {"optim.seed": seed})
    asked = cfg.device if device is None else device
    device = resolve_device(asked)
    if hand_model is None:
        from easyhoi.hand import load_hand_model

        hand_model = load_hand_model(cfg.hand_model, cfg.mano_dir, dtype=cfg.optim.torch_dtype)
    optim_device = "cpu" if asked == "auto" else device
    return RunSettings(config=cfg, hand_model=hand_model, device=device, optim_device=optim_device)
