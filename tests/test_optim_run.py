"""End-to-end optimize(): conventions, ablation switches, determinism, errors, progress."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.config import get_preset, with_overrides
from easyhoi.errors import OptimizationError
from easyhoi.hoi import HOIResult
from easyhoi.optim.run import optimize
from easyhoi.testing.optim_scenes import make_scene

SIZE = 96
NOISE = dict(rot_noise=0.05, trans_noise=0.02, depth_noise=0.05, pose_noise=0.03)


@pytest.fixture(scope="module")
def scene():
    return make_scene("box", size=SIZE, **NOISE)


def _cfg(**over):
    cfg = replace(get_preset("fast").optim, render_size=SIZE)
    return with_overrides(cfg, over) if over else cfg


def _small(**over):
    """A cheap schedule for the tests that only check plumbing."""
    base = {
        "camera.max_iters": 12,
        "contact.max_iters": 16,
        "contact.register_at": [4, 10],
        "refine.max_iters": 8,
    }
    return _cfg(**{**base, **over})


@pytest.fixture(scope="module")
def full_result(scene, hand):
    """The fast preset on the toy scene, whose hand touches the box at ONE point. Its re-scans
    run without the preset's tie margin: that margin is in units of the contact-band term,
    which here sees one touching vertex, not contact zones on the surface, and with it the
    re-scans keep the camera stage's 12 % depth error (final error 2.8 cm instead of 0.6 cm;
    on held synthetic grasps the margin lowers S.D. and I.V., docs/benchmark.md)."""
    calls = []
    cfg = _cfg(**{"contact.rescan_tie_margin": 0.0})
    res = optimize(scene.inp, cfg, hand_model=hand, progress=lambda *a: calls.append(a))
    return res, calls


@pytest.mark.slow
def test_full_run_reconstructs_the_scene(full_result, scene, hand):
    res, _ = full_result
    assert isinstance(res, HOIResult)
    assert [s.name for s in res.stages] == ["initial", "camera", "contact", "refine"]
    gt = hand(scene.gt_hand.to(dtype=torch.float32)).vertices[0].numpy() / scene.gt_metric_scale

    def err(s):
        return (
            np.linalg.norm(
                hand(s.hand_params).vertices[0].detach().numpy() / s.metric_scale - gt, axis=1
            ).mean()
            * scene.gt_metric_scale
        )

    assert err(res.stages[-1]) < 0.5 * err(res.stages[0])
    assert err(res.stages[-1]) < 0.02  # metres
    assert abs(res.metric_scale / scene.gt_metric_scale - 1.0) < 0.1
    p = res.plausibility
    assert p["object_mask_iou"] > 0.9 and p["hand_mask_iou"] > 0.8
    assert p["penetration_depth_cm"] < 0.3 and abs(p["contact_distance_cm"]) < 0.6
    assert set(res.timings) >= {"camera", "contact", "refine", "total"}


def test_result_follows_the_metric_scale_convention(full_result, hand):
    res, _ = full_result
    v = hand(res.hand_params).vertices[0].detach().double().numpy() / res.metric_scale
    np.testing.assert_allclose(v, res.hand_vertices, atol=1e-6)
    assert res.hand_faces.shape == (hand.faces.shape[0], 3)
    assert res.config["render_size"] == SIZE and res.seed == 0
    res2 = res.detach()
    assert res2.stage("contact").metric_scale > 0


def test_progress_reports_every_stage(full_result):
    _, calls = full_result
    names = {c[0] for c in calls}
    assert names == {"camera", "contact", "refine"}
    stage, it, max_iters, terms = calls[-1]
    assert stage == "refine" and 0 <= it <= max_iters and "total" in terms


def test_no_stages_returns_the_initial_state(scene, hand):
    cfg = _small(run_camera=False, run_contact=False, run_refine=False)
    res = optimize(scene.inp, cfg, hand_model=hand)
    assert [s.name for s in res.stages] == ["initial"]
    init = res.stages[0]
    assert torch.equal(res.hand_params.transl, init.hand_params.transl)
    assert res.metric_scale == init.metric_scale
    assert torch.equal(res.camera.K, init.camera.K)


def test_stage_switches(scene, hand):
    res = optimize(scene.inp, _small(run_refine=False), hand_model=hand)
    assert [s.name for s in res.stages] == ["initial", "camera", "contact"]
    np.testing.assert_allclose(
        res.hand_vertices,
        hand(res.stage("contact").hand_params).vertices[0].detach().double().numpy()
        / res.metric_scale,
        atol=1e-6,
    )


def test_deterministic(scene, hand):
    a = optimize(scene.inp, _small(), hand_model=hand)
    b = optimize(scene.inp, _small(), hand_model=hand)
    np.testing.assert_array_equal(a.hand_vertices, b.hand_vertices)
    assert torch.equal(a.camera.K, b.camera.K) and a.metric_scale == b.metric_scale
    assert [s.losses for s in a.stages] == [s.losses for s in b.stages]


def test_divergence_names_the_stage(scene, hand):
    with pytest.raises(OptimizationError, match="camera"):
        optimize(scene.inp, _small(**{"camera.lr": 1e30}), hand_model=hand)
