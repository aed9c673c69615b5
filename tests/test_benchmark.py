"""Synthetic benchmark (easyhoi.synth.benchmark / tables): frames, quick mode, determinism."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from easyhoi.config import get_preset
from easyhoi.structures import Camera
from easyhoi.synth.benchmark import (
    LOSS_ABLATIONS,
    BenchmarkSettings,
    evaluate_scene,
    run_benchmark,
    scene_specs,
    strip_timings,
)
from easyhoi.synth.evaluate import _truth, evaluate_hand, gt_hand_state
from easyhoi.synth.scene import make_scene
from easyhoi.synth.tables import all_tables, goals, save_report, tables_markdown

QUICK = BenchmarkSettings(scenes=3, paper_scenes=0, gallery=1, chamfer_samples=5000)


def test_scene_specs_cover_kinds_and_grasps():
    specs = scene_specs(15, seed=2)
    assert len({s[0] for s in specs}) == 15 and specs[0][0] == 2000
    assert {s[1] for s in specs[:5]} == {"cylinder", "box", "sphere", "mug", "tool"}
    assert len({(s[1], s[2]) for s in specs}) == 15


def test_gt_hand_maps_to_zero_error():
    """The GT hand expressed in the input's frames comes back exactly through every metric."""
    torch.set_num_threads(1)
    scene = make_scene(3, "box", "power", image_size=64, photo=False)
    inp = scene.to_hoi_input("hamer", seed=3)
    fast = get_preset("fast").optim
    e = evaluate_hand(_truth(scene, inp, fast), *gt_hand_state(scene, inp), sd_steps=5)
    for k in ("mpjpe_ra_cm", "mpjpe_root_cm", "mpjpe_cam_cm", "mpjpe_world_cm", "mpvpe_world_cm"):
        assert e[k] < 1e-6, (k, e[k])
    assert e["kp2d_px"] < 1e-6  # reprojected through the GT camera: the GT 2D keypoints
    assert e["scale_err_pct"] < 1e-9
    assert e["hand_iou"] > 0.9  # GT hand, hard render, vs GT M_h (occluder: deformed object)
    # a 1 % metric-scale error moves the hand in the world frame but not its articulation
    params, m, cam = gt_hand_state(scene, inp)
    e2 = evaluate_hand(_truth(scene, inp, fast), params, m * 1.01, cam, sd_steps=5)
    assert e2["mpjpe_ra_cm"] < 1e-6 and 0.01 < e2["mpjpe_world_cm"] < 3.0
    assert abs(e2["scale_err_pct"] - 1.0) < 1e-6
    # the GT camera's own image down is the GT gravity: the same simulation
    assert e["gravity_angle_deg"] < 1e-5 and e["sd_own_cm"] == e["sd_cm"]


def test_own_camera_gravity_is_the_cameras_image_down():
    """``sd_own_cm`` simulates with +y of the hand's own camera in the object frame: a camera
    turned by 50 degrees about the object's z axis parts it from the GT gravity by the angle
    between the two directions, computed here directly."""
    torch.set_num_threads(1)
    scene = make_scene(3, "box", "power", image_size=64, photo=False)
    inp = scene.to_hoi_input("hamer", seed=3)
    truth = _truth(scene, inp, get_preset("fast").optim)
    params, m, cam = gt_hand_state(scene, inp)
    t = np.radians(50.0)
    Rz = torch.tensor([[np.cos(t), -np.sin(t), 0.0], [np.sin(t), np.cos(t), 0.0], [0, 0, 1.0]],
                      dtype=cam.R.dtype)  # fmt: skip
    turned = Camera(cam.K, cam.R @ Rz, cam.t, cam.width, cam.height)
    e = evaluate_hand(truth, params, m, turned, sd_steps=5, cone=False)
    down = (cam.R @ Rz).double().numpy().T @ np.array([0.0, 1.0, 0.0])
    g = np.asarray(truth.gravity_obj, float)
    naive = np.degrees(np.arccos(down @ g / np.linalg.norm(down) / np.linalg.norm(g)))
    assert e["gravity_angle_deg"] == pytest.approx(naive, abs=1e-6) and naive > 1.0
    assert 0 <= e["sd_own_cm"] < 50


