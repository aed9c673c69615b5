"""The web demo's request handler (no browser): outputs, bad uploads, errors, CLI wiring.

The reconstruction is the stand-in of ``scripts/app_screenshot.py`` (a real overlay PNG and GLB
of the built-in hand); one slow test runs the real pipeline with a shortened schedule.
"""

from __future__ import annotations

import importlib.util
import io
import json
import sys
import urllib.request
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from easyhoi.app import handle_request, metrics_markdown
from easyhoi.errors import NoHandError

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "app_screenshot.py"


def load_screenshot_script():
    """``scripts/app_screenshot.py`` as a module (stand-in reconstruction, browser driver)."""
    spec = importlib.util.spec_from_file_location("easyhoi_app_screenshot", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


standin = load_screenshot_script()


def photo(path: Path, size=(160, 120), fmt: str | None = None) -> Path:
    """A small gradient photo with a skin-coloured blob."""
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.stack([40 + 150 * xx / w, 60 + 100 * yy / h, 90 + 0 * xx], -1)
    rgb[(xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (h / 4) ** 2] = (205, 150, 120)
    Image.fromarray(rgb.astype(np.uint8)).save(path, format=fmt)
    return path


class Recorder:
    """The stand-in reconstruction, recording its calls."""

    def __init__(self, fn=standin.standin_reconstruct):
        self.calls = []
        self.fn = fn

    def __call__(self, image_path, out_dir, config, **kw):
        self.calls.append({"image": Path(image_path), "out_dir": Path(out_dir), "config": config,
                           **kw})  # fmt: skip
        return self.fn(image_path, out_dir, config, **kw)


def test_good_photo_gives_overlay_glb_metrics_and_zip(tmp_path):
    src = photo(tmp_path / "my photo (1).png")
    fn = Recorder()
    progress = []
    res = handle_request(src, "fast", 3, work_root=tmp_path / "work", reconstruct_fn=fn,
                         progress=lambda desc, frac: progress.append((desc, frac)))  # fmt: skip
    assert res.ok and res.error == ""
    # the reconstruction got a copy of the upload inside this request's folder, the seed, preset
    (call,) = fn.calls
    assert call["seed"] == 3 and call["config"].name == "fast"
    assert call["image"].read_bytes() == src.read_bytes()
    assert (tmp_path / "work") in call["image"].parents and call["image"].name == "my_photo_1.png"
    # overlay: a PNG of the photo's size that differs from the photo where the hand is drawn
    with Image.open(res.overlay) as im:
        assert im.format == "PNG" and im.size == (160, 120)
        over = np.asarray(im.convert("RGB")).astype(int)
    orig = np.asarray(Image.open(src).convert("RGB")).astype(int)
    changed = np.abs(over - orig).sum(-1) > 30
    assert 0.02 < changed.mean() < 0.9
    # GLB: binary glTF with two meshes
    data = res.glb.read_bytes()
    assert data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") == len(data)
    gltf = json.loads(data[20 : 20 + int.from_bytes(data[12:16], "little")])
    assert len(gltf["meshes"]) == 2
    # the viewer's copy: same meshes seen from the photo camera (whose centre is the origin)
    from easyhoi.viz.viewer import orbit_position

    assert res.view_glb is not None and res.view_glb.parent == res.folder.parents[1]
    view = trimesh.load(res.view_glb, file_type="glb", force="scene")
    assert len(view.geometry) == 2
    lo, hi = view.bounds
    centre = (lo + hi) / 2  # the first view looks from the camera centre's direction
    alpha, beta, _ = res.camera_position
    np.testing.assert_allclose(orbit_position(centre, alpha, beta, np.linalg.norm(centre)), 0,
                               atol=1e-5)  # fmt: skip
    # metrics from result.json plus the run facts, and their table
    plaus = res.metrics["plausibility"]
    assert plaus["penetration_depth_cm"] == 0.21 and plaus["in_contact"] is True
    assert plaus["hand_mask_iou"] == pytest.approx(changed.mean(), abs=0.02)
    assert res.metrics["seed"] == 3 and res.metrics["preset"] == "fast"
    assert "| penetration depth | 0.21 cm |" in res.metrics_text
    assert "| intersection volume | 0.75 cm³ |" in res.metrics_text
    assert "| in contact | yes |" in res.metrics_text
    assert "| seed | 3 |" in res.metrics_text
    # downloads: the zip holds the whole result folder, then the GLB and the report
    assert [p.name for p in res.downloads] == ["my_photo_1-easyhoi.zip", "scene.glb",
                                                "report.html"]  # fmt: skip
    with zipfile.ZipFile(res.downloads[0]) as zf:
        names = set(zf.namelist())
        assert zf.read("my_photo_1/scene.glb") == data
    assert names == {f"my_photo_1/{n}" for n in ("overlay.png", "scene.glb", "result.json",
                                                 "report.html")}  # fmt: skip
    # progress: perception step names, then stage fractions up to 1, then packing
    assert progress[0] == ("stand-in: posing the built-in hand", None)
    stages = [d for d, f in progress if f is not None]
    assert stages[0] == "optimizing: camera" and stages[-1] == "optimizing: refine"
    assert ("optimizing: refine", 1.0) in progress and progress[-1][0] == "packing the results"


def test_requests_get_their_own_folders_and_old_ones_are_pruned(tmp_path):
    src = photo(tmp_path / "a.png")
    fn = Recorder()
    results = [handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn,
                              keep_runs=2) for _ in range(3)]  # fmt: skip
    assert all(r.ok for r in results)
    folders = [r.folder for r in results]
    assert len(set(folders)) == 3
    runs = sorted(p.name for p in (tmp_path / "w").iterdir())
    assert len(runs) == 2 and not folders[0].exists() and folders[2].exists()


def test_webp_named_jpg_is_accepted_by_content(tmp_path):
    src = photo(tmp_path / "holiday.jpg", fmt="WEBP")
    fn = Recorder()
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn)
    assert res.ok, res.error
    assert fn.calls[0]["image"].name == "holiday.webp"


