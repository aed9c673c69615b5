"""benchmarks/stage3_variants.py: its variants parsed against the fast preset, and its summary
against naive means and ratios (the stage-3 re-runs themselves are the benchmark's
``refine_from_contact``, tested with the benchmark)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from tests.helpers import load_script


def _script():
    return load_script("benchmarks/stage3_variants.py")


def _ap():
    return argparse.ArgumentParser(prog="stage3_variants")


def test_variants_are_named_overrides_checked_against_the_fast_preset():
    sv = _script()
    got = sv.parse_variants(_ap(), [["free", "optim.refine.rigid_first=false"],
                                    ["soft", "optim.refine.penetration_weight=500",
                                     "optim.refine.contact_weight=2"]])  # fmt: skip
    assert got == {
        "free": {"optim.refine.rigid_first": False},
        "soft": {"optim.refine.penetration_weight": 500, "optim.refine.contact_weight": 2},
    }


@pytest.mark.parametrize(
    "groups",
    [
        [["free", "optim.refine.no_such_field=1"]],  # the preset has no such field
        [["free", "optim.refine.push_out_steps=0.5"]],  # an int field
        [["free"]],  # nothing set
        [["a=1"]],  # no name
        [["free", "optim.refine.reg_weight=1"], ["free", "optim.refine.reg_weight=3"]],
        [["preset", "optim.refine.reg_weight=1"]],  # the preset's own row
        [["scan", "optim.contact.rescan_range=1.3"]],  # stage 2's: the snapshot has it already
    ],
)
def test_a_bad_variant_is_an_argument_error(groups, capsys):
    sv = _script()
    with pytest.raises(SystemExit) as exc:
        sv.parse_variants(_ap(), groups)
    assert exc.value.code == 2
    assert "stage3_variants: error:" in capsys.readouterr().err


def _rows(rng, metrics, n=12):
    rows = []
    for i in range(n):
        row = {"seed": i, "kind": "box", "grasp": "power"}
        for name, scale in (("contact", 2.0), ("preset", 1.0), ("free", 0.8), ("gt", 0.5)):
            row[name] = {k: float(scale * (1 + rng.random())) for k, _ in metrics}
        rows.append(row)
    return rows


def test_summary_means_and_paired_ratios_match_a_naive_computation():
    sv = _script()
    rows = _rows(np.random.default_rng(3), sv.METRICS)
    recs = sv.summary(rows, ["free"])
    assert [r["hand"] for r in recs[:: len(sv.METRICS)]] == ["contact", "preset", "free", "gt"]
    for r in recs:
        key = dict((label, k) for k, label in sv.METRICS)[r["metric"]]
        vals = [row[r["hand"]][key] for row in rows]
        assert r["mean"] == pytest.approx(sum(vals) / len(vals))
        if r["hand"] == "free":
            base = [row["preset"][key] for row in rows]
            assert r["ratio"] == pytest.approx(sum(vals) / sum(base))
            assert r["low"] <= r["ratio"] <= r["high"]
        else:
            assert "ratio" not in r  # only the variants are read against the preset
    text = sv.table(recs)
    assert text.count("\n") == len(recs) + 1
    free_mpjpe = next(r for r in recs if r["hand"] == "free" and r["metric"] == "MPJPE cm")
    assert f"{free_mpjpe['ratio']:.2f} ({free_mpjpe['low']:.2f}-" in text
