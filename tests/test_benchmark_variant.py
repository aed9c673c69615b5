"""A benchmark variant: `--set` overrides of the fast preset reach the scenes, bad ones fail
first, and benchmarks/compare_synth.py compares two runs of the same scenes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

import easyhoi.synth.benchmark as bench
from easyhoi.cli import main
from easyhoi.errors import InvalidInputError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import compare_synth  # noqa: E402


def test_overrides_reach_every_scene_and_the_report(monkeypatch):
    seen = []

    def fake_scene(spec, settings, fast, paper, gallery=False):
        seen.append((spec, fast))
        return {"timings": {"total": 0.0}}

    monkeypatch.setattr(bench, "_warm_up", lambda fast: seen.append(("warm", fast)))
    monkeypatch.setattr(bench, "evaluate_scene", fake_scene)
    settings = bench.BenchmarkSettings(
        scenes=2, paper_scenes=0, fast_overrides={"optim.refine.prior_weight": 3.5}
    )
    report = bench.run_benchmark(settings)
    assert len(seen) == 3  # the warm-up and both scenes
    assert all(fast.refine.prior_weight == 3.5 for _, fast in seen)
    assert report["settings"]["fast_overrides"] == {"optim.refine.prior_weight": 3.5}
    # the preset itself is untouched
    plain = bench.BenchmarkSettings(scenes=1).fast_config()
    assert plain.optim.refine.prior_weight != 3.5


def test_a_bad_override_fails_before_any_scene(tmp_path, capsys):
    with pytest.raises(InvalidInputError):
        bench.BenchmarkSettings(scenes=1, fast_overrides={"optim.refine.nope": 1})
    rc = main(["bench", "--scenes", "1", "--set", "optim.refine.nope=1", "--out",
               str(tmp_path / "o")])  # fmt: skip
    assert rc == 2 and "nope" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def _report(path: Path, sd: list[float], mpjpe: list[float], seeds=None) -> Path:
    scenes = []
    for i, (s, m) in enumerate(zip(sd, mpjpe, strict=True)):
        metrics = {"sd_cm": s, "iv_cm3": 2.0 * s, "iv_obman_cm3": s, "mpjpe_ra_cm": m,
                   "kp2d_px": 1.0}  # fmt: skip
        seed = (seeds or range(len(sd)))[i]
        scenes.append({"seed": seed, "kind": "box", "grasp": "power",
                       "stages": {st: metrics for st in compare_synth.STAGES}})  # fmt: skip
    path.write_text(json.dumps({"scenes": scenes}))
    return path


def test_compare_gives_the_ratio_of_means_and_a_paired_interval(tmp_path, capsys):
    a = _report(tmp_path / "a.json", [1.0, 2.0, 3.0, 4.0], [0.5, 0.5, 0.5, 0.5])
    b = _report(tmp_path / "b.json", [2.0, 4.0, 6.0, 8.0], [0.4, 0.4, 0.4, 0.4])
    rows = compare_synth.compare(compare_synth.load_scenes([a]), compare_synth.load_scenes([b]))
    sd = next(r for r in rows if r["stage"] == "refine" and r["metric"] == "S.D. cm")
    assert sd["base"] == pytest.approx(2.5) and sd["variant"] == pytest.approx(5.0)
    # every scene doubled: every resample's ratio is 2, so the interval is the point
    assert (sd["ratio"], sd["low"], sd["high"]) == pytest.approx((2.0, 2.0, 2.0))
    mp = next(r for r in rows if r["stage"] == "initial" and r["metric"] == "MPJPE cm")
    assert mp["ratio"] == pytest.approx(0.8)
    moves = compare_synth.largest_moves(compare_synth.load_scenes([a]),
                                        compare_synth.load_scenes([b]), k=2)  # fmt: skip
    assert [m[1:] for m in moves] == [(4.0, 8.0), (3.0, 6.0)]
    assert compare_synth.main([str(a), str(b)]) == 0
    assert "2.00 (2.00-2.00)" in capsys.readouterr().out
    # reports without the own-camera S.D. compare without it; with it, it is compared too
    assert not any(r["metric"] == "S.D. own camera cm" for r in rows)
    own = []
    for path, f in ((a, 1.0), (b, 3.0)):
        data = json.loads(path.read_text())
        for sc in data["scenes"]:
            sc["stages"] = {k: dict(v, sd_own_cm=f * v["sd_cm"]) for k, v in sc["stages"].items()}
        path.write_text(json.dumps(data))
        own.append(compare_synth.load_scenes([path]))
    rows = compare_synth.compare(*own)
    r = next(r for r in rows if r["stage"] == "refine" and r["metric"] == "S.D. own camera cm")
    assert r["ratio"] == pytest.approx(6.0) and r["base"] == pytest.approx(2.5)


def test_compare_interval_against_a_naive_bootstrap(tmp_path):
    rng = np.random.default_rng(5)
    x, y = rng.random(12) + 0.5, rng.random(12) + 0.5
    a = _report(tmp_path / "a.json", list(x), [1.0] * 12)
    b = _report(tmp_path / "b.json", list(y), [1.0] * 12)
    rows = compare_synth.compare(compare_synth.load_scenes([a]), compare_synth.load_scenes([b]))
    sd = next(r for r in rows if r["stage"] == "camera" and r["metric"] == "S.D. cm")
    from easyhoi.synth.tables import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED

    idx = np.random.default_rng(BOOTSTRAP_SEED).integers(0, 12, size=(BOOTSTRAP_RESAMPLES, 12))
    ratios = [y[i].mean() / x[i].mean() for i in idx]
    assert sd["low"] == pytest.approx(np.quantile(ratios, 0.025))
    assert sd["high"] == pytest.approx(np.quantile(ratios, 0.975))
    assert sd["low"] < y.mean() / x.mean() < sd["high"]


def test_compare_refuses_runs_of_other_scenes(tmp_path, capsys):
    a = _report(tmp_path / "a.json", [1.0, 2.0], [0.5, 0.5], seeds=[0, 1])
    b = _report(tmp_path / "b.json", [1.0, 2.0], [0.5, 0.5], seeds=[0, 2])
    assert compare_synth.main([str(a), str(b)]) == 2
    assert "different scenes" in capsys.readouterr().err
    assert compare_synth.main([str(a), str(tmp_path / "missing.json")]) == 2


def test_a_variant_says_so_above_its_tables(monkeypatch):
    from easyhoi.synth import tables

    monkeypatch.setattr(tables, "all_tables", lambda report: {"Goals": "| a |"})
    text = tables.tables_markdown({"settings": {"fast_overrides": {"optim.refine.x": 2.5}}})
    assert text.startswith("Fast preset with overrides: `optim.refine.x=2.5`.")
    assert "Fast preset" not in tables.tables_markdown({"settings": {"fast_overrides": {}}})
