"""Tables, goal checks, plots and gallery of a :func:`easyhoi.synth.benchmark.run_benchmark` report.

Every table is Markdown; numbers are means over the scenes (``mean ± std`` where shown). Units:
S.D. cm, I.V. cm^3, MPJPE / MPVPE cm, C.D. cm^2 / 10 (MOHO), times s.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = [
    "all_tables",
    "goals",
    "hand_accuracy_table",
    "preset_by_group_table",
    "ratio_interval",
    "save_report",
    "tables_markdown",
]

STAGE_ROWS = (
    ("initial", "no optimization"),
    ("camera", "+ camera setup"),
    ("contact", "+ contact alignment"),
    ("refine", "+ refinement (full)"),
)
#: (key, header, format, mean ± std?)
HAND_COLUMNS = (
    ("sd_cm", "S.D. cm", "{:.2f}", True),
    ("sd_own_cm", "S.D. own camera cm", "{:.2f}", True),
    ("sd_cone_cm", "S.D. cone cm", "{:.2f}", False),
    ("iv_cm3", "I.V. cm3 solid", "{:.2f}", True),
    ("iv_obman_cm3", "I.V. cm3 ObMan", "{:.2f}", False),
    ("mpjpe_ra_cm", "MPJPE cm", "{:.2f}", False),
    ("mpvpe_ra_cm", "MPVPE cm", "{:.2f}", False),
    ("mpjpe_root_cm", "MPJPE root cm", "{:.2f}", False),
    ("mpjpe_cam_cm", "MPJPE cam cm", "{:.1f}", False),
    ("mpjpe_world_cm", "MPJPE world cm", "{:.2f}", False),
    ("kp2d_px", "2D kp px", "{:.2f}", False),
    ("in_contact", "contact", "{:.2f}", False),
    ("hand_iou", "hand IoU", "{:.3f}", False),
    ("object_iou", "obj IoU", "{:.3f}", False),
    ("scale_err_pct", "scale err %", "{:.1f}", False),
)
#: Metrics compared between the fast and paper presets: (key, higher is better).
PRESET_METRICS = (
    ("sd_cm", False),
    ("sd_cone_cm", False),
    ("iv_cm3", False),
    ("mpjpe_ra_cm", False),
    ("mpvpe_ra_cm", False),
    ("mpjpe_root_cm", False),
    ("hand_iou", True),
    ("in_contact", True),
)
TIMED = ("setup", "initial", "camera", "contact", "refine", "plausibility", "total")


def _values(dicts, key) -> np.ndarray:
    return np.array([float(d[key]) for d in dicts if d.get(key) is not None], float)


def _cell(dicts, key, fmt, with_std) -> str:
    v = _values(dicts, key)
    if len(v) == 0:
        return "n/a"
    s = fmt.format(v.mean())
    return s + (" ± " + fmt.format(v.std()) if with_std else "")


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _hand_table(named: list[tuple[str, list[dict]]], first: str) -> str:
    header = [first] + [h for _, h, _, _ in HAND_COLUMNS]
    rows = [[name] + [_cell(ds, k, f, s) for k, _, f, s in HAND_COLUMNS] for name, ds in named]
    return _table(header, rows)


def stage_table(report: dict) -> str:
    sc = report["scenes"]
    named = [(label, [r["stages"][k] for r in sc]) for k, label in STAGE_ROWS]
    named.append(("(GT hand, input object)", [r["ground_truth"] for r in sc]))
    return _hand_table(named, "stage")


def loss_table(report: dict) -> str:
    sc = report["scenes"]
    names = list(sc[0]["loss_ablation"])
    return _hand_table([(n, [r["loss_ablation"][n] for r in sc]) for n in names], "stage-3 loss")


def object_input_table(report: dict) -> str:
    sc = report["scenes"]
    named = [
        (
            "estimator hand (no optimization, own camera)",
            [r["object_input"]["estimator"] for r in sc],
        ),
        ("reconstructed (perturbed) object", [r["object_input"]["reconstructed"] for r in sc]),
        ("ground-truth object shape", [r["object_input"]["gt"] for r in sc]),
    ]
    return _hand_table(named, "object input")


def _ci_cell(values: np.ndarray, reference: np.ndarray) -> str:
    r, lo, hi = ratio_interval(values, reference)
    return f"{r:.2f} ({lo:.2f}-{hi:.2f})" if np.isfinite(r) else "n/a"


def hand_accuracy_table(report: dict) -> str:
    """MPJPE (rotation-aligned) and 2D keypoint error of the estimator, the detector and every
    stage, with the reconstructed object and with the true object, each with its ratio to the
    estimator's (paired-bootstrap 95 % interval, :func:`ratio_interval`)."""
    sc = report["scenes"]
    est = [r["object_input"]["estimator"] for r in sc]
    e_mp, e_kp = _values(est, "mpjpe_ra_cm"), _values(est, "kp2d_px")
    ratio = "/ estimator"
    header = ["hand", "MPJPE cm", ratio, "2D kp px", ratio,
              "MPJPE cm, true object", ratio, "2D kp px, true object", ratio]  # fmt: skip
    det = _values(est, "detector_kp2d_px")
    rows = [
        ["estimator", f"{e_mp.mean():.3f}", "1", f"{e_kp.mean():.2f}", "1"] + [""] * 4,
        ["2D keypoint detector", "", "", f"{det.mean():.2f}" if len(det) else "n/a",
         _ci_cell(det, e_kp) if len(det) == len(e_kp) else "n/a"] + [""] * 4,
    ]  # fmt: skip
    for key, label in STAGE_ROWS:
        rec = [r["stages"][key] for r in sc]
        gts = [r["object_input"].get("gt_stages", {}).get(key) for r in sc]
        row = [label]
        for ds in (rec, gts):
            if any(d is None for d in ds):
                row += ["n/a"] * 4
                continue
            mp, kp = _values(ds, "mpjpe_ra_cm"), _values(ds, "kp2d_px")
            row += [f"{mp.mean():.3f}", _ci_cell(mp, e_mp), f"{kp.mean():.2f}", _ci_cell(kp, e_kp)]
        rows.append(row)
    return _table(header, rows)