@pytest.mark.parametrize(
    "content, expected",
    [
        ("truncated", "corrupt or truncated"),
        (b"name,value\nhand,1\n" * 10, "not an image"),
        (b"", "empty"),
    ],
    ids=["truncated-png", "text", "empty"],
)
def test_bad_upload_is_a_readable_error(tmp_path, content, expected):
    src = tmp_path / "upload.png"
    if content == "truncated":  # a real PNG cut in the middle of its pixel data
        full = photo(tmp_path / "full.png", size=(400, 300)).read_bytes()
        content = full[: len(full) // 2]
    src.write_bytes(content)
    fn = Recorder()
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn)
    assert not res.ok and fn.calls == []
    assert res.error.startswith("The photo cannot be used:") and expected in res.error
    assert "'upload.png'" in res.error
    assert "Traceback" not in res.error and str(tmp_path) not in res.error
    assert "\n" not in res.error
    assert res.overlay is None and res.downloads == ()


def test_oversize_upload_is_refused_before_decoding(tmp_path):
    src = tmp_path / "big.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (200, 200, 3), np.uint8)).save(src)
    fn = Recorder()
    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn,
                         max_upload_mb=0.05)  # fmt: skip
    assert src.stat().st_size > 0.05 * 2**20
    assert not res.ok and fn.calls == [] and not (tmp_path / "w").exists()
    assert "the limit is 0.05 MB" in res.error and "'big.png'" in res.error
    ok = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=fn)
    assert ok.ok