@pytest.fixture(scope="module")
def quick_report():
    torch.set_num_threads(1)
    return run_benchmark(QUICK)


@pytest.mark.slow
def test_quick_benchmark_sane_and_deterministic(quick_report, tmp_path):
    rep = quick_report
    assert len(rep["scenes"]) == 3
    for row in rep["scenes"]:
        assert set(row["stages"]) == {"initial", "camera", "contact", "refine"}
        assert set(row["loss_ablation"]) == set(LOSS_ABLATIONS)
        for ev in [*row["stages"].values(), *row["loss_ablation"].values()]:
            assert 0 <= ev["sd_cm"] < 50 and 0 <= ev["iv_cm3"] < 100
            assert 0 <= ev["mpjpe_ra_cm"] < 5  # articulation error of a "hamer" hand: ~1 cm
            assert 0.2 < ev["hand_iou"] <= 1 and 0.2 < ev["object_iou"] <= 1
            assert ev["scale_err_pct"] < 100
        # the GT object shape reconstructs exactly (aligned C.D. ~ 0), the perturbed one not
        q = row["object_quality"]
        assert q["gt"]["translation_scale"]["cd"] < 1e-6
        assert q["gt"]["translation_scale"]["f5"] == 1.0
        assert 0 < q["reconstructed"]["translation_scale"]["cd"] < 1.0
        # the estimator's articulation is the starting point: error ~1 cm, not 0
        assert 0.2 < row["object_input"]["estimator"]["mpjpe_ra_cm"] < 3
        assert row["timings"]["fast"]["total"] > 0
        # held scenes (BenchmarkSettings.hold): the GT grasp was checked under image-down gravity
        assert 0 <= row["gravity_sd_cm"] < 15
    # determinism: one scene evaluated again gives identical numbers
    fast = get_preset("fast").optim
    again = evaluate_scene(scene_specs(1, QUICK.seed)[0], QUICK, fast, None)
    assert strip_timings(again) == strip_timings(rep["scenes"][0])
    # tables, goals and files
    tables = all_tables(rep)
    assert len(tables) == 10
    md = tables_markdown(rep)
    assert "| no optimization |" in md and "| w/o penetration |" in md
    # no paper run here (paper_scenes=0): the by-group tables say so
    by_group = [t for k, t in tables.items() if "fast vs paper by" in k]
    assert len(by_group) == 2
    assert all(t.startswith("(the paper preset did not run") for t in by_group)
    assert "MISSED" in md or "met" in md
    assert all(isinstance(g["met"], bool) for g in goals(rep))
    paths = save_report(rep, tmp_path)
    assert {"json", "markdown", "stages", "gallery"} <= set(paths)
    data = json.loads(paths["json"].read_text())
    assert len(data["scenes"]) == 3 and data["goals"]


def test_refine_rerun_matches_optimize():
    """refine_from_contact with the unchanged config reproduces optimize's stage 3 exactly."""
    from easyhoi.optim.run import optimize
    from easyhoi.synth.evaluate import refine_from_contact

    torch.set_num_threads(1)
    scene = make_scene(1, "box", "precision", image_size=64, photo=False)
    inp = scene.to_hoi_input("hamer", seed=1)
    cfg = get_preset("fast").optim
    res = optimize(inp, cfg)
    params, m = refine_from_contact(inp, res, cfg)
    for name in ("global_orient", "transl", "pose"):
        a, b = getattr(params, name), getattr(res.hand_params, name)
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())
    assert m == res.metric_scale


