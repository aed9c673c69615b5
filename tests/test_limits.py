"""Input limits and early checks: photo pixels from the header, --out probed by writing,
--set and --seed values, and the exit codes of a full disk or exhausted memory."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from easyhoi import limits
from easyhoi.cli import main
from easyhoi.errors import (
    ExitCode,
    InputTooLargeError,
    InvalidInputError,
    ResourceError,
    as_resource_error,
    exit_code_of,
)


@pytest.fixture
def photo(tmp_path) -> Path:
    p = tmp_path / "in" / "a.png"
    p.parent.mkdir()
    Image.fromarray(np.full((40, 48, 3), 90, np.uint8)).save(p)
    return p


@pytest.fixture
def no_reconstruction(monkeypatch):
    """Fail the test if the reconstruction is reached."""
    import easyhoi.pipeline as pipeline

    def reached(*a, **k):
        raise AssertionError("the reconstruction started before the check")

    monkeypatch.setattr(pipeline, "reconstruct_photo", reached)


def test_image_header_checked_without_decoding(tmp_path, monkeypatch):
    p = tmp_path / "big.png"
    Image.new("L", (300, 200)).save(p)
    assert limits.check_image_header(p) == (300, 200)
    monkeypatch.setattr(limits, "MAX_IMAGE_PIXELS", 300 * 200 - 1)
    with pytest.raises(InputTooLargeError, match=r"300x200 = 0 MP; at most 0 MP"):
        limits.check_image_header(p)
    from easyhoi.io.image import load_image, load_mask

    for loader in (load_image, load_mask):  # every photo and mask loader goes through it
        with pytest.raises(InputTooLargeError):
            loader(p)
    monkeypatch.setattr(limits, "MAX_IMAGE_FILE_BYTES", p.stat().st_size - 1)
    with pytest.raises(InputTooLargeError, match="MiB are accepted"):
        limits.check_image_header(p)


def test_image_header_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        limits.check_image_header(tmp_path / "none.png")
    with pytest.raises(InvalidInputError, match="not a file"):
        limits.check_image_header(tmp_path)
    (tmp_path / "e.png").write_bytes(b"")
    with pytest.raises(InvalidInputError, match="empty"):
        limits.check_image_header(tmp_path / "e.png")
    (tmp_path / "t.png").write_text("hello")
    with pytest.raises(InvalidInputError, match="not an image"):
        limits.check_image_header(tmp_path / "t.png")


def test_output_folder_probe_leaves_nothing(tmp_path):
    assert limits.check_output_folder(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert list(tmp_path.iterdir()) == []  # probed in the nearest existing folder, then removed
    (tmp_path / "f").write_text("x")
    with pytest.raises(InvalidInputError, match="exists and is not a folder"):
        limits.check_output_folder(tmp_path / "f" / "run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]


def test_output_folder_on_a_full_disk(tmp_path, monkeypatch):
    real = os.statvfs(tmp_path)
    fake = SimpleNamespace(f_bavail=10, f_frsize=4096, f_blocks=real.f_blocks)
    monkeypatch.setattr(limits.os, "statvfs", lambda p: fake)
    with pytest.raises(ResourceError, match="only 0 MiB free on its disk; at least 64 MiB"):
        limits.check_output_folder(tmp_path / "out")


@pytest.mark.parametrize("where", ["/proc/easyhoi-out", "/sys/kernel/easyhoi-out",
                                   "/proc/self/easyhoi/run"])  # fmt: skip
def test_out_under_proc_or_sys_refused_before_any_work(where, photo, capsys, no_reconstruction):
    if not Path("/proc/self").is_dir() or not Path("/sys/kernel").is_dir():
        pytest.skip("no /proc and /sys here")
    for cmd in (["reconstruct", str(photo)], ["batch", str(photo.parent)]):
        rc = main([*cmd, "--out", where, "-q"])
        err = capsys.readouterr().err
        assert rc == 2 and f"error: InvalidInputError: cannot write to --out {where}: " in err, err
        assert "Traceback" not in err


def test_huge_seed_and_non_finite_set_refused_with_key_and_range(photo, capsys, no_reconstruction,
                                                                  tmp_path):  # fmt: skip
    out = tmp_path / "out"
    rc = main(["reconstruct", str(photo), "--out", str(out), "--seed", str(10**20), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "optim.seed=100000000000000000000 refused" in err, err
    assert "must be in [0, 4294967295]" in err
    for value, says in (("Infinity", "must be a finite number, got inf"),
                        ("NaN", "must be a finite number, got nan"),
                        ("-1", "must be > 0, got -1.0")):  # fmt: skip
        rc = main(["reconstruct", str(photo), "--out", str(out), "-q",
                   "--set", f"optim.refine.lr_pose={value}"])  # fmt: skip
        err = capsys.readouterr().err
        assert rc == 2 and "optim.refine.lr_pose=" in err and says in err, err
    assert not out.exists()


def _pillow_bomb() -> BaseException:
    """The error Pillow raises itself when a file declares far too many pixels."""
    import io
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0"))
    try:
        Image.open(io.BytesIO(data))
    except Image.DecompressionBombError as exc:
        return exc
    raise AssertionError("Pillow accepted the header")


@pytest.mark.parametrize(
    "exc, code, text",
    [
        (OSError(errno.ENOSPC, "No space left on device", "/x/y"), 10, "disk full"),
        (OSError(errno.EDQUOT, "Disk quota exceeded"), 10, "disk full"),
        (OSError(errno.ENOMEM, "Cannot allocate memory"), 10, "out of memory"),
        (MemoryError(), 10, "out of memory"),
        (OSError(errno.EACCES, "Permission denied"), 70, None),
        (InputTooLargeError("x"), 10, "x"),
        (_pillow_bomb(), 10, "image too large: Image size (400000000 pixels)"),
    ],
)
def test_resource_conditions_are_not_bugs(exc, code, text):
    assert exit_code_of(exc) == code
    res = as_resource_error(exc)
    assert (res is None) == (text is None)
    if res is not None:
        assert text in str(res) and res.exit_code == ExitCode.RESOURCE


def test_mesh_face_count_read_before_parsing(tmp_path, monkeypatch):
    import trimesh

    import easyhoi.perception.importers as imp

    ball = trimesh.creation.icosphere(subdivisions=2)  # 320 faces
    for ext in ("ply", "obj", "stl", "off"):
        path = tmp_path / f"ball.{ext}"
        ball.export(path)
        assert limits.declared_face_count(path) == 320, ext
    (tmp_path / "crlf.obj").write_bytes(b"f 1 2 3\r\nv 0 0 0\r\nf\t1 2 3\r\n# f 9\r\nvf 1\r\n")
    assert limits.declared_face_count(tmp_path / "crlf.obj") == 2
    monkeypatch.setattr(imp, "MAX_OBJECT_FACES", 319)

    def never(path):
        raise AssertionError("parsed a mesh over the limit")

    monkeypatch.setattr("easyhoi.geometry.mesh.load_mesh", never)
    for ext in ("ply", "obj", "stl", "off"):
        with pytest.raises(InputTooLargeError, match="320 faces; at most 319") as info:
            imp.load_object_mesh(tmp_path / f"ball.{ext}")
        assert exit_code_of(info.value) == ExitCode.RESOURCE


def test_oversized_pickle_is_exit_10(tmp_path, monkeypatch):
    import pickle

    import easyhoi.hand.safe_pickle as sp

    path = tmp_path / "big.pkl"
    path.write_bytes(pickle.dumps(list(range(100))))
    monkeypatch.setattr(sp, "MAX_PICKLE_BYTES", 10)
    with pytest.raises(InputTooLargeError, match="larger than") as info:
        sp.load_mano_pickle(path)
    assert exit_code_of(info.value) == 10
