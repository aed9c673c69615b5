"""The cheap paths of Camera, the input checks and project_faces give the validated results."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.checks import check_faces, check_finite
from easyhoi.errors import InvalidInputError
from easyhoi.render._common import project_faces
from easyhoi.structures import Camera


def _camera(dtype=torch.float64, grad=False) -> Camera:
    R = torch.tensor([[0.96, -0.28, 0.0], [0.28, 0.96, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    cam = Camera.from_focal((410.0, 395.0), 64, 48, R=R, t=[0.1, -0.05, 2.0], dtype=dtype)
    if grad:
        cam = replace(cam, K=cam.K.clone().requires_grad_(), t=cam.t.clone().requires_grad_())
    return cam


@pytest.mark.parametrize("field", ["K", "R", "t"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_camera_names_the_field(field, bad):
    cam = _camera()
    x = getattr(cam, field).clone()
    x.view(-1)[1] = bad
    with pytest.raises(InvalidInputError, match=f"Camera.{field} contains NaN"):
        replace(cam, **{field: x})


def test_bad_focal_and_size_still_raise():
    cam = _camera()
    K = cam.K.clone()
    K[1, 1] = -3.0
    with pytest.raises(InvalidInputError, match="focal lengths must be positive"):
        replace(cam, K=K)
    with pytest.raises(InvalidInputError, match="image size must be positive"):
        replace(cam, width=0)
    with pytest.raises(InvalidInputError, match="image size must be positive"):
        cam.resized(0, 10)
    with pytest.raises(InvalidInputError, match="Camera.K must have shape"):
        Camera(torch.eye(2), torch.eye(3), torch.zeros(3), 4, 4)


@pytest.mark.parametrize("grad", [False, True])
def test_resized_equals_the_validated_construction(grad):
    cam = _camera(grad=grad)
    for w, h in [(32, 24), (100, 75), (64, 48), (7, 300)]:
        fast = cam.resized(w, h)
        S = torch.diag(torch.tensor([w / 64, h / 48, 1.0], dtype=torch.float64))
        ref = Camera(S @ cam.K, cam.R, cam.t, w, h)
        assert (fast.width, fast.height) == (w, h)
        assert type(fast.width) is int and type(fast.height) is int
        assert torch.equal(fast.K, ref.K) and torch.equal(fast.R, ref.R)
        assert torch.equal(fast.t, ref.t)
        assert fast.K.requires_grad == grad
    # numpy integers take the validated path and come back as Python ints
    c = cam.resized(np.int64(32), np.int64(24))
    assert type(c.width) is int and torch.equal(c.K, cam.resized(32, 24).K)


def test_resized_gradient_reaches_the_source_camera():
    cam = _camera(grad=True)
    cam.resized(32, 24).K.sum().backward()
    assert torch.allclose(cam.K.grad[0], torch.tensor([0.5, 0.5, 0.5], dtype=torch.float64))
    assert torch.allclose(cam.K.grad[2], torch.ones(3, dtype=torch.float64))


def test_detach_and_to():
    cam = _camera(grad=True)
    d = cam.detach()
    assert not (d.K.requires_grad or d.R.requires_grad or d.t.requires_grad)
    assert torch.equal(d.K, cam.K.detach()) and torch.equal(d.t, cam.t.detach())
    assert d.detach() is d  # nothing to detach
    assert d.to(torch.float64) is d
    f = d.to(torch.float32)
    assert f.K.dtype == f.R.dtype == f.t.dtype == torch.float32
    assert torch.equal(f.K, d.K.float())
    huge = replace(d, t=torch.tensor([0.0, 0.0, 1e300], dtype=torch.float64))
    with pytest.raises(InvalidInputError, match="Camera.t contains NaN"):
        huge.to(torch.float32)  # overflows float32: still checked


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.float16, torch.int64])
def test_check_finite_matches_torch(dtype):
    x = torch.arange(12).reshape(3, 4).to(dtype)
    check_finite(x, "x")
    check_finite(x.t(), "x")  # non-contiguous views
    if dtype.is_floating_point:
        for bad in (math.nan, -math.inf):
            y = x.clone()
            y[2, 1] = bad
            with pytest.raises(InvalidInputError, match="y contains NaN"):
                check_finite(y, "y")
            with pytest.raises(InvalidInputError, match="y contains NaN"):
                check_finite(y.t(), "y")
            z = y.clone().requires_grad_()
            with pytest.raises(InvalidInputError):
                check_finite(z, "z")


def test_check_faces_range():
    f = torch.tensor([[0, 1, 2], [2, 3, 1]])
    check_faces(f, 4)
    check_faces(f.numpy(), 4)
    with pytest.raises(InvalidInputError, match=r"\[0, 3\] but there are only 3"):
        check_faces(f, 3)
    with pytest.raises(InvalidInputError, match=r"\[-1, 3\]"):
        check_faces(torch.tensor([[0, 1, 3], [-1, 2, 1]]), 4)


def _naive_project(verts, faces, camera, near):
    """The definition: gather every corner, drop faces with a corner before ``near``/non-finite."""
    B, F = verts.shape[0], faces.shape[0]
    uv, z = camera.project(verts)
    tri_uv = uv[:, faces].reshape(B * F, 3, 2)
    tri_z = z[:, faces].reshape(B * F, 3)
    ok = (tri_z >= near).all(dim=1) & torch.isfinite(tri_uv).all(dim=(1, 2))
    keep = ok.nonzero().squeeze(1)
    return tri_uv[keep], tri_z[keep], keep


@pytest.mark.parametrize("drop", [False, True])
def test_project_faces_matches_the_definition_with_gradients(drop):
    g = torch.Generator().manual_seed(3)
    verts = torch.randn(2, 30, 3, generator=g, dtype=torch.float64) * 0.3
    if drop:  # some vertices behind the near plane: their faces go
        verts[0, :4, 2] = -2.0
        verts[1, 7, 2] = -2.1
    faces = torch.randint(0, 30, (50, 3), generator=g)
    cam = _camera(grad=True)
    grads = []
    outs = []
    for fn in (project_faces, _naive_project):
        v = verts.clone().requires_grad_()
        cam.K.grad = None
        tri_uv, tri_z, keep = fn(v, faces, cam, 0.5)
        (tri_uv.square().sum() + (tri_z * 0.7).sum()).backward()
        outs.append((tri_uv.detach(), tri_z.detach(), keep))
        grads.append((v.grad.clone(), cam.K.grad.clone()))
    (a_uv, a_z, a_keep), (b_uv, b_z, b_keep) = outs
    assert torch.equal(a_keep, b_keep) and torch.equal(a_uv, b_uv) and torch.equal(a_z, b_z)
    assert (a_keep.shape[0] < 100) == drop
    assert torch.equal(grads[0][0], grads[1][0]) and torch.equal(grads[0][1], grads[1][1])


def test_camera_stage_parameters_give_the_validated_camera():
    from easyhoi.optim.camera import _CameraParams

    params = _CameraParams(_camera(), torch.tensor([0.02, 0.01, 1.9]), 0.3, optimise_focal=True)
    g = torch.Generator().manual_seed(4)
    with torch.no_grad():
        for p in params.tensors():
            p.copy_(0.1 * torch.randn(p.shape, generator=g, dtype=p.dtype))
    cam = params.camera()
    ref = Camera(cam.K, cam.R, cam.t, cam.width, cam.height)  # the validating constructor
    for f in ("K", "R", "t"):
        assert torch.equal(getattr(cam, f), getattr(ref, f))
    assert (cam.width, cam.height) == (64, 48) and cam.fx > 0 and cam.fy > 0
    cam.project(torch.tensor([[0.0, 0.1, 0.5]], dtype=torch.float64))[0].sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in params.tensors())
    assert params.delta.grad.abs().sum() > 0


def test_project_without_near_zero_depths_equals_the_selection_with_gradients():
    from easyhoi.structures import Camera

    torch.manual_seed(0)
    K = torch.tensor([[300.0, 2.0, 64.0], [0.0, 310.0, 60.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    cam = Camera(
        K,
        torch.eye(3, dtype=torch.float64),
        torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64),
        128,
        120,
    )
    pts = (torch.randn(50, 3, dtype=torch.float64) * 0.1).requires_grad_(True)
    uv, z = cam.project(pts)
    pc = pts @ cam.R.T + cam.t
    x, y, zz = pc.unbind(-1)
    zs = torch.where(zz.abs() < 1e-9, 1e-9, zz)
    ref = torch.stack([300.0 * x / zs + 2.0 * y / zs + 64.0, 310.0 * y / zs + 60.0], dim=-1)
    assert torch.equal(uv, ref) and torch.equal(z, zz)
    w = torch.randn_like(uv)
    (g,) = torch.autograd.grad((uv * w).sum(), pts)
    (g_ref,) = torch.autograd.grad((ref * w).sum(), pts)
    assert torch.equal(g, g_ref)
    # a point at the camera's depth plane still gets the floor
    at_plane = torch.tensor([[0.01, 0.02, -0.5]], dtype=torch.float64)
    uv0, _ = cam.project(at_plane)
    assert torch.isfinite(uv0).all()