def test_preset_quality_table_flags_fast_and_gt_against_paper():
    from easyhoi.synth.tables import PRESET_METRICS, preset_quality_table

    def ev(sd, iou):
        d = {k: 1.0 for k, _ in PRESET_METRICS}
        d.update(sd_cm=sd, hand_iou=iou)
        return d

    # paper S.D. 2 cm; fast 2.05 (within 5 % + 0.05) and GT 8 (worse); IoU: fast 0.5 < 0.95 * 0.8
    rows = [
        {"stages": {"refine": ev(2.05, 0.5)}, "paper": ev(2.0, 0.8), "ground_truth": ev(8.0, 1.0)},
        {"stages": {"refine": ev(2.05, 0.5)}, "paper": ev(2.0, 0.8), "ground_truth": ev(8.0, 1.0)},
    ]
    lines = {ln.split("|")[1].strip(): ln for ln in preset_quality_table({"scenes": rows})
             .splitlines()[2:]}  # fmt: skip
    cells = {k: [c.strip() for c in v.strip("|").split("|")] for k, v in lines.items()}
    # identical scenes: every resample gives the same ratio, so the interval is a point
    assert cells["sd_cm"] == ["sd_cm", "2.050", "2.000", "no", "1.02 (1.02-1.02)", "8.000", "yes"]
    assert cells["hand_iou"] == ["hand_iou", "0.500", "0.800", "yes", "0.62 (0.62-0.62)",
                                 "1.000", "no"]  # fmt: skip
    assert cells["iv_cm3"][3] == "no" and cells["iv_cm3"][6] == "no"
    # a metric the run did not compute (the gravity cone with --light) reads nan, silently
    for r in rows:
        for d in (r["stages"]["refine"], r["paper"], r["ground_truth"]):
            d["sd_cone_cm"] = None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        table = preset_quality_table({"scenes": rows})
    cone = next(ln for ln in table.splitlines() if ln.startswith("| sd_cone_cm"))
    assert [c.strip() for c in cone.strip("|").split("|")][1:3] == ["nan", "nan"]


def test_ratio_interval_matches_a_naive_paired_bootstrap():
    from easyhoi.synth.tables import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, ratio_interval

    rng = np.random.default_rng(3)
    fast, paper = rng.exponential(4.0, 12), rng.exponential(3.5, 12)
    r, lo, hi = ratio_interval(fast, paper)
    # naive: one resample at a time, the same index draws, the pairs kept together
    idx = np.random.default_rng(BOOTSTRAP_SEED).integers(0, 12, size=(BOOTSTRAP_RESAMPLES, 12))
    naive = sorted(sum(fast[i] for i in row) / sum(paper[i] for i in row) for row in idx.tolist())
    assert r == pytest.approx(fast.sum() / paper.sum(), rel=1e-12)
    assert lo == pytest.approx(np.quantile(naive, 0.025), rel=1e-9)
    assert hi == pytest.approx(np.quantile(naive, 0.975), rel=1e-9)
    assert lo < r < hi and hi - lo > 0.2  # 12 noisy scenes: a wide interval
    # pairing: fast = 1.1 x paper scene by scene -> the ratio of every resample is exactly 1.1
    r2, lo2, hi2 = ratio_interval(1.1 * paper, paper)
    assert (r2, lo2, hi2) == pytest.approx((1.1, 1.1, 1.1), rel=1e-12)
    assert all(np.isnan(ratio_interval(np.ones(3), np.zeros(3))))


def test_preset_by_group_table_means_per_grasp_type():
    from easyhoi.synth.tables import GROUP_METRICS, preset_by_group_table

    keys = [k for k, _, _ in GROUP_METRICS]

    def ev(x):
        return {k: x + i for i, k in enumerate(keys)}

    def row(grasp, fast, paper=None, gt=None):
        r = {"grasp": grasp, "stages": {"refine": ev(fast)}}
        return r if paper is None else {**r, "paper": ev(paper), "ground_truth": ev(gt)}

    rows = [row("power", 1.0, 3.0, 0.5), row("power", 2.0, 5.0, 1.5),
            row("lateral", 7.0, 2.0, 1.0), row("precision", 9.0)]  # fmt: skip
    # (the precision scene has no paper run: left out)
    lines = preset_by_group_table({"scenes": rows}).splitlines()
    cells = {ln.split("|")[1].strip(): [c.strip() for c in ln.strip("|").split("|")]
             for ln in lines[2:]}  # fmt: skip
    assert list(cells) == ["lateral", "power", "all"]
    # naive means: power fast (1 + 2) / 2, paper (3 + 5) / 2, GT (0.5 + 1.5) / 2, per column
    # offset by the column index (ev); all three paper scenes for "all"
    assert cells["power"][:3] == ["power", "2", "1.50 / 4.00 / 1.00"]
    assert cells["power"][3] == "2.5 / 5.0 / 2.0"  # I.V. column: + 1, one decimal
    assert cells["power"][4] == "3.50 / 6.00 / 3.00"  # MPJPE column: + 2
    assert cells["lateral"][2] == "7.00 / 2.00 / 1.00"
    assert cells["all"][1] == "3" and cells["all"][2] == "3.33 / 3.33 / 1.00"
    assert preset_by_group_table({"scenes": rows[3:]}).startswith("(the paper preset did not run")


