"""How the hand estimator's error splits into its size and its articulation.

The synthetic benchmark's estimator hand ("hamer" perturbation, :mod:`easyhoi.synth.perturb`)
carries an articulation error and a size error (shape coefficient 0). MPJPE with the global
rotation and the root removed (the benchmark's ``mpjpe_ra_cm``) still sees the size. The
optimizer keeps the hand's shape: a single photo does not tell a hand's size from its distance
(a larger hand farther away projects the same), so the size part is a floor under every stage.

For the benchmark's scenes of ``--seed`` (``easyhoi.synth.benchmark.scene_specs``, built as
``easyhoi bench`` builds them) this prints the mean MPJPE of:

* ``estimator``: the estimator's hand;
* ``size only``: the true articulation with the estimator's shape;
* ``articulation only``: the estimator's articulation with the true shape;
* ``hinge joints straightened``: the estimator's articulation with the non-flexion rotation of
  the fingers' middle and distal joints removed (what a prior that makes those joints pure
  hinges could take away at most), with the true shape;
* ``estimator, hinges straightened``: the same with the estimator's shape and rotation.

Usage::

    python benchmarks/hand_error_split.py --seed 42 --scenes 20
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def _keypoints(model, like, pose, betas) -> np.ndarray:
    """The 21 keypoints (the benchmark's MPJPE uses them) of ``like`` with ``pose``, ``betas``,
    posed as the benchmark poses its hands (:func:`easyhoi.synth.evaluate._hand_out`)."""
    from easyhoi.structures import HandParams
    from easyhoi.synth.evaluate import _hand_out

    q = HandParams(like.global_orient, like.transl, pose.to(like.pose.dtype), betas, like.side)
    return _hand_out(model, q)[1]


def split(seed: int, n: int) -> dict[str, float]:
    from easyhoi import metrics
    from easyhoi.hand.regions import DIGIT_JOINTS, flexion_axes
    from easyhoi.synth.benchmark import BenchmarkSettings, scene_specs
    from easyhoi.synth.scene import make_scene

    hinges = [DIGIT_JOINTS[d][r] - 1 for d in ("index", "middle", "ring", "pinky") for r in (1, 2)]
    rows: dict[str, list[float]] = {
        "estimator": [],
        "size only": [],
        "articulation only": [],
        "hinge joints straightened": [],
        "estimator, hinges straightened": [],
    }
    bench = BenchmarkSettings()
    for scene_seed, kind, grasp in scene_specs(n, seed):
        sc = make_scene(scene_seed, kind, grasp, image_size=bench.image_size, hold=bench.hold)
        model = sc.hand_model
        gt = sc.hand_params
        est = sc.to_hoi_input(bench.perturbation, seed=scene_seed).hand_params
        axes = torch.as_tensor(flexion_axes(model), dtype=torch.float64)
        truth = _keypoints(model, gt, gt.pose, gt.betas)
        theta = est.pose.reshape(15, 3).double()
        flex = (theta * axes).sum(-1)
        straight = theta.clone()
        straight[hinges] = flex[hinges, None] * axes[hinges]
        straight = straight.reshape(1, 45)
        preds = {
            "estimator": _keypoints(model, est, est.pose, est.betas),
            "size only": _keypoints(model, gt, gt.pose, est.betas),
            "articulation only": _keypoints(model, gt, est.pose, gt.betas),
            "hinge joints straightened": _keypoints(model, gt, straight, gt.betas),
            "estimator, hinges straightened": _keypoints(model, est, straight, est.betas),
        }
        for k, kp in preds.items():
            rows[k].append(metrics.mpjpe(kp, truth, align="rotation"))
    return {k: float(np.mean(v)) for k, v in rows.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--scenes", type=int, default=20)
    args = ap.parse_args(argv)
    out = split(args.seed, args.scenes)
    base = out["estimator"]
    for k, v in out.items():
        print(f"{k:32s} MPJPE {v:.3f} cm  ({v / base:.2f} of the estimator's)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
