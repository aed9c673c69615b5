"""Web demo: upload a photo, get the hand + object overlay, a 3D view, metrics and downloads.

:func:`build_app` wraps the request logic of :mod:`easyhoi.app_request` (plain Python, no
gradio) in a gradio page and :func:`launch` serves that page on this machine only
(``127.0.0.1``) unless told otherwise.

Click-to-prompt (:mod:`easyhoi.app_prompts`): a click on the shown photo adds a point on the held
object (or, in the "hand point" mode, marks the holding hand, and in the "background point" mode
a point that is not the object); the points are drawn on the photo,
"Show mask" segments the photo with them and shows the masks, and Run uses them.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from easyhoi.app_request import (
    KEEP_RUNS,
    MAX_SEED,
    MAX_UPLOAD_MB,
    DemoResult,
    check_upload,
    handle_request,
    metrics_markdown,
    synthetic_examples,
)
from easyhoi.errors import InvalidInputError

__all__ = [
    "DemoResult",
    "build_app",
    "check_upload",
    "handle_request",
    "launch",
    "metrics_markdown",
    "synthetic_examples",
]


# ----------------------------------------------------------------------------------------------
# gradio page
# ----------------------------------------------------------------------------------------------

_INTRO = """\
# EasyHOI: hand + held object from one photo
Upload a photo of a hand holding an object and press **Run**. If the wrong object is found,
click on the held object in the photo (add more clicks for more of it; *background point*
marks what the mask takes in that is not the object; *hand point* marks the holding hand;
*object box corner* takes two clicks at opposite corners of a box drawn close round the
object), or pick another *object region* (numbered in `masks.png` and in the mask preview:
the automatic path's or, after a click, the other outlines around the clicked point), check it
with **Show mask**, and run again. The reconstruction runs on this
machine's CPU: about half a minute with the *fast* preset on 2 cores, several minutes with
*paper*. Same photo, points, preset and seed give the same result.
"""

_CSS = """
#error, #error * { color: #b3261e !important; }
"""


def _require_gradio():
    os.environ["GRADIO_ANALYTICS_ENABLED"] = "False"
    os.environ.setdefault("HF_HUB_DISABLE_TELEMETRY", "1")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from easyhoi.errors import require

    return require("gradio", "demo", "the web demo")


def build_app(
    reconstruct_fn: Callable | None = None,
    preset: str = "fast",
    max_upload_mb: float = MAX_UPLOAD_MB,
    *,
    work_dir: str | Path | None = None,
    examples: Sequence[str | Path] | None = None,
    keep_runs: int = KEEP_RUNS,
    segment_fn: Callable | None = None,
):
    """The demo page as a ``gradio.Blocks`` (not started; see :func:`launch`).

    Args:
        reconstruct_fn (callable, optional): The reconstruction (default
            :func:`easyhoi.pipeline.reconstruct_photo`); see the module docstring for the contract.
        preset (str): Preset selected when the page opens.
        max_upload_mb (float): Upload size limit (checked again by :func:`handle_request`).
        work_dir (path, optional): Folder for the request folders (default: a new temporary folder).
            Stored as ``app.easyhoi_work_dir``.
        examples (list of paths, optional): Example photos offered under the upload (default:
            :func:`synthetic_examples`).
        keep_runs (int): Request folders kept on disk.
        segment_fn (callable, optional): The segmentation behind "Show mask" (default:
            :func:`easyhoi.app_prompts.segment_for_preview`; see
            :func:`~easyhoi.app_prompts.mask_preview`).

    Raises:
        MissingDependencyError: gradio is not installed (``pip install 'easyhoi[demo]'``).

    Note:
        Sets ``GRADIO_ANALYTICS_ENABLED=False`` and (unless set) ``HF_HUB_OFFLINE=1`` and
        ``HF_HUB_DISABLE_TELEMETRY=1`` in this process: the demo contacts no other machine.
    """
    gr = _require_gradio()
    from easyhoi.config import PRESETS
    from easyhoi.shape_families import OBJECT_SHAPES

    if preset not in PRESETS:
        raise InvalidInputError(f"unknown preset {preset!r}; available: {', '.join(PRESETS)}")
    work = (
        Path(work_dir) if work_dir is not None else Path(tempfile.mkdtemp(prefix="easyhoi-demo-"))
    )
    work.mkdir(parents=True, exist_ok=True)
    if examples is None:
        examples = synthetic_examples(work / "examples")
    examples = [str(p) for p in examples]

    from easyhoi import app_prompts as ap

    def on_upload(path):
        rgb, err, state = ap.load_preview(path, max_upload_mb)
        return (
            rgb, gr.update(value=f"**{err}**" if err else "", visible=bool(err)), state,
            ap.prompt_text(state), None, "", ap.choice_labels()[0],
        )  # fmt: skip

    def on_click(path, state, mode, evt: gr.SelectData):
        rgb, err, _ = ap.load_preview(path, max_upload_mb)
        if rgb is None:
            return gr.update(), state, ap.prompt_text(state), gr.update()
        state = ap.add_click(state, mode, evt.index, (rgb.shape[1], rgb.shape[0]))
        # the first object point replaces the automatic path's regions by its own: back to 1
        return ap.draw_prompts(rgb, state), state, ap.prompt_text(state), ap.choice_label(state)

    # gradio passes the click by the parameter's type, which it reads as an object: this
    # module's annotations are strings (``from __future__ import annotations``)
    on_click.__annotations__["evt"] = gr.SelectData

    def on_clear(path, state):
        rgb, _, fresh = ap.load_preview(path, max_upload_mb)
        return rgb, fresh, ap.prompt_text(fresh), None, "", ap.choice_labels()[0]

    def on_choice(state, label):
        state = ap.set_choice(state, label)
        return state, ap.prompt_text(state)

    def on_mask(path, state, preset_name):
        from easyhoi.config import get_preset

        rgb, text = ap.mask_preview(path, state, get_preset(preset_name), segment_fn)
        return rgb, text

    def on_run(path, preset_name, seed, state, shape, progress=gr.Progress()):  # noqa: B008
        def report(desc, frac):
            progress(frac, desc=desc)

        try:
            prompts = ap.state_prompts(state)
        except InvalidInputError:
            prompts = None
        res = handle_request(
            path, preset_name, seed, work_root=work, reconstruct_fn=reconstruct_fn,
            max_upload_mb=max_upload_mb, keep_runs=keep_runs, progress=report, prompts=prompts,
            object_shape=shape,
        )  # fmt: skip
        if not res.ok:
            return (
                None, None, "", None,
                gr.update(value=f"**{res.error}**", visible=True), gr.update(visible=False),
            )  # fmt: skip
        if res.view_glb is not None:  # first view = the photo's viewpoint
            view = gr.update(value=str(res.view_glb), camera_position=res.camera_position)
        else:
            view = str(res.glb)
        notes = "\n".join(f"* {w}" for w in res.warnings)
        return (
            str(res.overlay), view, res.metrics_text, [str(p) for p in res.downloads],
            gr.update(value="", visible=False), gr.update(value=notes, visible=bool(notes)),
        )  # fmt: skip

    with gr.Blocks(title="EasyHOI demo", analytics_enabled=False, delete_cache=(1800, 3600)) as app:
        gr.Markdown(_INTRO)
        with gr.Row():
            with gr.Column(scale=1):
                photo = gr.File(
                    label=f"Photo (JPEG, PNG, WebP...; up to {max_upload_mb:g} MB)",
                    file_types=["image"], type="filepath", elem_id="photo",
                )  # fmt: skip
                preview = gr.Image(label="Photo (click on the held object)", interactive=False,
                                   height=320, elem_id="preview", buttons=[])  # fmt: skip
                prompt_state = gr.State(ap.new_state())
                with gr.Row():
                    mode = gr.Radio(list(ap.MODES), value=ap.MODES[0], label="A click adds",
                                    elem_id="click_mode")  # fmt: skip
                    with gr.Column():
                        show_mask = gr.Button("Show mask", elem_id="show_mask")
                        clear = gr.Button("Clear points", elem_id="clear_points")
                region = gr.Dropdown(
                    choices=ap.choice_labels(), value=ap.choice_labels()[0],
                    label="Object region (automatic, or the first click's; 'Show mask' shows it)",
                    elem_id="object_region",
                )  # fmt: skip
                prompt_line = gr.Markdown(ap.prompt_text(None), elem_id="prompt_text")
                mask_view = gr.Image(label="Mask preview (object green, hand orange)",
                                     interactive=False, height=240, elem_id="mask_preview",
                                     buttons=[])  # fmt: skip
                mask_line = gr.Markdown("", elem_id="mask_text")
                with gr.Row():
                    preset_box = gr.Dropdown(
                        choices=sorted(PRESETS), value=preset, label="Preset", elem_id="preset"
                    )
                    seed_box = gr.Number(
                        value=0, precision=0, minimum=0, maximum=MAX_SEED, label="Seed",
                        elem_id="seed",
                    )  # fmt: skip
                shape_box = gr.Dropdown(
                    choices=["auto", *OBJECT_SHAPES], value="auto", elem_id="object_shape",
                    label="Object shape (auto: the best fit; or the family you know: a cup is a "
                    "revolution, a phone a cuboid or a slab, a pen a tube)",
                )  # fmt: skip
                run = gr.Button("Run", variant="primary", elem_id="run")
                error = gr.Markdown("", visible=False, elem_id="error")
                warnings = gr.Markdown("", visible=False, elem_id="warnings")
                if examples:
                    gr.Examples(examples, inputs=[photo], label="Example photos")
            with gr.Column(scale=2):
                overlay = gr.Image(
                    label="Overlay (reconstruction over the photo)", type="filepath",
                    interactive=False, elem_id="overlay", buttons=["download", "fullscreen"],
                )  # fmt: skip
                with gr.Row():
                    model3d = gr.Model3D(
                        label="3D: hand + object, seen from the photo (drag to turn)",
                        height=360, elem_id="model3d",
                    )  # fmt: skip
                    with gr.Column():
                        metrics = gr.Markdown("", elem_id="metrics")
                        downloads = gr.File(label="Downloads", file_count="multiple",
                                            interactive=False, elem_id="downloads")  # fmt: skip
        # change, not upload: an example photo fills the file box without an upload
        photo.change(on_upload, photo,
                     [preview, error, prompt_state, prompt_line, mask_view, mask_line, region],
                     queue=False)  # fmt: skip
        region.input(on_choice, [prompt_state, region], [prompt_state, prompt_line],
                     queue=False)  # fmt: skip
        preview.select(on_click, [photo, prompt_state, mode],
                       [preview, prompt_state, prompt_line, region], queue=False)  # fmt: skip
        clear.click(on_clear, [photo, prompt_state],
                    [preview, prompt_state, prompt_line, mask_view, mask_line, region],
                    queue=False)  # fmt: skip
        show_mask.click(on_mask, [photo, prompt_state, preset_box], [mask_view, mask_line],
                        concurrency_limit=1, api_name="mask_preview")  # fmt: skip
        run.click(
            on_run, [photo, preset_box, seed_box, prompt_state, shape_box],
            [overlay, model3d, metrics, downloads, error, warnings],
            concurrency_limit=1, api_name="reconstruct",
        )  # fmt: skip
    app.easyhoi_work_dir = work
    if work_dir is None:  # a folder of our own: removed with the app
        from easyhoi.app_cleanup import remove_on_exit

        remove_on_exit(app, work)
    return app


def launch(
    host: str = "127.0.0.1",
    port: int = 7860,
    *,
    preset: str = "fast",
    reconstruct_fn: Callable | None = None,
    max_upload_mb: float = MAX_UPLOAD_MB,
    block: bool = True,
    quiet: bool = False,
    examples: Sequence[str | Path] | None = None,
    segment_fn: Callable | None = None,
):
    """Build and serve the demo on ``http://host:port`` (no share link, no analytics).

    ``block=False`` returns at once with the server running in a background thread; stop it
    with ``app.close()``. Returns the ``gradio.Blocks`` app.
    """
    app = build_app(reconstruct_fn, preset, max_upload_mb, examples=examples,
                    segment_fn=segment_fn)  # fmt: skip
    app.queue(max_size=16, default_concurrency_limit=1)
    try:
        app.launch(
            server_name=host, server_port=int(port), share=False, inbrowser=False,
            prevent_thread_lock=not block, quiet=quiet, show_error=False,
            max_file_size=int(float(max_upload_mb) * 2**20),
            allowed_paths=[str(app.easyhoi_work_dir)], ssr_mode=False, mcp_server=False,
            enable_monitoring=False, pwa=False, css=_CSS,
        )  # fmt: skip
    except OSError as exc:
        raise InvalidInputError(f"cannot serve on {host}:{port}: {exc}") from exc
    return app
