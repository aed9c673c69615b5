"""A z-buffer right after a soft silhouette of the same mesh reuses its projection, and only
when nothing changed: same values as a fresh projection, gradients untouched."""

from __future__ import annotations

import torch

from easyhoi.render import _common
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import soft_silhouette
from easyhoi.structures import Camera


def _scene():
    g = torch.Generator().manual_seed(2)
    verts = (0.1 * torch.randn(60, 3, generator=g, dtype=torch.float64)).requires_grad_()
    with torch.no_grad():
        verts[:, 2] += 1.0
    faces = torch.randint(0, 60, (90, 3), generator=g)
    cam = Camera.from_focal(70.0, 48, 40, dtype=torch.float64)
    return verts, faces, cam


def _count_projections(monkeypatch) -> list:
    calls = []
    real = _common._project_faces

    def counting(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(_common, "_project_faces", counting)
    return calls


def test_depth_after_silhouette_reuses_the_projection(monkeypatch):
    verts, faces, cam = _scene()
    fresh = depth_map(verts.detach().clone(), faces, cam)  # another tensor: its own projection
    calls = _count_projections(monkeypatch)
    sil = soft_silhouette(verts, faces, cam)
    z = depth_map(verts.detach(), faces, cam.detach())
    assert len(calls) == 1  # the z-buffer reused the silhouette's projection
    assert torch.equal(z, fresh) and torch.isfinite(z).sum() > 50
    sil.sum().backward()  # the silhouette's graph is intact
    assert verts.grad is not None and verts.grad.abs().sum() > 0


def test_changed_inputs_are_projected_again(monkeypatch):
    verts, faces, cam = _scene()
    calls = _count_projections(monkeypatch)
    soft_silhouette(verts, faces, cam)
    with torch.no_grad():
        verts[:, 0] += 0.05  # in place: the version counter moves
    z = depth_map(verts.detach(), faces, cam)
    assert len(calls) == 2
    assert torch.equal(z, depth_map(verts.detach().clone(), faces, cam))
    depth_map(verts.detach(), faces, cam.resized(24, 20))  # another camera size
    depth_map(verts.detach(), faces, cam, near=0.5)  # another near plane
    assert len(calls) == 5


def test_gradient_paths_never_reuse(monkeypatch):
    verts, faces, cam = _scene()
    calls = _count_projections(monkeypatch)
    a = soft_silhouette(verts, faces, cam)
    b = soft_silhouette(verts, faces, cam)
    assert len(calls) == 2 and torch.equal(a, b)
    (g_a,) = torch.autograd.grad(a.sum(), verts)
    (g_b,) = torch.autograd.grad(b.sum(), verts)
    assert torch.equal(g_a, g_b)
