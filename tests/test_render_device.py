"""The renderer's torch kernels on any device against the CPU numba kernels.

The optimizer renders in float32 (``optim.dtype``). The torch path (the only one off the CPU)
must agree with the numba kernels within the tolerances docs/gpu.md states:
soft silhouettes 1e-5 absolute, their vertex gradients 1e-4 relative to the largest,
z-buffer and peeled depths 1e-5 relative, the same face ids. The "cuda" cases skip where torch
sees no GPU; the "meta" audit checks on the CPU that every tensor the kernels create is placed
on the inputs' device (a tensor created without a device lands on the meta device and the call
fails), which is what lets them run on a GPU at all.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.render import depth_map, hoi_masks, peel, peel_pixels, soft, soft_silhouette
from easyhoi.structures import Camera
from tests.helpers import assert_close

F32 = torch.float32
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA GPU")
DEVICES = ["cpu", pytest.param("cuda", marks=CUDA)]

SIL_ATOL = 1e-5
GRAD_RTOL = 1e-4
DEPTH_RTOL = 1e-5


def _mesh(size: int = 64):
    m = trimesh.creation.icosphere(2, radius=1.0)
    v = torch.tensor(m.vertices * [1.0, 0.8, 0.9], dtype=F32)
    cam = Camera.look_at((0.4, 0.3, -3.0), (0, 0, 0), focal=size * 0.8, width=size,
                         height=size * 3 // 4, dtype=F32)  # fmt: skip
    return v, torch.tensor(m.faces), cam


def _soft(backend: str, v, f, cam, w):
    soft.set_backend(backend)
    try:
        vv = v.clone().requires_grad_(True)
        sil = soft_silhouette(vv, f, cam, sigma=0.5)
        (g,) = torch.autograd.grad((sil * w).sum(), vv)
    finally:
        soft.set_backend("auto")
    return sil.detach(), g


@pytest.mark.parametrize("device", DEVICES)
def test_torch_kernels_on_device_match_cpu_numba(device):
    pytest.importorskip("easyhoi.render._numba_kernels")
    v, f, cam = _mesh()
    w = torch.randn(cam.height, cam.width, generator=torch.Generator().manual_seed(0))
    ref_sil, ref_g = _soft("numba", v, f, cam, w)
    ref_z = depth_map(v, f, cam)
    dev = torch.device(device)
    sil, g = _soft("torch", v.to(dev), f.to(dev), cam.to(device=dev), w.to(dev))
    assert sil.device.type == dev.type and g.device.type == dev.type
    assert 200 < int((ref_sil > 0.5).sum()) < ref_sil.numel()  # in view, not filling it
    assert_close(sil, ref_sil, atol=SIL_ATOL)
    scale = float(ref_g.abs().max())
    assert scale > 1.0
    assert_close(g, ref_g, atol=GRAD_RTOL * scale)
    soft.set_backend("torch")
    try:
        z = depth_map(v.to(dev), f.to(dev), cam.to(device=dev))
    finally:
        soft.set_backend("auto")
    hit = torch.isfinite(ref_z)
    assert int(hit.sum()) > 200 and torch.equal(torch.isfinite(z).cpu(), hit)
    assert_close(z.cpu()[hit], ref_z[hit], rtol=DEPTH_RTOL)


@pytest.mark.parametrize("device", DEVICES)
def test_depth_peeling_on_device_matches_cpu(device):
    v, f, cam = _mesh()
    dev = torch.device(device)
    ref = peel(v, f, cam, num_layers=3)
    out = peel(v.to(dev), f.to(dev), cam.to(device=dev), num_layers=3)
    assert out.depth.device.type == dev.type
    assert int((ref.face_ids[..., 1] >= 0).sum()) > 200  # a closed mesh: two layers per hit
    assert torch.equal(out.face_ids.cpu(), ref.face_ids)
    hit = ref.face_ids >= 0
    assert_close(out.depth.cpu()[hit], ref.depth[hit], rtol=DEPTH_RTOL)
    assert_close(out.bary.cpu(), ref.bary, atol=1e-5)
    uv = torch.tensor([[32.5, 24.5], [10.25, 40.0], [60.0, 2.0]])
    a = peel_pixels(v, f, cam, uv, num_layers=2)
    b = peel_pixels(v.to(dev), f.to(dev), cam.to(device=dev), uv.to(dev), num_layers=2)
    assert torch.equal(b.face_ids.cpu(), a.face_ids)
    assert_close(b.points.cpu(), a.points, atol=1e-5)


def _hoi(backend: str, device: str):
    v, f, cam = _mesh()
    dev = torch.device(device)
    hand = v * 0.4 + torch.tensor([0.5, 0.2, -1.0])  # a smaller sphere in front, off centre
    soft.set_backend(backend)
    try:
        return hoi_masks(hand.to(dev), f.to(dev), v.to(dev), f.to(dev), cam.to(device=dev),
                         sigma=0.5)  # fmt: skip
    finally:
        soft.set_backend("auto")


@pytest.mark.parametrize("device", DEVICES)
def test_occlusion_aware_masks_on_device_match_cpu_numba(device):
    pytest.importorskip("easyhoi.render._numba_kernels")
    ref, out = _hoi("numba", "cpu"), _hoi("torch", device)
    assert out.hand_visible.device.type == torch.device(device).type
    hidden = (ref.object > 0.5) & (ref.object_visible < 0.5)
    assert int(hidden.sum()) > 50  # the hand hides part of the object
    for name in ("hand", "object", "hand_visible", "object_visible"):
        assert_close(getattr(out, name), getattr(ref, name), atol=SIL_ATOL, msg=name)


def test_torch_kernels_create_every_tensor_on_the_inputs_device():
    v, f, cam = _mesh(48)
    uv = torch.tensor([[20.5, 18.5], [30.0, 10.0]])
    soft.set_backend("torch")
    torch.set_default_device("meta")
    try:
        vv = v.clone().requires_grad_(True)
        sil = soft_silhouette(vv, f, cam, sigma=0.5)
        sil.sum().backward()
        z = depth_map(v, f, cam)
        frags = peel(v, f, cam, num_layers=2)
        pts = peel_pixels(v, f, cam, uv, num_layers=2)
        masks = hoi_masks(v * 0.4 + torch.tensor([0.5, 0.2, -1.0], device="cpu"), f, v, f, cam)
    finally:
        torch.set_default_device(None)
        soft.set_backend("auto")
    for t in (sil, vv.grad, z, frags.depth, pts.points, masks.hand_visible):
        assert t.device.type == "cpu"
    assert float(sil.detach().max()) > 0.99 and np.isfinite(float(vv.grad.abs().sum()))
