"""The web demo with hostile uploads and at shutdown: a readable message for a photo over the
pixel limit (never a bare "Error"), and its temporary work folder removed on close and exit."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from easyhoi.app import check_upload, handle_request

ROOT = Path(__file__).resolve().parents[1]


def _png_claiming(path: Path, width: int, height: int) -> Path:
    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 1024)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)
    return path


def test_huge_photo_is_a_readable_message(tmp_path):
    bomb = _png_claiming(tmp_path / "huge.png", 20000, 20000)

    def never(*a, **k):
        raise AssertionError("reconstruction reached")

    res = handle_request(bomb, work_root=tmp_path / "work", reconstruct_fn=never)
    assert not res.ok
    assert res.error == (
        "The photo cannot be used: image 'huge.png' is too large: 400 MP; at most 120 MP are "
        "accepted (downscale the photo first)"
    )
    rgb, err = check_upload(bomb)
    assert rgb is None and "is too large: 400 MP" in err and str(tmp_path) not in err
    assert not (tmp_path / "work").exists() or list((tmp_path / "work").iterdir()) == []


@pytest.mark.slow
def test_work_folder_removed_on_close_and_on_exit(tmp_path):
    pytest.importorskip("gradio", reason="gradio not installed (pip install 'easyhoi[demo]')")
    from easyhoi.app import build_app

    app = build_app(examples=[])
    work = Path(app.easyhoi_work_dir)
    assert work.is_dir() and work.name.startswith("easyhoi-demo-")
    app.close()
    assert not work.exists()
    mine = tmp_path / "given"
    app = build_app(examples=[], work_dir=mine)
    app.close()
    assert mine.is_dir()  # a folder the caller gave is the caller's

    code = (
        "from easyhoi.app import build_app\n"
        "app = build_app(examples=[])\n"
        "print(app.easyhoi_work_dir, flush=True)\n"
    )  # exits without closing the app
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    left = Path(proc.stdout.strip().splitlines()[-1])
    assert left.name.startswith("easyhoi-demo-") and not left.exists()
