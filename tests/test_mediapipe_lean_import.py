"""The hand detector imports MediaPipe without its package ``__init__`` files, and the package
is still whole for any other user of it in the process."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

pytest.importorskip("mediapipe")

_CHILD = r"""
import sys, numpy as np
from easyhoi.perception.mediapipe_hand import MediaPipeHands
det = MediaPipeHands()
img = np.zeros((64, 64, 3), np.uint8)
assert det.detect(img) == []
lean = sorted(m for m in ("matplotlib", "mediapipe.tasks", "mediapipe.python.solutions.pose",
                          "mediapipe.python.solutions.drawing_utils") if m in sys.modules)
import mediapipe as mp
version = mp.__version__
whole = [hasattr(mp.solutions, "drawing_utils"), hasattr(mp, "tasks"),
         mp.solutions.hands.Hands is det._hands_api.Hands,
         callable(mp.solutions.drawing_utils.draw_landmarks)]
print(repr((lean, version, whole, "matplotlib.pyplot" in sys.modules)))
"""


def test_lean_import_then_whole_package_on_demand():
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    lean, version, whole, pyplot_after = ast.literal_eval(out.strip().splitlines()[-1])
    assert lean == []  # no drawing utilities, other solutions, tasks API or matplotlib
    from importlib.metadata import version as dist_version

    assert version == dist_version("mediapipe")
    assert whole == [True, True, True, True]
    assert pyplot_after  # the drawing utilities came with the whole package


def test_whole_package_first_is_used_as_is():
    child = (
        "import mediapipe as mp, sys\n"
        "from easyhoi.perception.mediapipe_hand import mediapipe_module\n"
        "h = mediapipe_module('mediapipe.python.solutions.hands')\n"
        "print(h is mp.solutions.hands, '__getattr__' in vars(mp))\n"
    )
    out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    assert out.split() == ["True", "False"]