def object_quality_table(report: dict) -> str:
    sc = report["scenes"]
    header = [
        "object input",
        "C.D. (aligned)",
        "F@5mm",
        "F@10mm",
        "C.D. (as placed)",
        "F@5mm",
        "F@10mm",
    ]
    rows = []
    for key, label in (("reconstructed", "reconstructed (perturbed)"), ("gt", "ground truth")):
        row = [label]
        for align in ("translation_scale", "none"):
            ds = [r["object_quality"][key][align] for r in sc]
            row += [
                _cell(ds, "cd", "{:.3f}", False),
                _cell(ds, "f5", "{:.3f}", False),
                _cell(ds, "f10", "{:.3f}", False),
            ]
        rows.append(row)
    return _table(header, rows)


def _paper_rows(report: dict) -> list[dict]:
    return [r for r in report["scenes"] if "paper" in r]


def runtime_table(report: dict) -> str:
    sc, pr = report["scenes"], _paper_rows(report)
    cap = report["settings"].get("paper_cap", 0)
    pname = "paper" + (f" (capped at {cap} it.)" if cap else "")
    header = [
        "stage",
        f"fast, all {len(sc)} scenes",
        f"fast, same {len(pr)} scenes",
        f"{pname}, {len(pr)} scenes",
        "paper / fast",
    ]
    rows = []
    for k in TIMED:
        f_all = _values([r["timings"]["fast"] for r in sc], k)
        f_k = _values([r["timings"]["fast"] for r in pr], k)
        p_k = _values([r["timings"]["paper"] for r in pr], k)
        ratio = f"{p_k.mean() / f_k.mean():.1f}x" if len(p_k) and f_k.mean() > 0 else "n/a"
        cells = [f"{v.mean():.2f}" if len(v) else "n/a" for v in (f_all, f_k, p_k)]
        rows.append([k] + cells + [ratio])
    return _table(header, rows)


def _worse(fast: float, paper: float, higher_better: bool, tol: float = 0.05) -> bool:
    """Fast worse than paper by > 5 % (relative), with a small absolute floor for near-zero
    values (0.01 for ratios and IoUs, 0.05 for cm / cm^3)."""
    if higher_better:
        return fast < paper * (1 - tol) - 0.01
    return fast > paper * (1 + tol) + 0.05


