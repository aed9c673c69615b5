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


def test_face_gather_matches_advanced_indexing_for_one_and_many_meshes():
    """The corner gather (one mesh: along the leading dimension) gives the values and the
    vertex gradients of plain ``uv[:, faces]`` indexing, bit for bit."""
    verts, faces, cam = _scene()
    for batch in (verts[None], torch.stack([verts, verts.flip(0)])):
        w = torch.randn(batch.shape[0] * faces.shape[0], 3, 2, dtype=torch.float64)
        wz = torch.randn(batch.shape[0] * faces.shape[0], 3, dtype=torch.float64)
        tri_uv, tri_z, keep = _common._project_faces(batch, faces, cam, 1e-3)
        g = torch.autograd.grad((tri_uv * w).sum() + (tri_z * wz).sum(), verts)[0]
        uv, z = cam.project(batch)
        ref_uv = uv[:, faces].reshape(-1, 3, 2)
        ref_z = z[:, faces].reshape(-1, 3)
        ref_g = torch.autograd.grad((ref_uv * w).sum() + (ref_z * wz).sum(), verts)[0]
        assert keep.shape[0] == ref_uv.shape[0]
        assert torch.equal(tri_uv, ref_uv) and torch.equal(tri_z, ref_z)
        assert torch.allclose(g, ref_g, rtol=1e-12, atol=1e-12)
        assert g.abs().sum() > 0
