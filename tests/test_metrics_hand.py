"""MPJPE / MPVPE against naive references and known transforms."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.transforms import random_rotations
from easyhoi.metrics.hand import align_hands, mpjpe, mpvpe
from tests.helpers import assert_close


def _joints(batch=4, n=21, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.05, size=(batch, n, 3))  # metres


def _rotations(batch, seed=0) -> np.ndarray:
    return random_rotations(batch, torch.Generator().manual_seed(seed)).numpy()


def _naive(pred, gt) -> float:
    total = 0.0
    for b in range(pred.shape[0]):
        s = 0.0
        for j in range(pred.shape[1]):
            s += np.sqrt(sum((pred[b, j, k] - gt[b, j, k]) ** 2 for k in range(3)))
        total += s / pred.shape[1]
    return 100.0 * total / pred.shape[0]


def test_no_alignment_matches_naive_loop():
    gt = _joints()
    pred = gt + np.random.default_rng(1).normal(scale=0.01, size=gt.shape)
    assert mpjpe(pred, gt) == pytest.approx(_naive(pred, gt), rel=1e-12)
    assert mpvpe(pred, gt) == pytest.approx(_naive(pred, gt), rel=1e-12)
    per = mpjpe(pred, gt, reduction="none")
    assert per.shape == (4,)
    assert_close(per.mean(), _naive(pred, gt), atol=1e-12)
    # torch input and unbatched input
    assert mpjpe(torch.from_numpy(pred), torch.from_numpy(gt)) == pytest.approx(_naive(pred, gt))
    assert mpjpe(pred[0], gt[0]) == pytest.approx(_naive(pred[:1], gt[:1]))


def test_constant_offset_is_its_length_in_cm():
    gt = _joints()
    pred = gt + np.array([0.03, 0.0, 0.04])  # 5 cm
    assert mpjpe(pred, gt) == pytest.approx(5.0)
    assert mpjpe(pred, gt, align="root") == pytest.approx(0.0, abs=1e-12)
    assert mpvpe(pred, gt, align="root") == pytest.approx(0.0, abs=1e-12)


def test_rigid_motion_vanishes_under_rotation_alignment_only():
    gt = _joints()
    R = _rotations(4)
    pred = np.einsum("bij,bnj->bni", R, gt) + np.array([0.1, -0.2, 0.3])
    assert mpjpe(pred, gt, align="root") > 1.0
    assert mpjpe(pred, gt, align="rotation") == pytest.approx(0.0, abs=1e-10)
    assert mpjpe(pred, gt, align="procrustes") == pytest.approx(0.0, abs=1e-10)


def test_rotation_is_about_the_root_without_translation_refit():
    # pred = gt with a 1 cm offset on every non-root joint along +x: rotation about the root
    # cannot remove a uniform offset, so the aligned error stays close to that offset; the
    # optimal rotation is the identity for a point cloud symmetric about the root.
    gt = np.zeros((1, 7, 3))
    axes = np.eye(3) * 0.05
    gt[0, 1:4], gt[0, 4:7] = axes, -axes
    pred = gt.copy()
    pred[0, 1:] += [0.01, 0.0, 0.0]
    p, g = align_hands(pred, gt, "rotation")
    assert_close(p[0, 0], [0, 0, 0], atol=1e-12)
    assert mpjpe(pred, gt, align="rotation") == pytest.approx(6.0 / 7.0, rel=1e-6)
    assert mpjpe(pred, gt, align="procrustes") < 0.3


def test_similarity_vanishes_under_procrustes():
    gt = _joints()
    R = _rotations(4, seed=3)
    scale = np.array([0.5, 1.0, 1.5, 2.0])[:, None, None]
    pred = scale * np.einsum("bij,bnj->bni", R, gt) + np.array([0.1, 0.0, -0.05])
    assert mpjpe(pred, gt, align="rotation") > 0.1
    assert mpjpe(pred, gt, align="procrustes") == pytest.approx(0.0, abs=1e-10)
    assert mpvpe(pred, gt, align="procrustes") == pytest.approx(0.0, abs=1e-10)


def test_reflection_is_not_used_by_procrustes():
    gt = _joints(batch=1)
    pred = gt * np.array([-1.0, 1.0, 1.0])  # mirror image: no proper rotation undoes it
    assert mpjpe(pred, gt, align="procrustes") > 0.5


def test_mpvpe_root_arguments():
    gt = _joints(batch=2, n=50)
    pred = gt + 0.02
    wrist = np.zeros((2, 3))
    assert mpvpe(pred, gt, align="root", pred_root=wrist + 0.02, gt_root=wrist) == pytest.approx(0)
    assert mpvpe(pred, gt, align="root", pred_root=wrist, gt_root=wrist) == pytest.approx(
        100 * 0.02 * np.sqrt(3)
    )


def test_bad_inputs():
    gt = _joints()
    with pytest.raises(InvalidInputError, match="same shape"):
        mpjpe(gt[:, :20], gt)
    with pytest.raises(InvalidInputError, match="align"):
        mpjpe(gt, gt, align="scale")
    bad = gt.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        mpjpe(bad, gt)
    with pytest.raises(InvalidInputError, match=r"\(B, N, 3\)"):
        mpjpe(gt[..., :2], gt[..., :2])
    with pytest.raises(InvalidInputError, match="pred_root"):
        mpvpe(gt, gt, align="root", pred_root=np.zeros((3, 3)), gt_root=np.zeros(3))
    with pytest.raises(InvalidInputError, match="reduction"):
        mpjpe(gt, gt, reduction="sum")
