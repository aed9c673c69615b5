"""Photo -> perception -> optimizer -> result folder."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from easyhoi.config import EasyHOIConfig
from easyhoi.settings import RunSettings, resolve_run

logger = logging.getLogger(__name__)


@dataclass
class Reconstruction:
    """Everything one photo produced."""

    result: object  # HOIResult
    inp: object  # HOIInput
    perception: dict
    files: list
    seconds: float


def reconstruct_photo(
    image_path: str | Path,
    folder: str | Path | None = None,
    settings: RunSettings | EasyHOIConfig | None = None,
    *,
    seed: int | None = None,
    provided=None,
    progress: Callable[[str, int, int, dict], None] | None = None,
    say: Callable[[str], None] | None = None,
    prompts=None,
    strict: bool = False,
) -> Reconstruction:
    """Reconstruct the hand and the held object of one photo.

    Args:
        image_path: The photo (any format PIL reads; decoded by content).
        folder: The result folder to write (created or replaced whole; see
            :func:`easyhoi.result_folder.write_result_folder`); None writes nothing.
        settings: The run's :class:`~easyhoi.settings.RunSettings`, or a configuration to
            resolve them from (None: the default preset).
        seed: Replaces the run's seed (``optim.seed``) when given; None keeps it. Same input
            and seed give the same output.
        provided: :class:`easyhoi.perception.chain.Provided` results of other tools.
        progress: Optimizer progress callback ``(stage, iteration, max_iters, losses)``.
        say: Callback for perception step names.
        prompts: :class:`easyhoi.perception.prompts.Prompts` in pixels of the photo as stored
            (before downscaling); checked against its size before any other work and recorded
            in ``result.json`` (``meta.prompts``).
        strict: Raise :class:`~easyhoi.errors.LowConfidenceError` when perception reports a
            low-confidence mask, before the optimizer runs and before anything is written.
    """
    from easyhoi.io.image import load_image

    t0 = time.perf_counter()
    image = load_image(image_path)  # bad photos fail first, before any heavy import
    given = None
    if prompts is not None and not prompts.empty:
        given = prompts.check(*image.original_size)
        h, w = image.rgb.shape[:2]
        prompts = scale_prompts(given, image.scale, (w, h))

    from easyhoi.optim.run import optimize
    from easyhoi.perception.chain import perceive

    if isinstance(settings, RunSettings):
        run = settings if seed is None else settings.with_seed(seed)
    else:
        run = resolve_run(settings, seed=seed)
    inp, report = perceive(image.rgb, run, progress=say, provided=provided, prompts=prompts)
    if given is not None:
        inp.meta["prompts"] = given.to_dict()
        inp.meta["prompts_photo_size"] = list(image.original_size)  # what their pixels are of
    if strict and report.low_confidence:
        from easyhoi.perception.feedback import low_confidence_error

        prompted = given is not None and given.has_object_prompt
        raise low_confidence_error(report.to_dict(), prompted)
    result = optimize(
        inp, run.config.optim, hand_model=run.hand_model, progress=progress, device=run.optim_device
    )
    files = []
    if folder is not None:
        from easyhoi.result_folder import write_result_folder

        files = write_result_folder(
            result, inp, folder, hand_model=run.hand_model, title=Path(image_path).name,
            full_size=run.config.full_size_pictures,
        )  # fmt: skip
    return Reconstruction(result, inp, report.to_dict(), files, time.perf_counter() - t0)


def scale_prompts(prompts, scale: float, size: tuple[int, int]):
    """``prompts`` in pixels of the photo resized by ``scale`` to ``size`` (width, height).

    Coordinates are continuous (pixel ``i`` spans ``[i, i + 1)``), so they scale as they are;
    points are kept inside the resized photo (its size was rounded).
    """
    from easyhoi.perception.prompts import Prompts

    W, H = size

    def pt(p):
        return (min(p[0] * scale, W - 1e-3), min(p[1] * scale, H - 1e-3))

    box = prompts.object_box
    return Prompts(
        object_points=tuple(pt(p) for p in prompts.object_points),
        object_box=None if box is None else tuple(v * scale for v in box),
        hand_point=None if prompts.hand_point is None else pt(prompts.hand_point),
        background_points=tuple(pt(p) for p in prompts.background_points),
        object_choice=prompts.object_choice,
    )