def test_missing_upload_bad_seed_and_bad_preset(tmp_path):
    src = photo(tmp_path / "a.png")
    fn = Recorder()
    kw = {"work_root": tmp_path / "w", "reconstruct_fn": fn}
    assert "Please upload a photo" in handle_request(None, "fast", 0, **kw).error
    for seed in (-1, 1.5, "abc", 2**32):
        res = handle_request(src, "fast", seed, **kw)
        assert not res.ok and "seed must be a whole number" in res.error
    res = handle_request(src, "slowest", 0, **kw)
    assert not res.ok and "Unknown preset 'slowest'" in res.error and "fast" in res.error
    assert fn.calls == []
    assert handle_request(src, "paper", "7", **kw).ok
    assert fn.calls[0]["seed"] == 7 and fn.calls[0]["config"].name == "paper"
    assert fn.calls[0]["config"].perception.object_shape == "auto"
    res = handle_request(src, "fast", 0, object_shape="cup", **kw)
    assert not res.ok and "Unknown object shape 'cup'" in res.error and "revolution" in res.error
    assert len(fn.calls) == 1
    assert handle_request(src, "fast", 0, object_shape="revolution", **kw).ok
    assert fn.calls[1]["config"].perception.object_shape == "revolution"


def test_reconstruction_errors_become_messages(tmp_path):
    src = photo(tmp_path / "a.png")

    def no_hand(image_path, out_dir, config, **kw):
        raise NoHandError(f"no hand landmarks in {image_path}")

    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=no_hand)
    assert res.error == "No hand was found in the photo: no hand landmarks in 'a.png'"

    def bug(image_path, out_dir, config, **kw):
        raise ZeroDivisionError(f"division by zero in {out_dir}\nmore lines")

    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=bug)
    assert not res.ok and res.error.startswith("Internal error (ZeroDivisionError: division")
    assert str(tmp_path) not in res.error and "more lines" not in res.error
    assert "Traceback" not in res.error

    def no_files(image_path, out_dir, config, **kw):
        rec = standin.standin_reconstruct(image_path, out_dir, config, **kw)
        rec.files = [f for f in rec.files if f.name != "scene.glb"]
        return rec

    res = handle_request(src, "fast", 0, work_root=tmp_path / "w", reconstruct_fn=no_files)
    assert not res.ok and "wrote no scene.glb" in res.error


def test_metrics_table_formats_units_and_missing_values():
    text = metrics_markdown({"plausibility": {"object_mask_iou": 0.83333, "penetration_depth_cm":
                                              None, "contact_distance_cm": float("nan")},
                             "seconds": 61.25})  # fmt: skip
    assert text.splitlines() == [
        "| metric | value |", "|---|---|",
        "| object mask IoU (fit to its own mask, not accuracy) | 0.833 |",
        "| penetration depth | n/a |", "| contact distance | n/a |", "| run time | 61.2 s |",
    ]  # fmt: skip
    shape = {"shape": "slab", "depth_cue_from": "pinch"}
    text = metrics_markdown({"plausibility": {}, "object_shape": shape, "seconds": 2.0})
    assert text.splitlines()[2:] == [
        "| object shape | slab; thickness along the view from a pinch |", "| run time | 2.0 s |",
    ]  # fmt: skip
    shape = {"shape": "inflation", "depth_cue_from": None}
    assert "| object shape | inflation; thickness along the view not measured" in metrics_markdown(
        {"plausibility": {}, "object_shape": shape}
    )


# ----------------------------------------------------------------------------------------------
# gradio page and CLI (no browser)
# ----------------------------------------------------------------------------------------------


def test_page_serves_on_localhost_and_runs_through_the_api(tmp_path):
    pytest.importorskip("gradio", reason="gradio not installed (pip install 'easyhoi[demo]')")
    from gradio_client import Client, handle_file

    from easyhoi.app import launch

    port = standin.free_port()
    example = photo(tmp_path / "example-photo.png")
    app = launch("127.0.0.1", port, reconstruct_fn=standin.standin_reconstruct, block=False,
                 quiet=True, examples=[example])  # fmt: skip
    try:
        assert app.server_name == "127.0.0.1" and app.share is False
        html = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30).read().decode()
        assert "EasyHOI demo" in html
        config = urllib.request.urlopen(f"http://127.0.0.1:{port}/config", timeout=30).read()
        assert b"Example photos" in config and b"example-photo.png" in config
        client = Client(f"http://127.0.0.1:{port}/", verbose=False, download_files=str(tmp_path))
        src = photo(tmp_path / "api.png")
        overlay, glb, metrics, downloads, error, warnings = client.predict(
            handle_file(str(src)), "fast", 2, api_name="/reconstruct"
        )
        # nobody clicked: the stand-in's object mask has low confidence, and the page says so
        assert "Low confidence in the object mask (score 0.30" in str(warnings)
        assert "click on the held object in the photo and run again" in str(warnings)
        assert Image.open(overlay).size == (160, 120)
        assert Path(glb["value"] if isinstance(glb, dict) else glb).read_bytes()[:4] == b"glTF"
        assert "| seed | 2 |" in metrics
        assert sorted(Path(d).name for d in downloads)[0] == "api-easyhoi.zip"
        bad = tmp_path / "bad.png"
        bad.write_bytes(b"not a png at all" * 10)
        out = client.predict(handle_file(str(bad)), "fast", 0, api_name="/reconstruct")
        assert out[0] is None and "The photo cannot be used" in str(out[4])
    finally:
        app.close()


