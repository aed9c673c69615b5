"""Loss terms: values against naive loops, gradients by gradcheck, Sinkhorn behaviour."""

from __future__ import annotations

import math

import pytest
import torch

from easyhoi.errors import InvalidInputError
from easyhoi.optim.losses import (
    contact_loss,
    mask_mse,
    penetration_loss,
    pose_reg_loss,
    sinkhorn_mask_loss,
    soft_iou_loss,
)
from tests.helpers import ATOL64, assert_close

D = torch.float64


def _naive_iou_loss(a, b, eps=1e-6):
    inter = sa = sb = 0.0
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            inter += float(a[i, j]) * float(b[i, j])
            sa += float(a[i, j])
            sb += float(b[i, j])
    return 1.0 - inter / (sa + sb - inter + eps)


def _square(h, w, top, left, size, dtype=D):
    m = torch.zeros(h, w, dtype=dtype)
    m[top : top + size, left : left + size] = 1.0
    return m


# ----------------------------------------------------------------------------------------------
# soft IoU / MSE
# ----------------------------------------------------------------------------------------------


def test_soft_iou_matches_naive_loop_and_batches():
    g = torch.Generator().manual_seed(1)
    a = torch.rand(3, 7, 9, generator=g, dtype=D)
    b = (torch.rand(3, 7, 9, generator=g, dtype=D) > 0.5).to(D)
    per = soft_iou_loss(a, b, reduction="none")
    for k in range(3):
        assert_close(per[k], _naive_iou_loss(a[k], b[k]), atol=ATOL64)
    assert_close(soft_iou_loss(a, b), per.mean(), atol=ATOL64)
    assert_close(soft_iou_loss(a, b, reduction="sum"), per.sum(), atol=ATOL64)
    assert_close(soft_iou_loss(a[1], b[1]), per[1], atol=ATOL64)


def test_soft_iou_known_answers():
    t = _square(10, 10, 0, 0, 4)
    assert_close(soft_iou_loss(t, t), 0.0, atol=1e-7)  # identical: 1 - 16/(16+eps)
    assert_close(soft_iou_loss(t, _square(10, 10, 5, 5, 4)), 1.0, atol=ATOL64)  # disjoint
    # half overlap: I = 8, U = 24 -> 1 - 1/3
    assert_close(soft_iou_loss(t, _square(10, 10, 0, 2, 4)), 2.0 / 3.0, atol=1e-7)
    # bool target accepted; two empty masks give 1 (documented)
    assert_close(soft_iou_loss(t, t.bool()), 0.0, atol=1e-7)
    z = torch.zeros(4, 4, dtype=D)
    assert_close(soft_iou_loss(z, z), 1.0, atol=ATOL64)


def test_soft_iou_gradcheck():
    g = torch.Generator().manual_seed(2)
    a = torch.rand(2, 5, 6, generator=g, dtype=D, requires_grad=True)
    b = torch.rand(2, 5, 6, generator=g, dtype=D)
    assert torch.autograd.gradcheck(lambda x: soft_iou_loss(x, b), (a,))
    assert torch.autograd.gradcheck(lambda x: mask_mse(x, b), (a,))


def test_mask_mse_matches_naive():
    g = torch.Generator().manual_seed(3)
    a = torch.rand(4, 5, generator=g, dtype=D)
    b = torch.rand(4, 5, generator=g, dtype=D)
    ref = sum(float(a[i, j] - b[i, j]) ** 2 for i in range(4) for j in range(5)) / 20
    assert_close(mask_mse(a, b), ref, atol=ATOL64)


def test_mask_shape_errors():
    with pytest.raises(InvalidInputError, match="target has shape"):
        soft_iou_loss(torch.zeros(4, 4), torch.zeros(4, 5))
    with pytest.raises(InvalidInputError, match=r"\(H, W\) or \(B, H, W\)"):
        soft_iou_loss(torch.zeros(4), torch.zeros(4))
    with pytest.raises(InvalidInputError, match="reduction"):
        soft_iou_loss(torch.zeros(4, 4), torch.zeros(4, 4), reduction="max")


# ----------------------------------------------------------------------------------------------
# Sinkhorn
# ----------------------------------------------------------------------------------------------


def test_sinkhorn_two_points_is_half_squared_distance():
    # single-pixel masks on a 16x16 image with grid=16: Diracs at pixel centres / 16
    a = torch.zeros(16, 16, dtype=D)
    b = torch.zeros(16, 16, dtype=D)
    a[2, 1] = 1.0
    b[10, 13] = 1.0
    dx, dy = (13 - 1) / 16, (10 - 2) / 16
    loss = sinkhorn_mask_loss(a, b, grid=16, blur=0.05, scaling=0.7)
    assert_close(loss, 0.5 * (dx * dx + dy * dy), atol=2e-3)
    # pooling 32x32 -> 16x16 merges 2x2 blocks: the same Diracs, centres at block centres
    a2 = torch.zeros(32, 32, dtype=D)
    a2[4:6, 2:4] = 1.0
    b2 = torch.zeros(32, 32, dtype=D)
    b2[20:22, 26:28] = 1.0
    assert_close(sinkhorn_mask_loss(a2, b2, grid=16, blur=0.05, scaling=0.7), loss, atol=1e-6)
    same = sinkhorn_mask_loss(b, b, grid=16, blur=0.05, scaling=0.7)
    assert float(same) < 1e-3  # only the MASS_EPS floor spread over the grid


