"""The ``easyhoi`` command line's arguments: every command, its options and their help.

:func:`build_parser` lays the commands out; :mod:`easyhoi.cli` runs them. Nothing here imports
torch, mediapipe or gradio, so ``easyhoi --help`` and argument errors stay fast.
"""

from __future__ import annotations

import argparse

from easyhoi import __version__
from easyhoi.errors import EXIT_CODE_MEANINGS


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logs and tracebacks")


def _add_picture_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--full-size-pictures", action="store_true",
                   help="draw the result pictures at the photo's full size (slower; default: "
                   "at the size the report shows them)")  # fmt: skip


def _add_model_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hand-model", choices=("open", "mano"), default="open",
                   help="hand model: built-in open hand (default) or your MANO file")  # fmt: skip
    p.add_argument("--mano-dir", default=None,
                   help="folder or path of MANO_RIGHT.pkl (or set EASYHOI_MANO_DIR)")  # fmt: skip


def _add_device_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None, metavar="{auto,cpu,cuda,cuda:N}",
                   help="where the optimizer and large models run (default: config 'device'; "
                        "auto = large models on cuda when torch sees a GPU, the optimizer on "
                        "the CPU, where it is faster)")  # fmt: skip


def _add_object_shape_option(p) -> None:
    from easyhoi.shape_families import OBJECT_SHAPES

    p.add_argument("--object-shape", default=None, choices=("auto", *OBJECT_SHAPES),
                   help="the object's shape family when you know its kind (a cup: revolution, "
                   "a mug: handled, a phone: cuboid or slab, a pen: tube); default auto, the best "
                   "fit of all (perception.object_shape)")  # fmt: skip


_OUT_HELP = (
    "output folder: OUT/<photo stem>/; several photos run as a batch (one folder each, x.jpg "
    "and x.png as x_jpg and x_png, and a manifest)"
)
_SEED_HELP = (
    "random seed, an alias of --set optim.seed=N (default: the preset's, 0); giving both with "
    "different values is an error. With several photos each photo's seed is derived from it "
    "and the photo's name"
)


def exit_codes_help() -> str:
    """The exit-code table as ``easyhoi --help`` prints it."""
    rows = [f"  {int(code):3d}  {text}" for code, text in EXIT_CODE_MEANINGS.items()]
    return "exit codes:\n" + "\n".join(rows)


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """The options ``reconstruct`` and ``batch`` share: preset, seed, models and backends."""
    p.add_argument("--preset", default="fast", help="optimizer preset: fast (default) or paper")
    p.add_argument("--seed", type=int, default=None, help=_SEED_HELP)
    _add_model_options(p)
    _add_device_option(p)
    for flag, role in (("--hand-backend", "hand"), ("--segmenter", "segmenter"),
                       ("--inpainter", "inpainter"), ("--amodal", "amodal"),
                       ("--object-backend", "object")):  # fmt: skip
        p.add_argument(flag, default=None, help=f"{role} backend (see `easyhoi doctor`)")
    _add_object_shape_option(p)


def _add_run_tail(p: argparse.ArgumentParser) -> None:
    """The last options of ``reconstruct`` and ``batch``: overrides, pictures, verbosity."""
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="config override, e.g. optim.refine.max_iters=50 (repeatable)")  # fmt: skip
    _add_picture_options(p)
    _add_common(p)


