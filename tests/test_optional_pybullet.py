"""pybullet is optional from Python 3.12 on (no wheel): the S.D. metric names the install."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from easyhoi.errors import ExitCode, MissingDependencyError
from easyhoi.metrics import simulation


@pytest.fixture
def no_pybullet(monkeypatch):
    monkeypatch.setitem(sys.modules, "pybullet", None)  # "import pybullet" raises ImportError


def test_simulation_metric_without_pybullet_says_what_to_install(no_pybullet):
    hand = trimesh.creation.icosphere(1, radius=0.02)
    obj = trimesh.creation.box((0.05, 0.05, 0.05))
    obj.apply_translation((0.0, 0.0, 0.04))
    for call in (
        lambda: simulation.simulation_displacement(hand, obj, steps=2),
        lambda: simulation.convex_decomposition(obj),
    ):
        with pytest.raises(MissingDependencyError) as info:
            call()
        msg = str(info.value)
        assert "pybullet" in msg and "simulation displacement" in msg
        assert "easyhoi[sim]" in msg
        assert info.value.exit_code == ExitCode.MISSING_DEPENDENCY
    assert np.isfinite(hand.volume)  # the meshes were valid input: only pybullet was missing


def test_pybullet_is_a_dependency_only_below_python_3_12():
    meta = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    assert meta["requires-python"] == ">=3.11,<3.13"
    pins = [d for d in meta["dependencies"] if d.startswith("pybullet")]
    assert pins == ["pybullet>=3.2; python_version < '3.12'"]
    assert meta["optional-dependencies"]["sim"] == ["pybullet>=3.2"]
