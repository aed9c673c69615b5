"""Metrics of a result folder, alone (plausibility) and against ground-truth files.

Everything is read from what ``easyhoi reconstruct`` writes (``hand.ply``, ``object.ply`` and
``result.json``, metres in the metric object frame), so results of older runs or other machines
can be evaluated without re-running anything.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from easyhoi.errors import InvalidInputError


def _load_result(folder: Path) -> tuple[dict, object, object]:
    from easyhoi.geometry.mesh import load_mesh

    folder = Path(folder)
    for name in ("result.json", "hand.ply", "object.ply"):
        if not (folder / name).is_file():
            raise InvalidInputError(
                f"{folder} is not a result folder: {name} is missing (expected the output of "
                "`easyhoi reconstruct`)"
            )
    try:
        info = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"cannot read {folder / 'result.json'}: {exc}") from None
    return info, load_mesh(folder / "hand.ply"), load_mesh(folder / "object.ply")


def evaluate_result(
    folder: str | Path,
    gt_object: str | Path | None = None,
    gt_hand: str | Path | None = None,
    *,
    align: str = "translation_scale",
    simulate: bool = True,
    sim_steps: int = 35,
    n_samples: int = 30000,
    seed: int = 0,
) -> dict:
    """Metrics of one result folder (lengths in cm, volumes in cm^3).

    Args:
        folder: a folder written by ``easyhoi reconstruct`` (``result.json``, ``hand.ply``,
            ``object.ply``).
        gt_object: ground-truth object mesh in metres (any frame: it is aligned, see ``align``).
        gt_hand: ground-truth hand mesh in metres with the same topology as ``hand.ply`` (the same
            hand model), for MPVPE (root-aligned and Procrustes-aligned).
        align: object alignment before C.D./F-score: "translation_scale" (MOHO/EasyHOI),
            "rigid" or "none".
        simulate: run the simulation-displacement metric (PyBullet), gravity along +y of the
            result's camera.
        sim_steps: simulation steps (35 as in ObMan's code, 1000 as in the paper's text).
    Returns:
        a JSON-ready dictionary.
    """
    from easyhoi.metrics import (
        chamfer_fscore,
        in_contact,
        intersection_volume,
        mpvpe,
        penetration_depth,
        simulation_displacement,
    )

    info, hand, obj = _load_result(Path(folder))
    out: dict = {"folder": str(folder), "units": {"length": "cm", "volume": "cm^3"}}
    out["penetration_depth_cm"] = float(penetration_depth(hand, obj))
    out["intersection_volume_cm3"] = {
        "solid": float(intersection_volume(hand, obj, method="solid")),
        "obman": float(intersection_volume(hand, obj, method="obman")),
    }
    out["in_contact_5mm"] = bool(in_contact(hand, obj))
    if simulate:
        R = np.asarray(info["camera"]["R"], dtype=np.float64)
        gravity = R.T @ np.array([0.0, 1.0, 0.0])  # image-down in the object frame
        sim = simulation_displacement(hand, obj, steps=sim_steps, gravity_dir=tuple(gravity))
        out["simulation_displacement_cm"] = float(sim.displacement)
        out["simulation_steps"] = int(sim_steps)
    if gt_object is not None:
        from easyhoi.geometry.mesh import load_mesh

        om = chamfer_fscore(obj, load_mesh(gt_object), n_samples=n_samples, seed=seed, align=align)
        out["object"] = {
            "chamfer_moho": float(om.chamfer),
            "f@5mm": float(om.f_at(5)),
            "f@10mm": float(om.f_at(10)),
            "alignment": align,
        }
    if gt_hand is not None:
        from easyhoi.geometry.mesh import load_mesh

        gh = load_mesh(gt_hand)
        if len(gh.vertices) != len(hand.vertices):
            raise InvalidInputError(
                f"ground-truth hand has {len(gh.vertices)} vertices but the result's hand has "
                f"{len(hand.vertices)}: MPVPE needs the same hand model (topology)"
            )
        p, g = np.asarray(hand.vertices)[None], np.asarray(gh.vertices)[None]
        out["hand"] = {
            "mpvpe_cm": float(mpvpe(p, g, align="none")),
            "mpvpe_root_cm": float(mpvpe(p, g, align="root")),
            "mpvpe_procrustes_cm": float(mpvpe(p, g, align="procrustes")),
        }
    return out
