"""benchmarks/hand_error_split.py: the estimator's MPJPE split into size and articulation, on the
benchmark's own scenes (its estimator row must be the one the benchmark's tables report)."""

from __future__ import annotations

import pytest

from tests.helpers import load_script


def _script():
    return load_script("benchmarks/hand_error_split.py")


def test_split_matches_the_benchmark_estimator_and_orders_its_parts():
    import numpy as np

    from easyhoi.config import get_preset
    from easyhoi.synth.benchmark import BenchmarkSettings, scene_specs
    from easyhoi.synth.evaluate import _estimator_hand, _truth
    from easyhoi.synth.scene import make_scene

    out = _script().split(3, 2)
    bench = BenchmarkSettings()
    ref = []
    for seed, kind, grasp in scene_specs(2, 3):
        sc = make_scene(seed, kind, grasp, image_size=bench.image_size, hold=bench.hold)
        inp = sc.to_hoi_input(bench.perturbation, seed=seed)
        truth = _truth(sc, inp, get_preset("fast").optim)
        ref.append(_estimator_hand(truth, inp)["mpjpe_ra_cm"])
    assert out["estimator"] == pytest.approx(float(np.mean(ref)), rel=1e-6)
    # each part alone is smaller than both together, and neither is zero with this noise
    for part in ("size only", "articulation only"):
        assert 0.05 < out[part] < out["estimator"]
    # straightening the hinges never moves the true-shape hand further than its articulation
    # error by more than a rounding (it removes rotation the true hand does not have)
    assert out["hinge joints straightened"] <= out["articulation only"] * 1.02
