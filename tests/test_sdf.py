"""Signed distances: exact values vs analytic shapes, grid lookup vs a naive trilinear reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from easyhoi.errors import InvalidInputError
from easyhoi.geometry.sdf import SDFGrid, build_sdf_grid, exact_signed_distance, query
from tests.helpers import assert_close

HALF = np.array([0.5, 0.3, 0.2])


def box_sdf(p: np.ndarray, half: np.ndarray = HALF) -> np.ndarray:
    q = np.abs(p) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=5, radius=0.5)


@pytest.fixture(scope="module")
def sphere_grid(sphere):
    return build_sdf_grid(sphere, resolution=48, padding=0.1)


def naive_trilinear(grid: SDFGrid, p: np.ndarray) -> np.ndarray:
    """Loop-free but explicit trilinear interpolation over the 8 corner nodes."""
    vals = grid.values.double().numpy()
    lo = grid.bounds_min.double().numpy()
    vox = (grid.bounds_max.double().numpy() - lo) / (grid.resolution - 1)
    u = (p - lo) / vox
    i0 = np.clip(np.floor(u).astype(int), 0, grid.resolution - 2)
    f = u - i0
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (
                    (f[:, 0] if dx else 1 - f[:, 0])
                    * (f[:, 1] if dy else 1 - f[:, 1])
                    * (f[:, 2] if dz else 1 - f[:, 2])
                )
                out += w * vals[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
    return out


def test_exact_distance_of_a_box_is_the_analytic_one():
    box = trimesh.creation.box(extents=2 * HALF)
    p = np.random.default_rng(0).uniform(-1, 1, (4000, 3))
    assert_close(exact_signed_distance(box, p), box_sdf(p), atol=1e-12)


def test_exact_distance_of_a_sphere_within_the_tessellation_error(sphere):
    p = np.random.default_rng(1).uniform(-1, 1, (4000, 3))
    exact = np.linalg.norm(p, axis=1) - 0.5
    # a polyhedron inscribed in the sphere: the error is at most the chord sagitta
    edge = float(sphere.edges_unique_length.max())
    sagitta = 0.5 - np.sqrt(0.25 - (edge / 2) ** 2 * 4 / 3)
    err = np.abs(exact_signed_distance(sphere, p) - exact)
    assert err.max() <= sagitta + 1e-12
    assert err.max() > 0  # it is a polyhedron, not the analytic sphere


def test_pseudonormal_sign_matches_winding_number_on_a_scan(shared_data):
    mesh = trimesh.load(shared_data / "objects" / "glue_1.obj", force="mesh")
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # merge UV-seam copies
    assert mesh.is_watertight
    lo, hi = mesh.bounds
    p = np.random.default_rng(2).uniform(lo - 0.01, hi + 0.01, (3000, 3))
    ours = exact_signed_distance(mesh, p)
    wind = exact_signed_distance(mesh, p, sign="winding")
    far = np.abs(ours) > 1e-4
    assert np.array_equal(np.sign(ours[far]), np.sign(wind[far]))
    assert (ours < 0).sum() > 100 and (ours > 0).sum() > 100


def test_grid_nodes_hold_exact_values_and_queries_at_nodes_return_them(sphere, sphere_grid):
    g = sphere_grid
    nodes = g.node_positions(torch.float64)
    flat = nodes.reshape(-1, 3).numpy()
    assert_close(g.values.double().reshape(-1), exact_signed_distance(sphere, flat), atol=1e-7)
    idx = torch.randint(0, g.resolution, (500, 3))
    pts = nodes[idx[:, 0], idx[:, 1], idx[:, 2]]
    want = g.values[idx[:, 0], idx[:, 1], idx[:, 2]].double()
    assert_close(query(g, pts), want, atol=1e-12)  # float64 queries: exact
    assert_close(query(g, pts.float()), want, atol=1e-6)  # float32 queries: rounding only
    # half a voxel off (the reference's align_corners bug) would not be exact
    shifted = query(g, pts + 0.5 * g.voxel_size.double())
    assert (shifted - want).abs().max() > 1e-3


def test_query_inside_matches_naive_trilinear(sphere_grid):
    g = sphere_grid
    lo, hi = g.bounds_min.double().numpy(), g.bounds_max.double().numpy()
    p = np.random.default_rng(3).uniform(lo, hi, (3000, 3))
    got = query(g, torch.as_tensor(p)).numpy()
    assert_close(got, naive_trilinear(g, p), atol=1e-12)


def test_query_outside_is_box_distance_plus_clamped_value(sphere_grid):
    g = sphere_grid
    lo, hi = g.bounds_min.double().numpy(), g.bounds_max.double().numpy()
    p = np.random.default_rng(4).uniform(-2.0, 2.0, (3000, 3))
    clamped = np.clip(p, lo, hi)
    want = naive_trilinear(g, clamped) + np.linalg.norm(p - clamped, axis=1)
    got = query(g, torch.as_tensor(p)).numpy()
    assert_close(got, want, atol=1e-12)
    outside = np.linalg.norm(p - clamped, axis=1) > 0.1
    true = np.linalg.norm(p, axis=1) - 0.5
    # an upper bound of the true distance that keeps growing (a clamp would stay flat)
    assert (got[outside] >= true[outside] - 1e-3).all()
    assert (got[outside] > naive_trilinear(g, clamped[outside]) + 0.09).all()


@pytest.mark.parametrize("shape", ["sphere", "box"])
def test_grid_error_is_within_a_voxel(shape, sphere_grid):
    if shape == "sphere":
        grid, truth = sphere_grid, lambda p: np.linalg.norm(p, axis=1) - 0.5
    else:
        grid = build_sdf_grid(trimesh.creation.box(extents=2 * HALF), resolution=48)
        truth = box_sdf
    lo, hi = grid.bounds_min.double().numpy(), grid.bounds_max.double().numpy()
    p = np.random.default_rng(5).uniform(lo, hi, (5000, 3))
    err = np.abs(query(grid, torch.as_tensor(p)).numpy() - truth(p))
    assert err.max() < float(grid.voxel_size.max())


def test_grid_error_on_a_scanned_object(shared_data):
    mesh = trimesh.load(shared_data / "objects" / "plastic_banana.obj", force="mesh")
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    grid = build_sdf_grid(mesh, resolution=40)
    lo, hi = grid.bounds_min.double().numpy(), grid.bounds_max.double().numpy()
    p = np.random.default_rng(6).uniform(lo, hi, (4000, 3))
    err = np.abs(query(grid, torch.as_tensor(p)).numpy() - exact_signed_distance(mesh, p))
    voxel = float(grid.voxel_size.max())
    assert err.max() < voxel
    assert np.median(err) < 0.05 * voxel


def test_gradcheck_float64_inside_and_outside(sphere_grid):
    g = sphere_grid.to(dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    p = (torch.rand(40, 3, generator=gen, dtype=torch.float64) * 2.4 - 1.2).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: query(g, x), (p,), eps=1e-6, atol=1e-6)


def test_gradient_points_away_from_the_sphere(sphere_grid):
    p = torch.randn(500, 3, dtype=torch.float64)
    radius = torch.empty(500, 1).uniform_(0.25, 0.58).double()  # inside the grid box
    p = p / p.norm(dim=1, keepdim=True) * radius
    p.requires_grad_()
    query(sphere_grid, p).sum().backward()
    radial = p.detach() / p.detach().norm(dim=1, keepdim=True)
    cos = (p.grad * radial).sum(1) / p.grad.norm(dim=1)
    assert cos.min() > 0.97
    assert ((p.grad.norm(dim=1) - 1).abs() < 0.1).float().mean() > 0.9  # |grad sdf| ~ 1


def test_query_keeps_batch_shape(sphere_grid):
    p = torch.rand(2, 5, 7, 3) - 0.5
    got = query(sphere_grid, p)
    assert got.shape == (2, 5, 7)
    assert_close(got.reshape(-1), query(sphere_grid, p.reshape(-1, 3)), atol=0)


def test_bad_input_raises_named_errors(sphere_grid):
    open_box = trimesh.creation.box()
    open_box.faces = open_box.faces[:-2]
    with pytest.raises(InvalidInputError, match="watertight"):
        build_sdf_grid(open_box)
    with pytest.raises(InvalidInputError, match="watertight"):
        exact_signed_distance(open_box, np.zeros((1, 3)))
    with pytest.raises(InvalidInputError, match=r"\(\.\.\., 3\)"):
        query(sphere_grid, torch.zeros(4, 2))
    with pytest.raises(InvalidInputError, match="resolution"):
        build_sdf_grid(trimesh.creation.box(), resolution=1)
    with pytest.raises(InvalidInputError, match=r"values must have shape \(4, 4, 4\)"):
        SDFGrid(torch.zeros(3, 3, 3), torch.zeros(3), torch.ones(3), 4)
    with pytest.raises(InvalidInputError, match="bounds_max"):
        SDFGrid(torch.zeros(4, 4, 4), torch.ones(3), torch.zeros(3), 4)
    with pytest.raises(InvalidInputError, match="NaN"):
        exact_signed_distance(trimesh.creation.box(), np.full((2, 3), np.nan))


def _banded_case(name: str, shared_data) -> trimesh.Trimesh:
    if name == "sphere":
        return trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    if name == "annulus":  # non-convex, with a thin wall and a hole through it
        return trimesh.creation.annulus(r_min=0.3, r_max=0.4, height=0.5, sections=64)
    mesh = trimesh.load(shared_data / "objects" / "plastic_banana.obj", force="mesh")
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)


@pytest.mark.parametrize("name", ["sphere", "annulus", "banana"])
@pytest.mark.parametrize("band", [0.0, 3.0])
def test_banded_build_is_exact_near_the_surface_and_bounded_elsewhere(name, band, shared_data):
    from easyhoi.geometry.sdf import _COARSE_STEP

    mesh = _banded_case(name, shared_data)
    full = build_sdf_grid(mesh, resolution=41, dtype=torch.float64).values.numpy()
    fast = build_sdf_grid(mesh, resolution=41, dtype=torch.float64, exact_band=band)
    got = fast.values.numpy()
    voxel = float(fast.voxel_size.max())
    near = np.abs(full) <= band * voxel
    assert_close(got[near], full[near], atol=1e-9)
    # every coarse node is exact too
    c = np.r_[np.arange(0, 41, _COARSE_STEP), 40]
    assert_close(got[np.ix_(c, c, c)], full[np.ix_(c, c, c)], atol=1e-9)
    # the documented bound: one coarse cell diagonal; the sign is exact everywhere
    err = np.abs(got - full)
    assert err.max() <= _COARSE_STEP * np.sqrt(3.0) * voxel
    assert np.array_equal(got < 0, full < 0)
    assert np.array_equal(got > 0, full > 0)
    if band == 3.0:
        assert (~near).mean() > 0.3  # the band is a small part of the grid: the test bites


def test_banded_per_node_error_bound_holds():
    from easyhoi.geometry.sdf import _banded_values, _pseudo_normals, _signed

    mesh = trimesh.creation.annulus(r_min=0.3, r_max=0.4, height=0.5, sections=64)
    axes = [np.linspace(-0.5, 0.5, 33)] * 3
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    normals = _pseudo_normals(v, f)
    values, bound = _banded_values(axes, 1.0 / 32, 2.0 / 32, lambda p: _signed(p, v, f, normals))
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    truth = exact_signed_distance(mesh, nodes).reshape(values.shape)
    assert (np.abs(values - truth) <= bound + 1e-12).all()
    assert (bound[np.abs(truth) <= 2.0 / 32] == 0).all()
    assert bound.max() > 0


def test_banded_build_rejects_a_bad_band():
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(InvalidInputError, match="exact_band"):
            build_sdf_grid(trimesh.creation.box(), resolution=16, exact_band=bad)


def _folded_box() -> trimesh.Trimesh:
    """A watertight, consistently wound box whose top is pushed down through its bottom: the
    surface folds through itself, and below the bottom the nearest surface is the pushed-down
    top, whose orientation calls the points there inside although no ray test does."""
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0), transform=None)
    mesh = mesh.subdivide().subdivide()
    v = np.asarray(mesh.vertices).copy()
    top = v[:, 2] > 0.49
    v[top, 2] = -1.0  # the top face now lies 0.5 below the bottom face
    return trimesh.Trimesh(v, mesh.faces, process=False)


def test_grid_signs_follow_the_winding_number_on_a_folded_mesh():
    """On a folded mesh the grid takes its signs from the winding number and keeps the exact
    distances."""
    from easyhoi.geometry.sdf import pseudonormal_signed_distance

    mesh = _folded_box()
    assert mesh.is_watertight and mesh.is_winding_consistent
    grid = build_sdf_grid(mesh, resolution=24, exact_band=2.0, dtype=torch.float64)
    import point_cloud_utils as pcu

    nodes = grid.node_positions().reshape(-1, 3).numpy()
    got = grid.values.reshape(-1).numpy()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    winding = pcu.signed_distance_to_mesh(nodes, v, f)[0] < 0
    clear = np.abs(got) > 0.05  # away from the surfaces, where the sign is unambiguous
    assert np.array_equal((got < 0)[clear], winding[clear])
    # where the pseudo-normal sign calls a node inside and neither the winding number nor a
    # ray-parity test does, the grid says outside; there are many such nodes: the test bites
    pn = pseudonormal_signed_distance(nodes, v, f) < 0
    phantom = pn & ~winding & ~mesh.contains(nodes) & clear
    assert phantom.sum() > 50
    assert (got[phantom] > 0).all()
    # the magnitude is still the exact distance to the surface
    full = build_sdf_grid(mesh, resolution=24, dtype=torch.float64).values.reshape(-1).numpy()
    near = np.abs(full) <= 2.0 / 23 * 1.0
    np.testing.assert_allclose(np.abs(got[near]), np.abs(full[near]), atol=1e-12)


def test_grid_of_a_clean_mesh_keeps_the_pseudonormal_signs():
    """On a closed surface that does not cross itself the grid is the pseudo-normal one."""
    from easyhoi.geometry.sdf import pseudonormal_signed_distance

    mesh = trimesh.creation.annulus(r_min=0.3, r_max=0.4, height=0.5, sections=48)
    grid = build_sdf_grid(mesh, resolution=20, dtype=torch.float64)
    nodes = grid.node_positions().reshape(-1, 3).numpy()
    ref = pseudonormal_signed_distance(nodes, np.asarray(mesh.vertices), np.asarray(mesh.faces))
    got = grid.values.reshape(-1).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-12)  # node positions agree to rounding
    assert np.array_equal(got[np.abs(ref) > 1e-9] < 0, ref[np.abs(ref) > 1e-9] < 0)