def test_cli_demo_without_gradio_names_the_extra(monkeypatch, capsys):
    from easyhoi.cli import main

    monkeypatch.setitem(sys.modules, "gradio", None)  # import gradio -> ImportError
    rc = main(["demo", "--port", "7999"])
    err = capsys.readouterr().err
    assert rc == 3
    assert "MissingDependencyError" in err and "pip install 'easyhoi[demo]'" in err


def test_cli_demo_defaults_to_localhost():
    from easyhoi.cli import build_parser

    args = build_parser().parse_args(["demo"])
    assert (args.host, args.port, args.preset, args.max_upload_mb) == ("127.0.0.1", 7860,
                                                                       "fast", 20.0)  # fmt: skip
    assert args.func.__name__ == "cmd_demo"


# ----------------------------------------------------------------------------------------------
# the real pipeline
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_real_pipeline_through_the_handler(tmp_path, shared_data):
    if importlib.util.find_spec("easyhoi.optim.run") is None:
        pytest.skip("easyhoi.optim.run (the optimizer) is not available yet")
    from easyhoi.config import with_overrides
    from easyhoi.pipeline import reconstruct_photo

    def short(image_path, out_dir, config, **kw):
        cfg = with_overrides(
            config,
            {
                "optim.camera.max_iters": 6,
                "optim.contact.max_iters": 6,
                "optim.refine.max_iters": 6,
                "optim.render_size": 96,
            },
        )
        return reconstruct_photo(image_path, out_dir, cfg, **kw)  # fmt: skip

    seen = []
    res = handle_request(shared_data / "images" / "hort-can.png", "fast", 0,
                         work_root=tmp_path, reconstruct_fn=short,
                         progress=lambda d, f: seen.append(d))  # fmt: skip
    assert res.ok, res.error
    with Image.open(res.overlay) as im:
        assert im.format == "PNG" and min(im.size) > 100
    assert res.glb.read_bytes()[:4] == b"glTF"
    assert {"penetration_depth_cm", "hand_mask_iou"} <= set(res.metrics["plausibility"])
    assert "| hand mask IoU (fit to its own mask, not accuracy) |" in res.metrics_text
    assert any(d.startswith("optimizing: refine") for d in seen)
    with zipfile.ZipFile(io.BytesIO(res.downloads[0].read_bytes())) as zf:
        assert "hort-can/report.html" in zf.namelist()


def test_no_object_error_says_what_to_do_on_the_page_and_on_the_command_line():
    """The automatic path's NoObjectError names the command line's prompts; the page replaces
    that hint with its own gesture (a click on the object), and keeps other messages whole."""
    from easyhoi.app_request import _readable
    from easyhoi.errors import NO_OBJECT_HINT, NoObjectError

    exc = NoObjectError(f"found 1 hand(s) but no held object{NO_OBJECT_HINT}")
    assert "--object-point X,Y" in str(exc) and "object_point" in str(exc)
    page = _readable(exc, {})
    assert page == (
        "No held object was found in the photo: found 1 hand(s) but no held object: click "
        "inside the object in the photo and run again"
    )
    other = NoObjectError("the hand nearest the hand point (hand 0, right) holds no object")
    assert _readable(other, {}).endswith("holds no object")
