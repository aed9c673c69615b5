"""Photo -> perception -> optimizer -> result folder."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from easyhoi.config import EasyHOIConfig, get_preset

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
    out_dir: str | Path | None = None,
    config: EasyHOIConfig | None = None,
    *,
    seed: int = 0,
    provided=None,
    prompts=None,
    progress: Callable[[str, int, int, dict], None] | None = None,
    say: Callable[[str], None] | None = None,
) -> Reconstruction:
    """Reconstruct the hand and the held object of one photo.

    Args:
        image_path: the photo (any format PIL reads; decoded by content).
        out_dir: folder for the outputs (None: nothing written).
        config: :class:`EasyHOIConfig` (default: the "fast" preset).
        seed: random seed (same input + seed -> same output).
        provided: :class:`easyhoi.perception.chain.Provided` results of other tools.
        prompts: :class:`easyhoi.perception.prompts.Prompts` pointing at the object / hand.
        progress: optimizer progress callback ``(stage, iteration, max_iters, losses)``.
        say: callback for perception step names.
    """
    from dataclasses import replace

    from easyhoi.io.image import load_image

    t0 = time.perf_counter()
    image = load_image(image_path)  # bad photos fail first, before any heavy import

    from easyhoi.optim.run import optimize
    from easyhoi.perception.chain import perceive

    cfg = config or get_preset("fast")
    cfg = replace(cfg, optim=replace(cfg.optim, seed=seed))
    inp, report = perceive(
        image.rgb, cfg, progress=say, seed=seed, provided=provided, prompts=prompts
    )
    result = optimize(inp, cfg.optim, progress=progress)
    files = []
    if out_dir is not None:
        from easyhoi.io.result_folder import write_result_folder

        files = write_result_folder(result, inp, Path(out_dir), Path(image_path).name)
    return Reconstruction(result, inp, report.to_dict(), files, time.perf_counter() - t0)