def build_parser(handlers: dict[str, dict]) -> argparse.ArgumentParser:
    """The ``easyhoi`` parser; ``handlers`` maps each command's name to its ``set_defaults``
    keywords (``func``, and optionally ``check_early`` and ``uses_torch``)."""
    parser = argparse.ArgumentParser(
        prog="easyhoi",
        description="Reconstruct a 3D hand holding an object from one photo, on a CPU.",
        epilog=exit_codes_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"easyhoi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("reconstruct", help="photo(s) -> hand + object meshes, camera, report")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="photo file(s)")
    p.add_argument("--out", required=True, help=_OUT_HELP)
    _add_run_options(p)
    p.add_argument("--sam-dir", help="local SAM model folder (uses the 'sam' amodal backend)")
    p.add_argument("--depth-dir", help="local depth model folder (uses the 'depth' object backend)")
    p.add_argument("--shape-dir", help="local Shap-E image-to-3D pipeline folder (uses the "
                   "'shap-e' object backend)")  # fmt: skip
    p.add_argument("--diffusion-dir", help="local diffusers inpainting pipeline folder")
    p.add_argument("--detector-dir", help="local OWLv2 or Grounding DINO folder (uses the "
                   "'grounded-sam' segmenter with --sam-dir)")  # fmt: skip
    p.add_argument("--hand-mask", help="visible hand mask PNG (replaces segmentation)")
    p.add_argument("--object-mask", help="visible held-object mask PNG")
    p.add_argument("--amodal-mask", help="complete (amodal) object mask PNG")
    p.add_argument("--object-mesh", help="object mesh OBJ/GLB/PLY (e.g. InstantMesh output)")
    p.add_argument("--hand-params", help="HaMeR hand file (.npz/.json/.pkl)")
    p.add_argument("--object-point", action="append", metavar="X,Y",
                   help="a pixel inside the held object (x right, y down; repeatable)")  # fmt: skip
    p.add_argument("--object-box", metavar="X0,Y0,X1,Y1",
                   help="a box drawn close round the held object (top-left, bottom-right "
                   "corner)")  # fmt: skip
    p.add_argument("--hand-point", metavar="X,Y", help="a pixel on the hand holding the object")
    p.add_argument("--background-point", action="append", metavar="X,Y",
                   help="a pixel that is not the held object, where the mask takes in too much "
                   "(repeatable)")  # fmt: skip
    p.add_argument("--object-choice", type=int, metavar="K",
                   help="take object region K instead of the first (masks.png numbers them): "
                   "the automatic path's, or with --object-point the point's "
                   "outlines")  # fmt: skip
    p.add_argument("--strict", action="store_true",
                   help="exit 9, writing nothing, when a mask or the hand's keypoints have low "
                   "confidence")  # fmt: skip
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing result folder (default: refuse, exit 2)")  # fmt: skip
    _add_run_tail(p)
    p.set_defaults(**handlers["reconstruct"])

    p = sub.add_parser("batch", help="every photo of a folder -> one result folder each")
    p.add_argument("folder", metavar="DIR", help="folder of photos")
    p.add_argument("--out", required=True, help="output folder (one subfolder per photo)")
    p.add_argument("--workers", type=int, default=None,
                   help="parallel worker processes, one torch thread each (default: one per "
                   "CPU core)")  # fmt: skip
    p.add_argument("--engine", choices=("local", "ray", "inline"), default="local",
                   help="local process pool (default), ray, or inline (debugging)")  # fmt: skip
    p.add_argument("--ray-address", default=None,
                   help="existing Ray cluster (default: a local one on 127.0.0.1)")  # fmt: skip
    p.add_argument("--resume", action="store_true",
                   help="skip photos the manifest records as done (folder present)")  # fmt: skip
    p.add_argument("--recursive", action="store_true", help="include subfolders")
    p.add_argument("--prompts", metavar="FILE",
                   help="per-photo prompts: JSON {photo: {object_points, object_box, "
                   "hand_point, background_points, object_choice}} or CSV "
                   "photo,kind,x,y[,x1,y1]")  # fmt: skip
    p.add_argument("--strict", action="store_true",
                   help="a photo with a low-confidence mask fails (exit 9)")  # fmt: skip
    p.add_argument("--wait", action="store_true",
                   help="if another run uses --out, wait for it (default: exit 11)")  # fmt: skip
    _add_run_options(p)
    _add_run_tail(p)
    p.set_defaults(**handlers["batch"])

    p = sub.add_parser(
        "example",
        help="synthetic photo -> full reconstruction, compared with the photo's truth (make demo)",
    )
    p.add_argument("--out", default="outputs/demo", help="output folder")
    p.add_argument("--seed", type=int, default=None,
                   help="scene and run seed (alias of --set optim.seed; default 0)")  # fmt: skip
    p.add_argument("--size", type=int, default=384, help="photo size in pixels")
    p.add_argument("--preset", default="fast", help="optimizer preset: fast (default) or paper")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override")
    _add_model_options(p)
    _add_device_option(p)
    for flag in ("--hand-backend", "--segmenter", "--inpainter", "--amodal", "--object-backend"):
        p.add_argument(flag, default=None, help=argparse.SUPPRESS)
    _add_common(p)
    p.set_defaults(**handlers["example"])

    p = sub.add_parser("bench", help="synthetic benchmark with ground truth (paper's tables)")
    p.add_argument("--scenes", type=int, default=20, help="number of scenes (default 20)")
    p.add_argument("--quick", action="store_true",
                   help="3 scenes, paper preset on 1 scene capped at 100 iterations")  # fmt: skip
    p.add_argument("--out", default="benchmarks/results/synth", help="output folder")
    p.add_argument("--seed", type=int, default=0, help="scene seed offset (default 0)")
    p.add_argument("--paper-scenes", type=int, default=None,
                   help="paper preset on the first K scenes (default 3; quick 1)")  # fmt: skip
    p.add_argument("--paper-cap", type=int, default=None,
                   help="paper stage iteration cap (default 0 = none; quick 100)")  # fmt: skip
    p.add_argument("--perturbation", default="hamer", help="none, low, hamer (default), high")
    p.add_argument("--sd-steps", type=int, default=35, help="S.D. simulation steps (default 35)")
    p.add_argument("--light", action="store_true",
                   help="no loss ablation, no S.D. gravity cone (about 3x faster)")  # fmt: skip
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override of the fast preset, e.g. optim.refine.prior_weight=5 "
                        "(repeatable): a variant on the same scenes; compare two runs with "
                        "benchmarks/compare_synth.py")  # fmt: skip
    _add_common(p)
    p.set_defaults(**handlers["bench"])

    p = sub.add_parser("demo-hand", help="pose the built-in hand model; write meshes + pictures")
    p.add_argument("--out", default="outputs/demo-hand", help="output folder")
    _add_model_options(p)
    _add_common(p)
    p.set_defaults(**handlers["demo-hand"])

    p = sub.add_parser("demo", help="web demo in the browser (pip install 'easyhoi[demo]')")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default 127.0.0.1: this machine only)")  # fmt: skip
    p.add_argument("--port", type=int, default=7860, help="port (default 7860)")
    p.add_argument("--preset", default="fast", help="preset selected at start (default fast)")
    p.add_argument("--max-upload-mb", type=float, default=20.0,
                   help="largest accepted photo in MB (default 20)")  # fmt: skip
    _add_common(p)
    p.set_defaults(**handlers["demo"])

    p = sub.add_parser("eval", help="metrics of result folders (plausibility, vs ground truth)")
    p.add_argument("results", nargs="+", metavar="RESULT_DIR", help="folders from reconstruct")
    p.add_argument("--gt-object", help="ground-truth object mesh (metres; aligned before C.D.)")
    p.add_argument("--gt-hand", help="ground-truth hand mesh, same hand model (for MPVPE)")
    p.add_argument("--align", default="translation_scale",
                   choices=("translation_scale", "rigid", "none"),
                   help="object alignment before C.D./F-score (default: MOHO/EasyHOI)")  # fmt: skip
    p.add_argument("--no-sim", action="store_true", help="skip the simulation displacement")
    p.add_argument("--sim-steps", type=int, default=35, help="simulation steps (paper text: 1000)")
    p.add_argument("--json", help="also write the metrics to this JSON file")
    _add_common(p)
    p.set_defaults(**handlers["eval"])

    p = sub.add_parser("doctor", help="versions, backends and what is missing")
    _add_common(p)
    p.set_defaults(**handlers["doctor"])
    return parser
