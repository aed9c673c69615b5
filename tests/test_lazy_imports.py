"""The command line starts without the heavy libraries: each check runs a fresh interpreter."""

import json
import os
import subprocess
import sys
import time

import pytest

HEAVY = ("torch", "mediapipe", "gradio", "transformers", "diffusers", "matplotlib", "cv2")

_PROBE = """
import json, sys
from easyhoi import cli
try:
    code = cli.main({argv!r})
except SystemExit as exc:
    code = exc.code
print(json.dumps({{"code": code, "heavy": sorted(m for m in {heavy!r} if m in sys.modules)}}))
"""


def _run(argv: list[str]) -> tuple[dict, float, str]:
    """Run ``easyhoi ARGV`` in a fresh interpreter; (probe result, wall seconds, stderr)."""
    env = dict(os.environ, EASYHOI_TORCH_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _PROBE.format(argv=argv, heavy=HEAVY)],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    seconds = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), seconds, proc.stderr


def test_help_imports_no_heavy_library():
    res, _, _ = _run(["--help"])
    assert res == {"code": 0, "heavy": []}


def test_doctor_imports_no_heavy_library():
    res, _, _ = _run(["doctor", "-q"])
    assert res == {"code": 0, "heavy": []}


@pytest.mark.parametrize(
    "argv",
    [
        ["reconstruct"],  # --out and the photo missing: argparse
        ["reconstruct", "photo.jpg", "--out", "o", "--preset"],  # option without its value
        ["batch", "folder", "--out", "o", "--workers", "two"],  # not an integer
    ],
)
def test_argument_errors_exit_2_without_torch(argv):
    res, _, err = _run(argv)
    assert res == {"code": 2, "heavy": []}
    assert "usage:" in err and "Traceback" not in err


def test_missing_photo_fails_fast_without_torch(tmp_path):
    res, seconds, err = _run(["reconstruct", str(tmp_path / "nope.jpg"), "--out", str(tmp_path)])
    assert res == {"code": 2, "heavy": []}
    assert "image file not found" in err
    # a fresh interpreter plus easyhoi's light modules; torch alone takes a second or more
    assert seconds < 5.0


def test_not_an_image_fails_without_torch(tmp_path):
    bad = tmp_path / "notes.jpg"
    bad.write_text("not a photo")
    res, _, err = _run(["reconstruct", str(bad), "--out", str(tmp_path / "o")])
    assert res == {"code": 2, "heavy": []}
    assert "not an image" in err
    assert not (tmp_path / "o").exists()


def test_import_easyhoi_does_not_import_torch():
    code = "import sys, easyhoi; print('torch' in sys.modules, easyhoi.__version__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[0] == "False"


def test_lazy_public_names_are_the_real_objects():
    import easyhoi
    from easyhoi.structures import Camera, HandParams

    assert easyhoi.Camera is Camera and easyhoi.HandParams is HandParams
    assert {"Camera", "HandOutput", "HandParams", "optimize"} <= set(dir(easyhoi))


def test_doctor_backends_match_the_registry():
    from easyhoi.doctor import registered_backends
    from easyhoi.perception.base import ROLES, available

    assert registered_backends() == {role: available(role) for role in ROLES}


def test_doctor_versions_match_the_imported_modules():
    import numpy
    import torch

    from easyhoi.doctor import library_version

    assert library_version("numpy") == numpy.__version__
    assert library_version("torch") == torch.__version__
    assert library_version("surely_not_a_module_here") is None


_ENTRY = """
import atexit, sys
from pathlib import Path
marker = Path(sys.argv[1])
atexit.register(lambda: marker.write_text("exit handlers ran"))
sys.argv = ["easyhoi", *sys.argv[2:]]
from easyhoi.cli import entry
entry()
print("not reached")
"""


@pytest.mark.parametrize("ok", [True, False])
def test_entry_exits_with_mains_code_after_the_exit_handlers(tmp_path, ok):
    marker = tmp_path / "marker.txt"
    out = tmp_path / "out"
    argv = ["demo-hand", "--out", str(out)] if ok else ["eval", str(tmp_path / "missing")]
    proc = subprocess.run([sys.executable, "-c", _ENTRY, str(marker), *argv],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert marker.read_text() == "exit handlers ran"
    assert "not reached" not in proc.stdout
    if ok:
        assert proc.returncode == 0, proc.stderr
        assert "wrote" in proc.stdout  # buffered output was flushed before the fast exit
        assert (out / "hand_grasp.ply").stat().st_size > 10_000
    else:
        assert proc.returncode == 2 and "error:" in proc.stderr


def test_malformed_prompt_fails_without_torch(tmp_path):
    argv = ["reconstruct", str(tmp_path / "any.png"), "--out", str(tmp_path), "--object-box", "1,2"]
    res, _, err = _run(argv)
    assert res == {"code": 2, "heavy": []}
    assert "--object-box expects" in err


def test_batch_of_an_empty_or_missing_folder_fails_without_torch(tmp_path):
    res, _, err = _run(["batch", str(tmp_path), "--out", str(tmp_path / "o")])
    assert res == {"code": 2, "heavy": []}
    assert "no photos found" in err
    res, _, err = _run(["batch", str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    assert res == {"code": 2, "heavy": []}
