"""Soft silhouettes: culled renderer vs the dense reference, gradients, culling, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.render import soft
from easyhoi.render._common import bbox_pairs, project_faces
from easyhoi.render.reference import dense_soft_silhouette
from easyhoi.render.soft import cull_margin, sigma_from_ndc, soft_log_visibility, soft_silhouette
from easyhoi.structures import Camera
from tests.helpers import assert_close

F64 = torch.float64
BACKENDS = ["numba", "torch"]


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Run a test with each kernel backend, restoring the automatic choice afterwards."""
    soft.set_backend(request.param)
    yield request.param
    soft.set_backend("auto")


def _sphere(sub=2, radius=1.0, dtype=F64):
    m = trimesh.creation.icosphere(sub, radius=radius)
    v = torch.tensor(m.vertices * [1.0, 0.8, 0.9], dtype=dtype)
    return v, torch.tensor(m.faces)


def _cam(w=40, h=32, focal=30.0, dtype=F64):
    return Camera.look_at((0.4, 0.3, -3.0), (0, 0, 0), focal=focal, width=w, height=h, dtype=dtype)


def test_culled_matches_dense_value_and_gradient(backend):
    v, f = _sphere()
    cam = _cam()
    w = torch.randn(cam.height, cam.width, dtype=F64)
    for sigma in (0.5, 2.0):
        va = v.clone().requires_grad_(True)
        vb = v.clone().requires_grad_(True)
        a = soft_silhouette(va, f, cam, sigma=sigma)
        b = dense_soft_silhouette(vb, f, cam, sigma=sigma)
        assert a.shape == (cam.height, cam.width)
        assert 50 < float((a > 0.5).sum()) < a.numel()  # the sphere is in view, not filling it
        assert_close(a, b, atol=1e-5)
        (ga,) = torch.autograd.grad((a * w).sum(), va)
        (gb,) = torch.autograd.grad((b * w).sum(), vb)
        assert float(gb.abs().max()) > 1.0
        assert_close(ga, gb, atol=1e-5)


def test_culled_matches_dense_camera_gradient_float32(backend):
    v, f = _sphere(dtype=torch.float32)
    K = torch.tensor([[30.0, 0, 20], [0, 32.0, 16], [0, 0, 1]], requires_grad=True)
    t = torch.tensor([0.1, -0.05, 3.0], requires_grad=True)
    R = torch.eye(3, requires_grad=True)
    cam = Camera(K, R, t, 40, 32)
    w = torch.randn(32, 40)
    grads = []
    for fn in (soft_silhouette, dense_soft_silhouette):
        out = fn(v, f, cam, sigma=1.0)
        grads.append(torch.autograd.grad((out * w).sum(), (K, R, t)))
    for ga, gb in zip(*grads, strict=True):
        assert_close(ga, gb, atol=1e-3, rtol=1e-4)  # float32 sums over ~1k pixels


def test_gradcheck_vertices_and_camera(backend):
    v = torch.tensor(
        [[0.0, 0.0, 0.3], [0.9, 0.1, 0.0], [0.1, 0.8, 0.1], [-0.6, -0.5, 0.2]], dtype=F64
    )
    f = torch.tensor([[0, 1, 2], [0, 3, 1], [0, 2, 3]])
    K = torch.tensor([[6.0, 0.0, 5.1], [0.0, 6.5, 4.2], [0.0, 0.0, 1.0]], dtype=F64)
    R = torch.eye(3, dtype=F64)
    t = torch.tensor([0.05, 0.02, 3.0], dtype=F64)

    def render(v, K, R, t):
        return soft_silhouette(v, f, Camera(K, R, t, 10, 8), sigma=0.8)

    args = [x.clone().requires_grad_(True) for x in (v, K, R, t)]
    assert torch.autograd.gradcheck(render, args, eps=1e-6, atol=1e-6)


def test_single_edge_closed_form(backend):
    # a huge triangle with a vertical edge at u = 20: pixels left of it see sigmoid(-d^2/sigma)
    cam = Camera.from_focal(10.0, 40, 8, dtype=F64)
    z = 1.0
    uv = torch.tensor([[20.0, -500.0], [20.0, 500.0], [520.0, 4.0]], dtype=F64)
    v = cam.unproject(uv, torch.full((3,), z, dtype=F64))
    sigma = 3.0
    out = soft_silhouette(v, torch.tensor([[0, 1, 2]]), cam, sigma=sigma)
    u = torch.arange(40, dtype=F64) + 0.5
    d2 = (u - 20.0) ** 2
    expected = torch.sigmoid(torch.where(u > 20, d2, -d2) / sigma)
    assert_close(out[4], expected, atol=1e-8)  # culled terms are below cull_eps = 1e-8