def test_sinkhorn_decreases_as_square_approaches_target():
    target = _square(32, 32, 12, 22, 6, dtype=torch.float32)
    values = []
    for left in (0, 3, 6, 9, 12, 15, 18, 22):
        pred = _square(32, 32, 12, left, 6, torch.float32)
        values.append(float(sinkhorn_mask_loss(pred, target, grid=16)))
    assert all(v1 < v0 for v0, v1 in zip(values, values[1:], strict=False)), values
    assert values[-1] < 1e-3 and values[0] > 0.1
    # translation by d (no overlap): W2^2/2 = d^2/2 in normalised units
    d = 22 / 32
    assert abs(values[0] - 0.5 * d * d) < 0.02


def test_sinkhorn_gradient_pulls_disjoint_mass_toward_target():
    # pred square on the left, target on the right, no overlap: IoU has no useful gradient,
    # the Sinkhorn gradient must favour pixels on the target side.
    pred = _square(32, 32, 12, 2, 8).requires_grad_(True)
    target = _square(32, 32, 12, 22, 8)
    iou_grad = torch.autograd.grad(soft_iou_loss(pred, target), pred)[0]
    assert float(iou_grad[:, :20].abs().max()) == 0.0  # IoU is blind away from the target
    g = torch.autograd.grad(sinkhorn_mask_loss(pred, target, grid=16), pred)[0]
    assert torch.isfinite(g).all()
    # a pixel just right of the square (toward the target) lowers the loss when added,
    # a pixel just left of it raises it
    assert float(g[15, 11]) < 0 < float(g[15, 0])
    # along the row through both squares the gradient decreases toward the target
    row = g[15, 0:24]
    assert bool((row[1:] <= row[:-1] + 1e-12).all())
    # a small gradient step moves the mass centroid toward the target and lowers the loss
    step = (pred - 2e-3 * g / g.abs().max() * 50).clamp(0, 1).detach()
    cols = torch.arange(32, dtype=D)
    assert float((step.sum(0) * cols).sum() / step.sum()) > float(
        (pred.detach().sum(0) * cols).sum() / pred.detach().sum()
    )
    assert float(sinkhorn_mask_loss(step, target, grid=16)) < float(
        sinkhorn_mask_loss(pred.detach(), target, grid=16)
    )


def test_sinkhorn_gradient_matches_finite_difference():
    g = torch.Generator().manual_seed(4)
    pred = torch.rand(16, 16, generator=g, dtype=D).requires_grad_(True)
    target = _square(16, 16, 3, 8, 6)
    kw = dict(grid=8, blur=0.05, scaling=0.95)
    grad = torch.autograd.grad(sinkhorn_mask_loss(pred, target, **kw), pred)[0]
    direction = torch.randn(16, 16, generator=g, dtype=D)
    h = 1e-4
    with torch.no_grad():
        fd = (
            sinkhorn_mask_loss(pred + h * direction, target, **kw)
            - sinkhorn_mask_loss(pred - h * direction, target, **kw)
        ) / (2 * h)
    assert math.isclose(
        float((grad * direction).sum()), float(fd.detach()), rel_tol=0.05, abs_tol=1e-6
    )


def test_sinkhorn_batch_and_non_square_and_empty():
    a = torch.stack([_square(10, 20, 1, 1, 3), _square(10, 20, 5, 15, 3)])
    b = torch.stack([_square(10, 20, 5, 15, 3), _square(10, 20, 5, 15, 3)])
    per = sinkhorn_mask_loss(a, b, grid=16, reduction="none")  # 10x16 cells (short side)
    assert per.shape == (2,) and float(per[0]) > 0.05 and float(per[1]) < 1e-3
    # x spans [0, 1] (long side), y [0, 0.5]: the shift (14, 4) px -> (0.7, 0.2)
    assert abs(float(per[0]) - 0.5 * (0.7**2 + 0.2**2)) < 0.02
    assert_close(sinkhorn_mask_loss(a, b, grid=16), per.mean(), atol=1e-9)
    # an empty prediction is a uniform distribution: finite loss and gradient
    z = torch.zeros(10, 20, dtype=D, requires_grad=True)
    val = sinkhorn_mask_loss(z, b[0], grid=16)
    (gz,) = torch.autograd.grad(val, z)
    assert torch.isfinite(val) and torch.isfinite(gz).all() and float(gz[6, 16]) < 0
    with pytest.raises(InvalidInputError, match="target mask is empty"):
        sinkhorn_mask_loss(b[0], torch.zeros(10, 20, dtype=D))
    with pytest.raises(InvalidInputError, match="grid"):
        sinkhorn_mask_loss(b[0], b[0], grid=0)


