"""The ``easyhoi`` command line.

Exit codes are :class:`easyhoi.errors.ExitCode` (listed by ``easyhoi --help``).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from easyhoi import __version__, cli_parser
from easyhoi.errors import (
    EasyHOIError,
    ExitCode,
    InvalidInputError,
    as_resource_error,
)

logger = logging.getLogger("easyhoi")


# ----------------------------------------------------------------------------------------------
# commands
# ----------------------------------------------------------------------------------------------


def cmd_demo_hand(args) -> int:
    """Pose the built-in hand, write meshes and pictures (works without any model file)."""
    from easyhoi.hand import load_hand_model
    from easyhoi.hand.regions import grasp_pose, plot_regions
    from easyhoi.io.atomic import atomic_write_bytes
    from easyhoi.structures import HandParams

    model = load_hand_model(args.hand_model, args.mano_dir)  # a missing MANO file fails first
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rest = model(HandParams.zeros(1)).to_trimesh()
    params = HandParams.zeros(1)
    params = HandParams(params.global_orient, params.transl, grasp_pose(model).float(), None)
    posed = model(params).to_trimesh()
    files = []
    for name, mesh in (("hand_rest.ply", rest), ("hand_grasp.ply", posed)):
        atomic_write_bytes(out / name, mesh.export(file_type="ply"))
        files.append(out / name)
    files.append(plot_regions(model, out / "hand_regions.png"))
    _say(args, f"hand model '{model.name}': {model.num_vertices} vertices, "
         f"{len(model.faces)} faces, watertight={rest.is_watertight}, "
         f"volume={rest.volume * 1e6:.0f} cm^3")  # fmt: skip
    for f in files:
        _say(args, f"wrote {f}")
    return 0


def cmd_example(args) -> int:
    """Generate a synthetic photo of a hand holding an object, reconstruct it end to end and
    compare the result with the scene's truth (:mod:`easyhoi.synth.against_truth`)."""
    import time

    from PIL import Image

    from easyhoi.errors import NoHandError, NoObjectError
    from easyhoi.io.atomic import atomic_write_bytes
    from easyhoi.pipeline import reconstruct_photo
    from easyhoi.synth import make_scene

    run = run_from_args(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    _say(args, f"generating synthetic scene (seed {run.seed}) ...")
    scene = make_scene(run.seed, image_size=args.size)
    photo = out / f"synthetic_{run.seed}.png"
    folder = out / photo.stem
    import io

    buf = io.BytesIO()
    Image.fromarray(scene.image).save(buf, format="PNG")
    atomic_write_bytes(photo, buf.getvalue())
    _say(args, f"wrote {photo} ({scene.object.kind}, {scene.grasp.grasp_type} grasp)")
    try:
        with _Progress(args, photo.name) as bar:
            rec = reconstruct_photo(photo, folder, run, progress=bar.update, say=bar.step)
        result = rec.result
        how = "photo -> perception -> optimizer"
        # as `reconstruct` does: what the product doubts, and whether the hand touches
        _tell_perception(args, photo.name, rec.perception)
        _tell_contact(photo.name, result.plausibility)
        from easyhoi.synth.against_truth import against_truth, truth_line

        truth = truth_line(against_truth(scene, rec.inp, result, run.hand_model))
    except (NoHandError, NoObjectError) as exc:
        # the generated photo defeated the offline perception: use the scene's own (perturbed)
        # perception outputs so the demo still shows the optimizer, and say so
        _err(f"perception failed on the synthetic photo ({exc}); using the scene's masks")
        from easyhoi.optim.run import optimize
        from easyhoi.result_folder import write_result_folder

        inp = scene.to_hoi_input("hamer")
        result = optimize(inp, run.config.optim, hand_model=run.hand_model, device=run.optim_device)
        write_result_folder(result, inp, folder, hand_model=run.hand_model, title=photo.name)
        how = "synthetic perception outputs -> optimizer"
        truth = None
    p = result.plausibility
    _say(args, f"reconstructed ({how}) in {time.perf_counter() - t0:.1f} s")
    from easyhoi.optim.run import SELF_CONSISTENCY_KEYS

    phys = {k: v for k, v in p.items() if k not in SELF_CONSISTENCY_KEYS}
    own = {k: v for k, v in p.items() if k in SELF_CONSISTENCY_KEYS}
    _say(args, "plausibility: " + ", ".join(f"{k}={_fmt(v)}" for k, v in phys.items()))
    if own:
        items = ", ".join(f"{k}={_fmt(v)}" for k, v in own.items())
        _say(args, f"fit to its own masks (self-consistency, not accuracy): {items}")
    if truth:
        _say(args, truth)
    _say(args, f"results: {folder}  (open {folder / 'report.html'})")
    return 0


def _fmt(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def cmd_reconstruct(args) -> int:
    """Reconstruct hand + object from one photo into ``--out/<stem>``; several photos run as a
    batch (one folder each, a manifest; see :mod:`easyhoi.batch`)."""
    from easyhoi.pipeline import reconstruct_photo

    prompts = _prompts_from_args(args)
    _check_out_dir(Path(args.out))
    # the config, the seed and the hand model (a missing or unsafe MANO file fails now, not
    # after perception) are resolved once, before any photo is read
    run = run_from_args(args)
    provided = _provided_from_args(args)
    if len(args.images) > 1:
        if provided is not None:
            raise InvalidInputError("--hand-mask/--object-mask/... imports need exactly one photo")
        if prompts is not None:
            raise InvalidInputError(
                "--object-point/--object-box/--hand-point/--background-point/--object-choice "
                "need exactly one photo (for many photos: easyhoi batch --prompts FILE)"
            )
        return _run_batch(args, [Path(p) for p in args.images], None, run)
    image = Path(args.images[0])
    folder = Path(args.out) / image.stem  # an existing one was refused by the early check
    with _Progress(args, image.name) as bar:
        rec = reconstruct_photo(
            image, folder, run, provided=provided, progress=bar.update, say=bar.step,
            prompts=prompts, strict=args.strict,
        )  # fmt: skip
    _tell_perception(args, image, rec.perception, prompts)
    _tell_contact(image, getattr(getattr(rec, "result", None), "plausibility", None), prompts)
    _say(args, f"{image}: done in {rec.seconds:.1f} s -> {folder} (open report.html)")
    for f in rec.files:
        logger.info("wrote %s", f)
    return ExitCode.OK


def cmd_batch(args) -> int:
    """Reconstruct every photo of a folder; ``manifest.jsonl``/``.csv`` record each outcome."""
    folder = Path(args.folder)
    images = _batch_images(args)
    if args.engine == "local":
        from easyhoi.batch import ReconstructWorker
        from easyhoi.distributed import start_fork_server

        start_fork_server(ReconstructWorker.preload)  # its imports overlap the set-up below
    prompts = None
    if args.prompts:
        from easyhoi.batch import plan_tasks
        from easyhoi.batch_prompts import load_prompts_file

        photos = {t.key: t.image for t in plan_tasks(images, args.out, root=folder)}
        prompts = load_prompts_file(args.prompts, photos)
    return _run_batch(args, images, folder, run_from_args(args), prompts)


def _batch_images(args) -> list[Path]:
    """The photos of ``batch``'s folder, after checking ``--out`` (no torch needed)."""
    from easyhoi.batch import discover_images

    folder = Path(args.folder)
    _check_out_dir(Path(args.out))
    images = discover_images(folder, recursive=args.recursive, exclude=[args.out])
    if not images:
        hint = "" if args.recursive else " (add --recursive to include subfolders)"
        raise InvalidInputError(f"no photos found in {folder}{hint}")
    return images


def _run_batch(args, images: list[Path], root: Path | None, run, prompts=None) -> int:
    """Run the batch runner over ``images`` with a progress bar; the batch's exit code.

    ``prompts``: batch photo name -> Prompts (``batch --prompts``).
    """
    from tqdm import tqdm

    from easyhoi.batch import ReconstructWorker, run_batch

    worker = ReconstructWorker(run, prompts=prompts, strict=getattr(args, "strict", False))
    counts = {"ok": 0, "failed": 0, "skipped": 0}
    bar = tqdm(total=len(images), unit="photo", desc="batch",
               disable=args.quiet or not sys.stderr.isatty())  # fmt: skip

    def progress(rec, done: int, total: int) -> None:
        counts[rec.status] += 1
        bar.update(1)
        bar.set_postfix(counts)
        if rec.status == "failed":
            tqdm.write(f"{rec.path}: {rec.error_type}: {rec.error}", file=sys.stderr)
        for kind in ("notes", "warnings"):
            for line in rec.info.get(kind) or ():
                tqdm.write(f"{rec.path}: {kind[:-1]}: {line}", file=sys.stderr)

    try:
        summary = run_batch(
            images, args.out, worker, engine=getattr(args, "engine", "inline"),
            workers=_batch_workers(args), resume=getattr(args, "resume", False),
            seed=run.seed, ray_address=getattr(args, "ray_address", None),
            progress=progress, root=root, wait=getattr(args, "wait", False),
        )  # fmt: skip
    finally:
        bar.close()
    _say(args, f"batch: {summary.line()}; manifest: {summary.manifest}")
    return summary.exit_code


def _batch_in_process(args) -> bool:
    """Whether ``batch`` reconstructs in this process (the inline engine) rather than in worker
    processes."""
    return getattr(args, "engine", "local") == "inline"


def _batch_workers(args) -> int:
    """``--workers``, else one worker process per available core (1 for the inline engine)."""
    workers = getattr(args, "workers", None)
    if workers is not None:
        return workers
    if getattr(args, "engine", "inline") == "inline":
        return 1  # several photos given to reconstruct: one warm process, this one
    from easyhoi.distributed import available_cores

    return available_cores()


def cmd_demo(args) -> int:
    """Serve the web demo on this machine (needs the [demo] extra: gradio)."""
    from easyhoi.app import launch

    if args.host not in ("127.0.0.1", "localhost", "::1"):
        logger.warning("serving the demo on %s: other machines can reach it", args.host)
    launch(args.host, args.port, preset=args.preset, max_upload_mb=args.max_upload_mb,
           quiet=args.quiet)  # fmt: skip
    return 0


def cmd_bench(args) -> int:
    """Synthetic benchmark with ground truth: the paper's tables (docs/benchmark.md)."""
    import torch

    from easyhoi.synth.benchmark import BenchmarkSettings, run_benchmark
    from easyhoi.synth.tables import save_report, tables_markdown

    torch.set_num_threads(1)  # small ops run many times slower oversubscribed
    scenes = 3 if args.quick else args.scenes
    paper = args.paper_scenes if args.paper_scenes is not None else (1 if args.quick else 3)
    cap = args.paper_cap if args.paper_cap is not None else (100 if args.quick else 0)
    from easyhoi.config import get_preset, parse_overrides

    overrides = parse_overrides(args.set, get_preset("fast")) if args.set else {}
    settings = BenchmarkSettings(scenes=scenes, seed=args.seed, paper_scenes=min(paper, scenes),
                                 paper_cap=cap, perturbation=args.perturbation,
                                 sd_steps=args.sd_steps, gallery=min(3, scenes),
                                 loss_ablation=not args.light, sd_cone=not args.light,
                                 fast_overrides=overrides)  # fmt: skip
    report = run_benchmark(settings, progress=lambda msg: _say(args, msg))
    paths = save_report(report, args.out)
    _say(args, "\n" + tables_markdown(report))
    load = report["machine"]
    _say(args, f"wall time {report['wall_seconds']:.0f} s; load average before "
         f"{load['load_before']}, after {load['load_after']}")  # fmt: skip
    for path in paths.values():
        _say(args, f"wrote {path}")
    return 0


def cmd_eval(args) -> int:
    """Metrics of result folders (plausibility, and against ground truth when given)."""
    import json

    from easyhoi.evaluate import evaluate_result

    rows = []
    for folder in args.results:
        res = evaluate_result(
            folder, args.gt_object, args.gt_hand, align=args.align, simulate=not args.no_sim,
            sim_steps=args.sim_steps,
        )  # fmt: skip
        rows.append(res)
        _say(args, f"{folder}:")
        for k, v in res.items():
            if k not in ("folder", "units"):
                _say(args, f"  {k}: {json.dumps(v)}")
    if args.json:
        from easyhoi.io.atomic import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(rows, indent=2))
        _say(args, f"wrote {args.json}")
    return 0


def cmd_doctor(args) -> int:
    """Versions, available backends and what is missing (imports none of the heavy libraries)."""
    from easyhoi.doctor import doctor_lines

    for line in doctor_lines(__version__):
        _say(args, line, force=True)
    return 0


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def run_from_args(args):
    """The run's :class:`~easyhoi.settings.RunSettings` from the command line, resolved once.

    ``--seed N`` is an alias of ``--set optim.seed=N``; giving both with different values is
    refused (InvalidInputError) rather than one silently winning.
    """
    from easyhoi.settings import resolve_run

    return resolve_run(_config_from_args(args))


def _config_from_args(args):
    from dataclasses import replace

    from easyhoi.config import get_preset, parse_overrides, with_overrides

    cfg = get_preset(args.preset)
    cfg = replace(cfg, hand_model=args.hand_model, mano_dir=args.mano_dir)
    if getattr(args, "device", None):
        cfg = replace(cfg, device=args.device)
    perception = {
        "hand": args.hand_backend, "segmenter": args.segmenter, "inpainter": args.inpainter,
        "amodal": args.amodal, "object": args.object_backend,
        "object_shape": getattr(args, "object_shape", None),
    }  # fmt: skip
    for flag, role, name in (("sam_dir", "amodal", "sam"), ("depth_dir", "object", "depth"),
                             ("diffusion_dir", "inpainter", "diffusion"),
                             ("shape_dir", "object", "shap-e"),
                             ("detector_dir", "segmenter", "grounded-sam")):  # fmt: skip
        if getattr(args, flag, None):
            perception[flag] = getattr(args, flag)
            perception[role] = perception[role] or name
    if getattr(args, "full_size_pictures", False):
        cfg = replace(cfg, full_size_pictures=True)
    perception = {k: v for k, v in perception.items() if v}
    if perception:
        cfg = replace(cfg, perception=replace(cfg.perception, **perception))
    overrides = parse_overrides(args.set, cfg) if args.set else {}
    cfg = with_overrides(cfg, overrides)
    seed = getattr(args, "seed", None)
    if seed is not None:
        if cfg.optim.seed != seed and _sets_seed(overrides):
            raise InvalidInputError(
                f"--seed {seed} and --set optim.seed={cfg.optim.seed} disagree; --seed is an "
                "alias of --set optim.seed: give one of them"
            )
        cfg = with_overrides(cfg, {"optim.seed": seed})
    return cfg


def _sets_seed(overrides: dict) -> bool:
    """Whether ``--set`` overrides named the seed (``optim.seed``, or a whole ``optim``)."""
    optim = overrides.get("optim")
    return "optim.seed" in overrides or (isinstance(optim, dict) and "seed" in optim)


def _prompts_from_args(args):
    """The --object-point/--object-box/--hand-point/--background-point prompts (pixels) and
    --object-choice, or None when none given."""
    from easyhoi.perception.prompts import Prompts, parse_numbers

    points = tuple(parse_numbers(t, 2, "--object-point") for t in args.object_point or ())
    box = None if args.object_box is None else parse_numbers(args.object_box, 4, "--object-box")
    hand = None if args.hand_point is None else parse_numbers(args.hand_point, 2, "--hand-point")
    bg = tuple(parse_numbers(t, 2, "--background-point") for t in args.background_point or ())
    prompts = Prompts(
        object_points=points,
        object_box=box,
        hand_point=hand,
        background_points=bg,
        object_choice=args.object_choice,
    )
    if box is not None and not (box[0] < box[2] and box[1] < box[3]):
        raise InvalidInputError(f"--object-box {args.object_box} must have x0 < x1 and y0 < y1")
    return None if prompts.empty else prompts


def _tell_perception(args, image, perception: dict, prompts=None) -> None:
    """Say which hand the result uses when it is not the first, and warn about weak masks."""
    from easyhoi.perception.feedback import hand_choice_note, low_confidence_lines

    note = hand_choice_note(perception)
    if note:
        _err(f"{image}: note: {note}")
    prompted = prompts is not None and prompts.has_object_prompt
    for line in low_confidence_lines(perception, "cli", prompted):
        _err(f"{image}: warning: {line}")


def _tell_contact(image, plausibility: dict, prompts=None) -> None:
    """Warn when the result's hand does not touch its object."""
    from easyhoi.perception.feedback import contact_line

    prompted = prompts is not None and prompts.has_object_prompt
    line = contact_line(plausibility or {}, "cli", prompted)
    if line:
        _err(f"{image}: warning: {line}")


def _check_out_dir(out: Path) -> None:
    """Refuse an output folder that can never be written before any work is done."""
    from easyhoi.limits import check_output_folder

    check_output_folder(out)


def _check_reconstruct_early(args) -> None:
    """The checks of ``reconstruct`` that need no torch: run before torch is imported."""
    _prompts_from_args(args)  # malformed prompts first, as cmd_reconstruct reports them
    _check_out_dir(Path(args.out))
    if len(args.images) == 1:
        _check_photo(Path(args.images[0]))
        _check_no_result(Path(args.out) / Path(args.images[0]).stem, args)


def _check_no_result(folder: Path, args) -> None:
    """Refuse to replace an existing result folder unless ``--overwrite`` was given."""
    if folder.exists() and not getattr(args, "overwrite", False):
        raise InvalidInputError(
            f"{folder} already exists; pass --overwrite to replace it (nothing was changed)"
        )


def _check_photo(path: Path) -> None:
    """Refuse a photo that is missing, not an image or over the size limits before torch and
    the models load (:func:`easyhoi.limits.check_image_header`: only the header is read; a file
    that is an image but corrupt further in still fails, with a named error, when decoded)."""
    from easyhoi.limits import check_image_header

    check_image_header(path)


def _provided_from_args(args):
    keys = ("hand_mask", "object_mask", "amodal_mask", "object_mesh", "hand_params")
    if not any(getattr(args, k) for k in keys):
        return None
    from easyhoi.io.image import load_image, load_mask
    from easyhoi.perception.chain import Provided

    size = original = None
    if args.images:
        img = load_image(args.images[0])
        size = img.rgb.shape[:2]
        original = (img.original_size[1], img.original_size[0])  # (H, W) before downscaling
    kw = {}
    for k in ("hand_mask", "object_mask", "amodal_mask"):
        if getattr(args, k):
            mask = load_mask(getattr(args, k))
            if size is not None and mask.shape != size and mask.shape == original:
                # a mask of the full-size photo: follow the photo's downscaling
                import cv2

                small = cv2.resize(mask.astype("uint8"), (size[1], size[0]),
                                   interpolation=cv2.INTER_NEAREST)  # fmt: skip
                mask = small.astype(bool)
            if size is not None and mask.shape != size:
                raise InvalidInputError(
                    f"{k.replace('_', ' ')} is {mask.shape[0]}x{mask.shape[1]} but the image is "
                    f"{size[0]}x{size[1]} (height x width)"
                )
            kw[k] = mask
    if args.object_mesh:
        from easyhoi.geometry.mesh import load_mesh

        kw["object_mesh"] = load_mesh(args.object_mesh)
    if args.hand_params:
        from easyhoi.perception.importers import load_hamer_hand

        W, H = (size[1], size[0]) if size else (None, None)
        kw["hand"] = load_hamer_hand(args.hand_params, (W, H) if size else None)
    return Provided(**kw)


class _Progress:
    """Per-stage progress bars on stderr (silent with --quiet or when not a terminal)."""

    def __init__(self, args, label: str):
        self.enabled = not args.quiet and sys.stderr.isatty()
        self.label = label
        self.bar = None
        self.stage = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.close()
        return False

    def step(self, name: str):
        logger.info("%s: %s", self.label, name)
        if self.enabled:
            sys.stderr.write(f"{self.label}: {name}\n")

    def update(self, stage: str, it: int, total: int, losses: dict):
        if not self.enabled:
            return
        from tqdm import tqdm

        if stage != self.stage:
            if self.bar is not None:
                self.bar.close()
            self.bar = tqdm(total=total, desc=f"{self.label} {stage}", leave=False)
            self.stage = stage
        self.bar.n = min(it, total)
        if losses:
            self.bar.set_postfix({k: f"{v:.3g}" for k, v in list(losses.items())[:3]})
        self.bar.refresh()


def _say(args, msg: str, force: bool = False) -> None:
    if force or not getattr(args, "quiet", False):
        sys.stdout.write(msg + "\n")


def _err(msg: str) -> None:
    sys.stderr.write(msg + "\n")


def _set_torch_threads(args) -> None:
    """One torch thread unless EASYHOI_TORCH_THREADS says otherwise.

    easyhoi's tensors are small (a few thousand vertices, <= 256 px masks): on this workload extra
    intra-op threads cost more in synchronisation than they save, badly so on a loaded machine.
    Commands that never use torch in this process (``doctor``, a ``batch`` whose workers are
    other processes, which set their own threads) do not import it: importing torch costs a
    second, and a batch's worker processes import it anyway.
    """
    import os

    raw = os.environ.get("EASYHOI_TORCH_THREADS", "1")
    try:
        n = max(1, int(raw))
    except ValueError:
        raise InvalidInputError(f"EASYHOI_TORCH_THREADS must be an integer, got {raw!r}") from None
    uses = getattr(args, "uses_torch", True)
    if callable(uses):
        uses = uses(args)
    if uses:
        import torch

        torch.set_num_threads(n)


def build_parser() -> argparse.ArgumentParser:
    """The parser of :mod:`easyhoi.cli_parser` with each command's function attached."""
    return cli_parser.build_parser({
        "reconstruct": dict(func=cmd_reconstruct, check_early=_check_reconstruct_early),
        "batch": dict(func=cmd_batch, check_early=_batch_images, uses_torch=_batch_in_process),
        "example": dict(func=cmd_example),
        "bench": dict(func=cmd_bench),
        "demo-hand": dict(func=cmd_demo_hand),
        "demo": dict(func=cmd_demo),
        "eval": dict(func=cmd_eval),
        "doctor": dict(func=cmd_doctor, uses_torch=False),
    })  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return int(ExitCode.INVALID_INPUT)
    level = logging.DEBUG if args.verbose else (logging.ERROR if args.quiet else logging.WARNING)
    # --verbose opens easyhoi's own debug log only; other libraries (matplotlib, numba, ...)
    # stay at warnings
    logging.basicConfig(level=max(level, logging.WARNING) if args.verbose else level,
                        format="%(levelname)s %(name)s: %(message)s")  # fmt: skip
    logger.setLevel(level)
    try:
        if getattr(args, "check_early", None) is not None:
            args.check_early(args)  # bad input fails in a fraction of a second, before torch
        _set_torch_threads(args)
        return int(args.func(args) or 0)
    except EasyHOIError as exc:
        if args.verbose:
            logger.exception("failed")
        _err(f"error: {type(exc).__name__}: {exc}")
        return int(exc.exit_code)
    except KeyboardInterrupt:
        _err("interrupted")
        return int(ExitCode.INTERRUPTED)
    except Exception as exc:  # noqa: BLE001 - last line of defence: no traceback for users
        if (res := as_resource_error(exc)) is not None:  # disk full, out of memory
            _err(f"error: {type(res).__name__}: {res}")
            return int(res.exit_code)
        if args.verbose:
            logger.exception("internal error")
        _err(f"internal error: {type(exc).__name__}: {exc} (rerun with --verbose for details)")
        return int(ExitCode.INTERNAL)


def entry() -> None:
    """The ``easyhoi`` console command: :func:`main`, then :func:`fast_exit` with its code."""
    fast_exit(main())


def fast_exit(code: int) -> None:
    """End the process with ``code`` without Python's module teardown.

    Python's own shutdown of a process that imported torch and the perception libraries
    costs 0.5 to 1.3 s of CPU (clearing every module and freeing their objects) for nothing:
    the process ends anyway. The exit handlers still run (logging, temporary files, worker
    pools) and the output streams are flushed; only the teardown is skipped. When a
    non-daemon thread is still running, the ordinary exit (which waits for it) is used.
    """
    import threading

    others = [t for t in threading.enumerate()
              if t is not threading.main_thread() and not t.daemon and t.is_alive()]  # fmt: skip
    run_exit_handlers = getattr(__import__("atexit"), "_run_exitfuncs", None)
    if others or run_exit_handlers is None:
        sys.exit(code)
    import os

    try:
        run_exit_handlers()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # closed or broken pipe: nothing more to write
                pass
        os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