def test_batch_orientation_and_log_visibility(backend):
    v, f = _sphere()
    cam = _cam()
    vb = torch.stack([v, v * 0.5 + 0.2])
    batch = soft_silhouette(vb, f, cam)
    assert batch.shape == (2, cam.height, cam.width)
    assert_close(batch[1], soft_silhouette(vb[1], f, cam), atol=1e-12)
    assert_close(soft_silhouette(v, f.flip(1), cam), batch[0], atol=1e-12)
    sil, logs = soft_log_visibility(v, f, cam)
    assert torch.isfinite(logs).all()
    assert_close(sil, -torch.expm1(logs), atol=1e-12)
    assert_close(soft_silhouette(v, f, cam), soft_silhouette(v, f, cam), atol=0)  # deterministic


def test_backends_agree_on_batches_and_clipped_faces():
    # a batch of two meshes, one partly outside the image (faces clipped by the borders)
    v, f = _sphere(dtype=F64)
    vb = torch.stack([v, v * 1.3 + torch.tensor([1.2, 0.4, 0.0], dtype=F64)])
    cam = _cam()
    w = torch.randn(2, cam.height, cam.width, dtype=F64)
    res = {}
    try:
        for name in BACKENDS:
            soft.set_backend(name)
            vv = vb.clone().requires_grad_(True)
            sil, logs = soft_log_visibility(vv, f, cam, sigma=0.7)
            (g,) = torch.autograd.grad((sil * w).sum() + 1e-3 * logs.sum(), vv)
            res[name] = (sil, logs, g)
    finally:
        soft.set_backend("auto")
    a, b = res["numba"], res["torch"]
    assert float(a[0][1, :, -1].max()) > 0.5  # the second mesh reaches the right border
    assert_close(a[0], b[0], atol=1e-7)
    assert_close(a[1], b[1], atol=1e-6)  # the numba kernel skips terms below cull_eps exactly
    assert float(a[2].abs().max()) > 1.0
    assert_close(a[2], b[2], atol=2e-5)  # skipped terms: each below cull_eps / sigma * radius


def test_backend_switch_rejects_unknown_names():
    with pytest.raises(InvalidInputError, match="backend"):
        soft.set_backend("cuda")
    assert soft.get_backend() in ("numba", "torch")


def test_without_numba_auto_falls_back_to_torch(monkeypatch):
    from easyhoi.render import _common

    v, f = _sphere()
    cam = _cam()
    expected = soft_silhouette(v, f, cam)
    monkeypatch.setitem(_common._NUMBA, "mod", None)  # as if numba failed to import
    assert soft.get_backend() == "torch"
    with pytest.raises(InvalidInputError, match="numba"):
        soft.set_backend("numba")
    assert_close(soft_silhouette(v, f, cam), expected, atol=1e-7)


def test_a_failing_numba_kernel_warns_and_falls_back_to_torch(monkeypatch):
    from types import SimpleNamespace

    from numba.core.errors import TypingError

    from easyhoi import compiled
    from easyhoi.render import _common, extend_depth
    from easyhoi.render.raster import depth_map

    v, f = _sphere()
    cam = _cam()
    expected = (soft_silhouette(v, f, cam), depth_map(v, f, cam))
    z = expected[1].clone()

    def boom(*args):
        raise TypingError("cannot compile on this machine")

    broken = SimpleNamespace(soft_logsum_forward=boom, zbuffer=boom, min_filter=boom)
    monkeypatch.setattr(compiled, "_FAILED", set())  # this test's failures stay in it
    for call in (lambda: soft_silhouette(v, f, cam), lambda: depth_map(v, f, cam),
                 lambda: extend_depth(z, 2)):  # fmt: skip
        monkeypatch.setitem(_common._NUMBA, "mod", broken)
        monkeypatch.setitem(_common.BACKEND, "name", "auto")
        with pytest.warns(RuntimeWarning, match="numba kernel .* failed"):
            out = call()
        assert soft.get_backend() == "torch"  # disabled for the rest of the process
        assert torch.isfinite(out).any()
    assert_close(soft_silhouette(v, f, cam), expected[0], atol=1e-7)
    assert_close(depth_map(v, f, cam), expected[1], atol=1e-12)


