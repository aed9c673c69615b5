"""Back-off, closing and refinement steps of :func:`easyhoi.synth.grasp.synthesize_grasp`.

:func:`_back_off` and :func:`_close` query the SDF grid of the object (end of step 1, step 2:
per-finger closing along the synergy with segment-wise freezing); :func:`_refine` is step 3
(Adam with tangent-plane signed distances, :func:`_signed_distance_planes`). The method is
described in :mod:`easyhoi.synth.grasp`.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from easyhoi.geometry.sdf import SDFGrid, exact_signed_distance, query
from easyhoi.geometry.transforms import axis_angle_to_matrix
from easyhoi.hand.regions import DIGIT_JOINTS
from easyhoi.optim.adam import Adam

__all__: list[str] = []


def _sdf(grid: SDFGrid, canon: torch.Tensor, R: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    return query(grid, canon @ R.T + T)


def _back_off(grid, canon, R, T, direction, tol: float, max_dist: float = 0.08) -> np.ndarray:
    """Smallest shift along ``direction`` that leaves no vertex deeper than ``tol`` inside."""
    shifts = torch.linspace(0.0, max_dist, 81, dtype=torch.float64)
    moved = canon[None] @ R.T + T + shifts[:, None, None] * torch.as_tensor(direction)
    depth = query(grid, moved).amin(dim=1)
    ok = torch.nonzero(depth > -tol)
    k = int(ok[0]) if len(ok) else len(shifts) - 1
    return T.numpy() + float(shifts[k]) * np.asarray(direction)


def _close(poser, grid, opened, closed, digits, R, T, num_steps, contact_tol):
    """Per-finger closing along the synergy with segment-wise freezing; returns (15, 3)."""
    part = poser.model.regions.vertex_part.numpy()
    vel = closed - opened
    alpha = np.zeros(15)
    active = {d: np.array([True, True, True]) for d in digits}
    seg_ids = {d: [np.nonzero(part == j)[0] for j in DIGIT_JOINTS[d]] for d in digits}
    steps = np.linspace(0.0, 1.0, num_steps + 1)[1:]
    for _ in range(3):
        if not any(a.any() for a in active.values()):
            break
        a = np.repeat(alpha[None], num_steps, axis=0)
        for d in digits:
            rows = [j - 1 for j in DIGIT_JOINTS[d]]
            a[:, rows] = np.minimum(a[:, rows] + steps[:, None] * active[d], 1.0)
        batch = opened[None] + a[..., None] * vel[None]
        with torch.no_grad():
            canon = poser.canonical(torch.as_tensor(batch.reshape(num_steps, 45)))
            d_all = _sdf(grid, canon, R, T)  # (S, V)
        for d in digits:
            if not active[d].any():
                continue
            rows = [j - 1 for j in DIGIT_JOINTS[d]]
            seg_min = torch.stack([d_all[:, ids].amin(dim=1) for ids in seg_ids[d]], 1).numpy()
            hit = seg_min < contact_tol  # (S, 3)
            first = np.nonzero(hit.any(axis=1))[0]
            if len(first) and first[0] > 0:
                alpha[rows] = a[first[0] - 1, rows]
            elif not len(first):
                alpha[rows] = a[-1, rows]
            if len(first):
                active[d][: int(np.nonzero(hit[first[0]])[0].max()) + 1] = False
            else:
                active[d][:] = False
    return opened + alpha[:, None] * vel


def _signed_distance_planes(mesh: trimesh.Trimesh, x: np.ndarray):
    """Exact signed distance (N,) and unit outward directions (N, 3) at points (N, 3).

    ``d(x + dx) ~ d + n . dx`` near ``x`` (the closest surface point's tangent plane).
    """
    import point_cloud_utils as pcu

    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    d = exact_signed_distance(mesh, x)
    _, fid, bc = pcu.closest_points_on_mesh(np.ascontiguousarray(x), v, f)
    closest = np.einsum("nk,nkd->nd", bc, v[f[fid]])
    n = (x - closest) / np.where(np.abs(d) > 1e-7, d, 1.0)[:, None]
    flat = np.abs(d) <= 1e-7
    n[flat] = mesh.face_normals[fid[flat]]
    return d, n / np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)


def _refine(poser, mesh, pose0, R0, T0, groups, iterations, w_pen, w_att, w_reg):
    """Adam on (rotation residual, translation residual, articulation).

    The signed distance of every hand vertex is its exact value at the last refresh plus the
    motion since along the closest point's outward direction (a tangent-plane model, exact to
    first order, refreshed every 5 iterations). When a vertex is still more than 1.5 mm inside
    after ``iterations`` steps, ``iterations // 2`` more run.
    """
    if iterations <= 0:
        return pose0, R0, T0
    pose = pose0.clone().requires_grad_(True)
    drot = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    dt = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    opt = Adam([{"params": [pose], "lr": 0.01},
                {"params": [drot], "lr": 0.005},
                {"params": [dt], "lr": 0.001}])  # fmt: skip
    groups = [torch.as_tensor(g) for g in groups if len(g)]

    def place():
        R = axis_angle_to_matrix(drot) @ R0
        return poser.canonical(pose[None])[0] @ R.T + T0 + dt

    it, total = 0, iterations
    while True:
        if it == total:
            if total > iterations:
                break
            with torch.no_grad():
                deepest = exact_signed_distance(mesh, place().numpy()).min()
            if deepest >= -0.0015:
                break
            total += iterations // 2
        opt.zero_grad()
        x = place()
        if it % 5 == 0:
            x_ref = x.detach()
            planes = _signed_distance_planes(mesh, x_ref.numpy())
            d_ref, n_ref = (torch.as_tensor(a) for a in planes)
        d = d_ref + ((x - x_ref) * n_ref).sum(-1)
        pen = torch.relu(-d).pow(2).sum()
        att = sum(torch.relu(d[g].amin()).pow(2) for g in groups)
        reg = (pose - pose0).pow(2).sum()
        loss = w_pen * pen + w_att * att + w_reg * reg
        loss.backward()
        opt.step()
        it += 1
    with torch.no_grad():
        R = axis_angle_to_matrix(drot) @ R0
    return pose.detach(), R.detach(), (T0 + dt).detach()