def _preset_values(rows: list[dict], key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-scene values over the paper scenes of ``key``: fast (final stage), paper, GT hand."""
    return tuple(
        _values([get(r) for r in rows], key)
        for get in (lambda r: r["stages"]["refine"], lambda r: r["paper"],
                    lambda r: r["ground_truth"])
    )  # fmt: skip


def _mean(v: np.ndarray) -> float:
    """Mean of ``v``; NaN (without NumPy's empty-slice warning) when it holds no value, as a
    metric the run did not compute (the gravity cone with ``--light``)."""
    return float(v.mean()) if len(v) else float("nan")


def _preset_means(rows: list[dict], key: str) -> tuple[float, float, float]:
    """Means over the paper scenes of ``key``: fast (final stage), paper, GT hand."""
    return tuple(_mean(v) for v in _preset_values(rows, key))


#: Resamples and seed of :func:`ratio_interval` (fixed: the tables are deterministic).
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


def ratio_interval(
    fast: np.ndarray, paper: np.ndarray, level: float = 0.95
) -> tuple[float, float, float]:
    """Ratio of means ``mean(fast) / mean(paper)`` and its paired-bootstrap interval.

    The scenes are resampled with replacement (the same scenes for both presets, so the
    pairing is kept), :data:`BOOTSTRAP_RESAMPLES` times with :data:`BOOTSTRAP_SEED`; resamples
    whose paper mean is 0 are dropped. Returns ``(ratio, low, high)`` (percentile interval at
    ``level``); NaN where undefined (no scenes, paper mean 0).
    """
    fast, paper = np.asarray(fast, dtype=np.float64), np.asarray(paper, dtype=np.float64)
    n = len(fast)
    if n == 0 or len(paper) != n or paper.mean() == 0:
        return (float("nan"),) * 3
    idx = np.random.default_rng(BOOTSTRAP_SEED).integers(0, n, size=(BOOTSTRAP_RESAMPLES, n))
    num, den = fast[idx].mean(axis=1), paper[idx].mean(axis=1)
    ok = den != 0
    ratios = num[ok] / den[ok]
    lo, hi = np.quantile(ratios, [(1 - level) / 2, (1 + level) / 2])
    return float(fast.mean() / paper.mean()), float(lo), float(hi)


def preset_quality_table(report: dict) -> str:
    pr = _paper_rows(report)
    if not pr:
        return "(the paper preset did not run: --paper-scenes 0)"
    header = ["metric", "fast", "paper", "fast worse by > 5 %", "fast / paper (95 % CI)",
              "GT hand", "GT worse by > 5 %"]  # fmt: skip
    rows = []
    for k, hb in PRESET_METRICS:
        fv, pv, gv = _preset_values(pr, k)
        f, p, g = _mean(fv), _mean(pv), _mean(gv)
        r, lo, hi = ratio_interval(fv, pv)
        ci = f"{r:.2f} ({lo:.2f}-{hi:.2f})" if np.isfinite(r) else "n/a"
        rows.append([k, f"{f:.3f}", f"{p:.3f}", "yes" if _worse(f, p, hb) else "no", ci,
                     f"{g:.3f}", "yes" if _worse(g, p, hb) else "no"])  # fmt: skip
    return _table(header, rows)


#: Columns of :func:`preset_by_group_table`: (key, header, format).
GROUP_METRICS = (
    ("sd_cm", "S.D. cm", "{:.2f}"),
    ("iv_cm3", "I.V. cm3", "{:.1f}"),
    ("mpjpe_ra_cm", "MPJPE cm", "{:.2f}"),
)


def preset_by_group_table(report: dict, field: str = "grasp") -> str:
    """fast / paper / GT hand means per scene group (``field``: "grasp" or "kind").

    One row per group among the scenes the paper preset ran on (sorted by name), then "all";
    for each metric of :data:`GROUP_METRICS` the three means as ``fast / paper / GT``. Shows
    where the presets differ (e.g. which grasp types the paper preset holds by burying the hand).
    """
    pr = _paper_rows(report)
    if not pr:
        return "(the paper preset did not run: --paper-scenes 0)"
    groups = sorted({str(r[field]) for r in pr})
    header = [field, "scenes"] + [h + " fast / paper / GT" for _, h, _ in GROUP_METRICS]
    rows = []
    for name, sel in [(g, [r for r in pr if str(r[field]) == g]) for g in groups] + [("all", pr)]:
        cells = [name, str(len(sel))]
        for key, _, fmt in GROUP_METRICS:
            cells.append(" / ".join(fmt.format(m) for m in _preset_means(sel, key)))
        rows.append(cells)
    return _table(header, rows)


def _stage_values(report: dict, stage: str, key: str, where: str = "stages") -> np.ndarray:
    if where == "gt":
        return _values([r["object_input"]["gt_stages"][stage] for r in report["scenes"]], key)
    return _values([r["stages"][stage] for r in report["scenes"]], key)


def goals(report: dict) -> list[dict]:
    """The targets of the optimizer (from the paper's tables, docs/method.md section 4) with the
    measured ratio, its paired-bootstrap 95 % interval (:func:`ratio_interval`) and pass / miss
    (on the ratio)."""
    sc = report["scenes"]
    out = []

    def ratio_goal(goal: str, num: np.ndarray, den: np.ndarray, limit: float, unit: str):
        r, lo, hi = ratio_interval(num, den)
        ok = bool(np.isfinite(r) and r <= limit)
        val = (f"{r:.2f} (95 % CI {lo:.2f}-{hi:.2f}; {den.mean():.2f} -> {num.mean():.2f} {unit})"
               if np.isfinite(r) else "n/a")  # fmt: skip
        out.append({"goal": goal, "value": val, "met": ok, "ratio": r, "ci": [lo, hi]})

    sd = {k: _stage_values(report, k, "sd_cm") for k, _ in STAGE_ROWS}
    ratio_goal("S.D. full / no optimization <= 0.55 (-45 %)", sd["refine"], sd["initial"],
               0.55, "cm")  # fmt: skip
    keys = [k for k, _ in STAGE_ROWS]
    for prev, cur in zip(keys, keys[1:], strict=False):
        ratio_goal(f"S.D. {cur} / {prev} <= 1 (no stage raises it)", sd[cur], sd[prev], 1.0, "cm")
    own = {k: _stage_values(report, k, "sd_own_cm") for k, _ in STAGE_ROWS}
    if all(len(v) == len(sc) for v in own.values()):  # reports from before the column lack it
        ratio_goal("S.D. own camera: full / no optimization <= 0.55", own["refine"],
                   own["initial"], 0.55, "cm")  # fmt: skip
        for prev, cur in zip(keys, keys[1:], strict=False):
            ratio_goal(f"S.D. own camera: {cur} / {prev} <= 1", own[cur], own[prev], 1.0, "cm")
    for key, label in (("iv_cm3", "solid"), ("iv_obman_cm3", "ObMan")):
        ratio_goal(f"I.V. ({label}) refinement / contact alignment <= 0.45",
                   _stage_values(report, "refine", key), _stage_values(report, "contact", key),
                   0.45, "cm3")  # fmt: skip
    est = _values([r["object_input"]["estimator"] for r in sc], "mpjpe_ra_cm")
    ratio_goal("MPJPE after refinement / estimator's <= 1",
               _stage_values(report, "refine", "mpjpe_ra_cm"), est, 1.0, "cm")  # fmt: skip
    if all("gt_stages" in r["object_input"] for r in sc):
        gt_mp = _stage_values(report, "refine", "mpjpe_ra_cm", "gt")
        ratio_goal("true object: MPJPE after refinement / estimator's <= 0.8", gt_mp, est, 0.8,
                   "cm")  # fmt: skip
    pr = _paper_rows(report)
    if pr:
        f = _values([r["timings"]["fast"] for r in pr], "total").mean()
        p = _values([r["timings"]["paper"] for r in pr], "total").mean()
        out.append(
            {
                "goal": "fast >= 10x faster than paper",
                "value": f"{p / f:.1f}x",
                "met": bool(p / f >= 10),
            }
        )
        worse = [k for k, hb in PRESET_METRICS if _worse(*_preset_means(pr, k)[:2], hb)]
        out.append(
            {
                "goal": "fast: no metric worse than paper by > 5 %",
                "value": ", ".join(worse) or "none worse",
                "met": not worse,
            }
        )
    return out


def goals_table(report: dict) -> str:
    rows = [[g["goal"], g["value"], "met" if g["met"] else "MISSED"] for g in goals(report)]
    return _table(["goal (paper)", "measured", ""], rows)


def all_tables(report: dict) -> dict[str, str]:
    """Title -> Markdown table."""
    n, k = len(report["scenes"]), len(_paper_rows(report))
    return {
        f"Stage ablation ({n} scenes, snapshots of one fast run per scene)": stage_table(report),
        f"Loss ablation (stage 3 re-run from the contact snapshot, {n} scenes)": loss_table(report)
        if len(report["scenes"][0]["loss_ablation"]) > 1
        else "(not run)",
        "Reconstructed vs ground-truth object input": object_input_table(report),
        "Hand accuracy per stage (ratios to the estimator, 95 % CI)": hand_accuracy_table(report),
        "Object quality (MOHO convention, metres)": object_quality_table(report),
        f"Runtime per stage, seconds (paper preset on the first {k} scenes only)": runtime_table(
            report
        ),
        f"Quality fast vs paper (same {k} scenes)": preset_quality_table(report),
        f"fast vs paper by grasp type (same {k} scenes)": preset_by_group_table(report, "grasp"),
        f"fast vs paper by object kind (same {k} scenes)": preset_by_group_table(report, "kind"),
        "Goals from the paper's tables": goals_table(report),
    }


def tables_markdown(report: dict) -> str:
    parts = [f"## {title}\n\n{table}\n" for title, table in all_tables(report).items()]
    overrides = report.get("settings", {}).get("fast_overrides")
    if overrides:  # a variant: say so above its numbers
        given = ", ".join(f"`{k}={json.dumps(v)}`" for k, v in overrides.items())
        parts.insert(0, f"Fast preset with overrides: {given}.\n")
    return "\n".join(parts)


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------


def _stage_plot(report: dict, path: Path) -> None:
    from easyhoi.viz.plots import new_figure

    sc = report["scenes"]
    fig = new_figure(9, 3.4)
    labels = [lab.replace("+ ", "+").replace(" (full)", "") for _, lab in STAGE_ROWS]
    for i, (key, title) in enumerate(
        (
            ("sd_cm", "S.D. (cm)"),
            ("iv_cm3", "I.V. solid (cm3)"),
            ("mpjpe_ra_cm", "MPJPE rotation-aligned (cm)"),
        )
    ):
        ax = fig.add_subplot(1, 3, i + 1)
        vals = [_values([r["stages"][k] for r in sc], key) for k, _ in STAGE_ROWS]
        ax.bar(
            range(4),
            [v.mean() for v in vals],
            yerr=[v.std() for v in vals],
            capsize=3,
            color="#4c78a8",
        )
        ax.set_xticks(range(4), labels, rotation=30, ha="right", fontsize=8)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _runtime_plot(report: dict, path: Path) -> None:
    from easyhoi.viz.plots import new_figure

    pr = _paper_rows(report)
    if not pr:
        return
    stages = ("initial", "camera", "contact", "refine", "plausibility")
    fig = new_figure(6, 3.2)
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(len(stages))
    for j, preset in enumerate(("fast", "paper")):
        ys = [_values([r["timings"][preset] for r in pr], k).mean() for k in stages]
        ax.bar(x + (j - 0.5) * 0.4, ys, 0.4, label=preset)
    ax.set_xticks(x, stages)
    ax.set_ylabel("seconds")
    ax.set_yscale("log")
    ax.set_title(f"Seconds per stage ({len(pr)} scenes, 1 thread)", fontsize=10)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _gallery_png(gallery: list[dict], path: Path) -> None:
    from easyhoi.viz.plots import new_figure

    if not gallery:
        return
    cols = (("photo", "photo"), ("overlay", "result over the photo"), ("side", "side view"))
    fig = new_figure(3 * 2.6, len(gallery) * 2.8)
    for i, g in enumerate(gallery):
        for j, (k, title) in enumerate(cols):
            ax = fig.add_subplot(len(gallery), 3, 3 * i + j + 1)
            ax.imshow(g[k])
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(title if j else f"{g['title']}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def save_report(report: dict, out_dir) -> dict[str, Path]:
    """Write ``results.json``, ``tables.md``, ``stages.png``, ``runtime.png``, ``gallery.png``."""
    from easyhoi.io.atomic import atomic_write_bytes

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        k: out / n
        for k, n in (
            ("json", "results.json"),
            ("markdown", "tables.md"),
            ("stages", "stages.png"),
            ("runtime", "runtime.png"),
            ("gallery", "gallery.png"),
        )
    }
    data = {k: v for k, v in report.items() if k != "gallery"}
    data["goals"] = goals(report)
    atomic_write_bytes(paths["json"], json.dumps(data, indent=1, default=_json).encode())
    head = (
        f"# Synthetic benchmark\n\n{len(report['scenes'])} scenes, wall time "
        f"{report['wall_seconds']:.0f} s, load average before/after "
        f"{report['machine']['load_before']} / {report['machine']['load_after']}\n\n"
    )
    atomic_write_bytes(paths["markdown"], (head + tables_markdown(report)).encode())
    _stage_plot(report, paths["stages"])
    _runtime_plot(report, paths["runtime"])
    _gallery_png(report.get("gallery", []), paths["gallery"])
    return {k: p for k, p in paths.items() if p.exists()}


def _json(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