# ----------------------------------------------------------------------------------------------
# 3D terms
# ----------------------------------------------------------------------------------------------


def test_penetration_matches_naive_loop():
    g = torch.Generator().manual_seed(5)
    d = torch.randn(3, 50, generator=g, dtype=D) * 0.01
    for thr in (0.0, -5e-3):
        ref = []
        for b in range(3):
            s = 0.0
            for v in range(50):
                if float(d[b, v]) < thr:
                    s += max(0.0, -float(d[b, v]))
            ref.append(s / 50)
        assert_close(penetration_loss(d, threshold=thr, reduction="none"), ref, atol=ATOL64)
        assert_close(penetration_loss(d, threshold=thr), sum(ref) / 3, atol=ATOL64)
    assert_close(penetration_loss(torch.tensor([0.1, -0.2, -0.4, 0.3])), 0.15, atol=1e-7)


def test_contact_matches_naive_loop():
    g = torch.Generator().manual_seed(6)
    d = torch.randn(2, 40, generator=g, dtype=D) * 0.02
    for md in (None, 0.01):
        ref = []
        for b in range(2):
            s = 0.0
            for v in range(40):
                x = float(d[b, v])
                if x > 0 and (md is None or x < md):
                    s += x
            ref.append(s)
        assert_close(contact_loss(d, max_distance=md, reduction="none"), ref, atol=ATOL64)
    with pytest.raises(InvalidInputError, match="max_distance"):
        contact_loss(d, max_distance=0.0)
    # one radius per vertex
    radii = torch.where(torch.arange(40) % 3 == 0, 0.03, 0.01).to(D)
    ref = [sum(float(d[b, v]) for v in range(40) if 0 < float(d[b, v]) < float(radii[v]))
           for b in range(2)]  # fmt: skip
    uniform = contact_loss(d, max_distance=0.01, reduction="none")
    assert (torch.as_tensor(ref, dtype=D) > uniform + 1e-3).all()  # the wider radii count
    assert_close(contact_loss(d, max_distance=radii, reduction="none"), ref, atol=ATOL64)
    with pytest.raises(InvalidInputError, match="max_distance"):
        contact_loss(d, max_distance=radii[:10])
    with pytest.raises(InvalidInputError, match="max_distance"):
        contact_loss(d, max_distance=radii - 0.02)


def test_pose_reg_matches_naive_and_errors():
    g = torch.Generator().manual_seed(7)
    th = torch.randn(2, 45, generator=g, dtype=D)
    th0 = torch.randn(2, 45, generator=g, dtype=D)
    ref = [sum(abs(float(th[b, i] - th0[b, i])) for i in range(45)) for b in range(2)]
    assert_close(pose_reg_loss(th, th0, reduction="none"), ref, atol=ATOL64)
    assert_close(pose_reg_loss(th, th0[0]), (sum(abs(th - th0[0])).sum() / 2), atol=ATOL64)
    with pytest.raises(InvalidInputError, match="same P"):
        pose_reg_loss(th, th0[:, :10])


def test_3d_terms_gradcheck():
    g = torch.Generator().manual_seed(8)
    # keep values away from the kinks (0, thresholds) so finite differences are valid
    d = torch.randn(2, 30, generator=g, dtype=D) * 0.05
    d = torch.where(d.abs() < 0.012, d.sign() * 0.02, d).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: penetration_loss(x), (d,))
    assert torch.autograd.gradcheck(lambda x: penetration_loss(x, threshold=-5e-3), (d,))
    assert torch.autograd.gradcheck(lambda x: contact_loss(x), (d,))
    assert torch.autograd.gradcheck(lambda x: contact_loss(x, max_distance=0.1), (d,))
    radii = torch.full((30,), 0.1, dtype=D)
    radii[::2] = 0.04
    assert torch.autograd.gradcheck(lambda x: contact_loss(x, max_distance=radii), (d,))
    th0 = torch.randn(2, 45, generator=g, dtype=D)
    th = th0 + torch.where(torch.rand(2, 45, generator=g, dtype=D) > 0.5, 0.1, -0.1)
    th.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: pose_reg_loss(x, th0), (th,))


def test_penetration_gradient_is_minus_one_over_v_for_counted_vertices():
    d = torch.tensor([[0.1, -0.002, -0.01, -0.3]], dtype=D, requires_grad=True)
    (g,) = torch.autograd.grad(penetration_loss(d, threshold=-5e-3), d)
    assert_close(g, [[0.0, 0.0, -0.25, -0.25]], atol=ATOL64)