def test_culling_evaluates_few_pairs():
    v, f = _sphere(sub=4, radius=0.3, dtype=torch.float32)
    cam = _cam(128, 128, focal=150.0, dtype=torch.float32)
    tri_uv, _, _ = project_faces(v[None], f, cam, 1e-3)
    face, pix = bbox_pairs(tri_uv, 128, 128, cull_margin(1.0))
    dense = 128 * 128 * f.shape[0]
    assert 0 < face.numel() < 0.01 * dense
    used, _ = soft._face_table(tri_uv, 128, 128, cull_margin(1.0), torch.zeros(len(f)).long())
    assert torch.equal(used, face)  # the renderer evaluates exactly these pairs
    # every generated pair lies inside its face's grown bounding box
    u = (pix % 128).float() + 0.5
    lo = tri_uv[face, :, 0].amin(1) - cull_margin(1.0)
    hi = tri_uv[face, :, 0].amax(1) + cull_margin(1.0)
    assert bool(((u >= lo) & (u <= hi)).all())


def test_sigma_conversion_and_margin():
    cam = _cam(256, 128)
    assert math.isclose(sigma_from_ndc(1e-4, cam), 1e-4 * 128**2)
    assert math.isclose(torch.sigmoid(torch.tensor(-cull_margin(2.0, 1e-8) ** 2 / 2.0)).item(),
                        1e-8, rel_tol=1e-3)  # fmt: skip


def test_faces_behind_near_plane_are_dropped():
    v, f = _sphere()
    cam = Camera.look_at((0, 0, -1.2), (0, 0, 0), focal=20.0, width=32, height=32, dtype=F64)
    z = cam.world_to_camera(v)[:, 2]
    near = 0.5
    kept = f[(z[f] >= near).all(1)]
    assert 0 < kept.shape[0] < f.shape[0]
    assert_close(soft_silhouette(v, f, cam, near=near), soft_silhouette(v, kept, cam, near=near))


def test_empty_and_behind_camera_give_zero_masks():
    cam = _cam()
    v, f = _sphere()
    zero = torch.zeros(cam.height, cam.width, dtype=F64)
    assert_close(soft_silhouette(torch.zeros(0, 3, dtype=F64), torch.zeros(0, 3), cam), zero)
    assert_close(soft_silhouette(v, torch.zeros(0, 3, dtype=torch.long), cam), zero)
    behind = (v + torch.tensor([0.0, 0.0, -10.0], dtype=F64)).requires_grad_(True)
    out = soft_silhouette(behind, f, cam)
    assert_close(out, zero, atol=0)
    (g,) = torch.autograd.grad(out.sum(), behind, allow_unused=True)
    assert g is None or bool((g == 0).all())
    far = v + torch.tensor([100.0, 0.0, 0.0], dtype=F64)  # in front, outside the image
    assert_close(soft_silhouette(far, f, cam), zero, atol=0)


@pytest.mark.parametrize(
    "verts, faces, kw",
    [
        (np.full((4, 3), np.nan), [[0, 1, 2]], {}),
        (np.zeros((4, 3)), [[0, 1, 4]], {}),
        (np.zeros((4, 3)), [[0, 1, -1]], {}),
        (np.zeros((4, 3)), [[0.0, 1.0, 2.0]], {}),
        (np.zeros((4, 2)), [[0, 1, 2]], {}),
        (np.zeros((4, 3)), [[0, 1]], {}),
        (np.zeros((4, 3)), [[0, 1, 2]], {"sigma": 0.0}),
        (np.zeros((4, 3)), [[0, 1, 2]], {"near": -1.0}),
        (np.zeros((4, 3)), [[0, 1, 2]], {"cull_eps": 2.0}),
    ],
)
def test_bad_input_raises(verts, faces, kw):
    with pytest.raises(InvalidInputError):
        soft_silhouette(verts, faces, _cam(), **kw)


def test_bad_camera():
    with pytest.raises(InvalidInputError):
        soft_silhouette(np.zeros((3, 3)), [[0, 1, 2]], "camera")
    with pytest.raises(InvalidInputError):
        Camera.from_focal(-5.0, 32, 32)


@pytest.mark.slow
def test_compiled_kernels_match_eager():
    v, f = _sphere(dtype=torch.float32)
    cam = _cam(dtype=torch.float32)
    w = torch.randn(cam.height, cam.width)
    results = []
    try:
        for name in ("torch", "compile"):
            soft.set_backend(name)
            vv = v.clone().requires_grad_(True)
            out = soft_silhouette(vv, f, cam)
            (g,) = torch.autograd.grad((out * w).sum(), vv)
            results.append((out, g))
    finally:
        soft.set_backend("auto")
    assert_close(results[1][0], results[0][0], atol=1e-5)
    assert_close(results[1][1], results[0][1], atol=1e-3, rtol=1e-4)