def test_goals_and_hand_accuracy_table_against_naive_ratios():
    from easyhoi.synth.tables import goals, hand_accuracy_table

    def ev(sd, iv, mp, kp):
        return {"sd_cm": sd, "iv_cm3": iv, "iv_obman_cm3": iv, "mpjpe_ra_cm": mp, "kp2d_px": kp,
                "sd_own_cm": sd / 2 + 1.0}  # fmt: skip

    def scene(k):
        stages = {
            "initial": ev(10.0 * k, 8, 1.0, 4.0),
            "camera": ev(8.0 * k, 8, 1.0, 4.0),
            "contact": ev(9.0 * k, 10, 1.0, 3.0),
            "refine": ev(4.0 * k, 4, 0.9, 2.0),
        }
        gt = {**stages, "refine": ev(3.0, 1, 0.7 * k, 2.0)}
        est = {"mpjpe_ra_cm": 1.0 * k, "kp2d_px": 4.0, "detector_kp2d_px": 2.0}
        return {"stages": stages, "object_input": {"estimator": est, "gt_stages": gt}}

    report = {"scenes": [scene(1.0), scene(2.0)]}
    g = {x["goal"]: x for x in goals(report)}
    sd = g["S.D. full / no optimization <= 0.55 (-45 %)"]
    assert sd["ratio"] == pytest.approx((4 + 8) / (10 + 20)) and sd["met"]
    raise_ = g["S.D. contact / camera <= 1 (no stage raises it)"]
    assert raise_["ratio"] == pytest.approx(27 / 24) and not raise_["met"]
    own = g["S.D. own camera: full / no optimization <= 0.55"]
    assert own["ratio"] == pytest.approx((3 + 5) / (6 + 11)) and own["met"]
    own_raise = g["S.D. own camera: contact / camera <= 1"]
    assert own_raise["ratio"] == pytest.approx((5.5 + 10) / (5 + 9)) and not own_raise["met"]
    # reports written before the column have no own-camera goals
    for sc in report["scenes"]:
        for st in sc["stages"].values():
            del st["sd_own_cm"]
    assert not any(x["goal"].startswith("S.D. own camera") for x in goals(report))
    iv = g["I.V. (solid) refinement / contact alignment <= 0.45"]
    assert iv["ratio"] == pytest.approx(0.4) and iv["met"]
    mp = g["MPJPE after refinement / estimator's <= 1"]
    assert mp["ratio"] == pytest.approx(1.8 / 3.0) and mp["met"]
    gt = g["true object: MPJPE after refinement / estimator's <= 0.8"]
    assert gt["ratio"] == pytest.approx(0.7 * 3.0 / 3.0) and gt["met"]
    table = hand_accuracy_table(report).splitlines()
    refine = [c.strip() for c in table[-1].strip("|").split("|")]
    assert refine[0] == "+ refinement (full)"
    assert refine[1] == "0.900" and refine[3] == "2.00" and refine[5] == "1.050"
    assert refine[4] == "0.50 (0.50-0.50)"  # 2D error ratio identical in both scenes
    detector = [c.strip() for c in table[3].strip("|").split("|")]
    assert detector[3] == "2.00" and detector[4] == "0.50 (0.50-0.50)"
