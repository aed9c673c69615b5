"""easyhoi.io.native_output.silenced: native writes to a file descriptor are dropped inside the
block and pass again after it, in a fresh process (pytest captures the descriptors itself)."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = r"""
import logging, os, sys
from easyhoi.io.native_output import silenced
fd = int(sys.argv[1])
if sys.argv[2] == "debug":
    logging.getLogger("easyhoi").setLevel(logging.DEBUG)
os.write(fd, b"before;")
with silenced(fd):
    os.write(fd, b"inside;")
os.write(fd, b"after;")
with silenced(fd, keep_when_debug=False):
    os.write(fd, b"forced;")
os.write(fd, b"end")
"""


def _run(fd: int, mode: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", SCRIPT, str(fd), mode], capture_output=True, check=True
    )


def test_silenced_drops_native_writes_and_restores_the_descriptor():
    for fd in (1, 2):
        p = _run(fd, "plain")
        out, other = (p.stdout, p.stderr) if fd == 1 else (p.stderr, p.stdout)
        assert out == b"before;after;end"
        assert other == b""


def test_silenced_keeps_native_writes_with_the_debug_log():
    p = _run(2, "debug")
    assert p.stderr == b"before;inside;after;end"
