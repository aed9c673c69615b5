"""benchmarks/bench_gpu.py: its scenes where pybullet is missing (Python 3.12 and later, where a
GPU machine's image usually is): drawn without the holding roll, with a note, instead of failing."""

from __future__ import annotations

import sys

import numpy as np

from tests.helpers import load_script


def test_scenes_without_pybullet_are_drawn_unrolled_with_a_note(monkeypatch, capsys):
    from easyhoi.synth.scene import make_scene

    bg = load_script("benchmarks/bench_gpu.py")
    monkeypatch.setitem(sys.modules, "pybullet", None)  # import pybullet -> ImportError
    scenes = bg._scenes(2, 64)
    assert [name for name, _ in scenes] == ["0-cylinder-power", "1-box-precision"]
    assert "pybullet" in capsys.readouterr().err
    # the same scene make_scene draws without the roll
    plain = make_scene(0, "cylinder", "power", image_size=64, hold=False)
    inp = plain.to_hoi_input("hamer", seed=0)
    assert np.array_equal(scenes[0][1].image, inp.image)