def test_numba_exp_and_log1p_polynomials_match_libm():
    kern = pytest.importorskip("easyhoi.render._numba_kernels")
    y = np.concatenate([np.linspace(0.0, 40.0, 200_001), [1e-300, 1e-12, 1e-6, 39.999]])
    got = np.array([kern._exp_neg(v) for v in y])
    ref = np.exp(-y)
    assert np.max(np.abs(got / ref - 1.0)) < 1e-13
    assert kern._exp_neg(60.0) == kern._exp_neg(40.0) < 5e-18  # clamped, far below any use
    z = np.concatenate([np.linspace(0.0, 1.0, 200_001), [1e-300, 1e-17, 1e-9, math.sqrt(2) - 1]])
    got = np.array([kern._log1p_unit(v) for v in z])
    ref = np.log1p(z)
    pos = z > 0
    assert np.max(np.abs(got[pos] / ref[pos] - 1.0)) < 1e-15
    assert got[~pos].max() == 0.0


def _box_pair_reference(tri, base, H, W, sigma, margin, grad_out):
    """Culled sum and corner gradient of the numba kernels, from the torch pair kernel."""
    tri_t = torch.tensor(tri, dtype=F64)
    face, table = soft._face_table(tri_t.view(-1, 3, 2), H, W, margin, torch.tensor(base))
    out, pix, coef, rx, ry, t, e = soft._fused_forward(
        tri_t.t().contiguous(), table, face, W, 1.0 / sigma, int(grad_out.size)
    )
    # the numba kernels skip the pairs farther than margin outside the face (coef < 0)
    val, *_ = soft._pair_kernel(*tri_t[face].t(), (pix % W).double() + 0.5,
                                (pix // W % H).double() + 0.5, 1.0 / sigma)  # fmt: skip
    kept = (coef > 0) | (rx * rx + ry * ry <= margin * margin)
    out = torch.zeros_like(out).index_add_(0, pix[kept], val[kept])
    grad = soft._fused_backward(torch.tensor(grad_out), face, pix, coef * kept, rx, ry, t, e,
                                tri.shape[0])  # fmt: skip
    return out.numpy(), grad.view(-1, 6).numpy()


def test_numba_kernels_match_pair_reference_on_blocks_borders_and_batches():
    kern = pytest.importorskip("easyhoi.render._numba_kernels")
    rng = np.random.default_rng(3)
    H, W, B = 23, 37, 2
    n = 300
    centre = rng.uniform([-6.0, -6.0], [W + 6.0, H + 6.0], size=(n, 1, 2))
    size = rng.choice([0.3, 2.0, 7.0, 25.0], size=(n, 1, 1))  # boxes of 1 to ~40 columns
    tri = (centre + size * rng.uniform(-1, 1, size=(n, 3, 2))).reshape(n, 6)
    tri[0] = [5.0, 5.0, 5.0, 5.0, 5.0, 5.0]  # degenerate: a point
    tri[1] = [-3.3, 1.7, W + 2.9, 2.2, W / 2 + 0.37, H + 3.1]  # wider than the image
    base = rng.integers(0, B, size=n) * (H * W)
    grad_out = rng.standard_normal(B * H * W)
    grad_out[::7] = 0.0
    for sigma in (0.1, 1.0, 3.0):
        margin = cull_margin(sigma)
        out = np.empty(B * H * W)
        grad = np.empty((n, 6))
        kern.soft_logsum_forward(tri, base, H, W, 1.0 / sigma, margin, B * H * W, out)
        kern.soft_logsum_backward(tri, base, H, W, 1.0 / sigma, margin, grad_out, grad)
        ref_out, ref_grad = _box_pair_reference(tri, base, H, W, sigma, margin, grad_out)
        assert out.min() < -1.0  # covered pixels
        np.testing.assert_allclose(out, ref_out, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(grad, ref_grad, rtol=1e-10, atol=1e-11 * np.abs(ref_grad).max())
        again = np.empty((n, 6))
        kern.soft_logsum_backward(tri, base, H, W, 1.0 / sigma, margin, grad_out, again)
        assert np.array_equal(grad, again)  # deterministic
