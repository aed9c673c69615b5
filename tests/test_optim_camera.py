"""Stage 1 (camera setup) on synthetic scenes with a known object camera."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.config import get_preset
from easyhoi.optim.camera import (
    _yaw,
    candidate_rotations,
    fit_box,
    fit_camera,
    hull_vertex_ids,
    initial_camera,
)
from easyhoi.optim.losses import sinkhorn_mask_loss
from easyhoi.optim.state import Scene, hard_iou
from easyhoi.render.raster import depth_map
from easyhoi.render.soft import soft_silhouette
from easyhoi.structures import Camera
from easyhoi.testing.optim_scenes import make_scene

SIZE = 96


def _setup(kind, hand):
    sc = make_scene(kind, size=SIZE)
    scene = Scene.from_input(sc.inp, hand, torch.float32)
    cfg = replace(get_preset("fast").optim, render_size=SIZE)
    return sc, scene, cfg


def _reprojection(scene, cam, gt):
    pts = scene.object_verts.double()
    uv, _ = cam.to(torch.float64).project(pts)
    uv_gt, _ = gt.project(pts)
    return float((uv - uv_gt).norm(dim=-1).mean())


def _raster_iou(scene, cam, target):
    z = depth_map(scene.object_verts, scene.object_faces, cam.detach())
    return hard_iou(torch.isfinite(z).float(), target)


def _perturbed(gt: Camera) -> Camera:
    """The ground-truth camera rotated by ~8 degrees, shifted and with a 12 % longer focal."""
    from easyhoi.geometry.transforms import axis_angle_to_matrix

    dR = axis_angle_to_matrix(torch.tensor([0.08, -0.1, 0.05], dtype=torch.float64))
    K = gt.K.clone()
    K[0, 0] *= 1.12
    K[1, 1] *= 1.12
    t = gt.t + torch.tensor([0.35, -0.25, -0.4], dtype=torch.float64)
    return Camera(K, dR @ gt.R, t, gt.width, gt.height).to(torch.float32)


@pytest.mark.parametrize("kind", ["cylinder", "box"])
def test_camera_recovered_from_perturbed_start(kind, hand):
    sc, scene, cfg = _setup(kind, hand)
    cam0 = _perturbed(sc.gt_camera)
    target = scene.masks_at(SIZE, SIZE)["amodal"]
    err0 = _reprojection(scene, cam0, sc.gt_camera)
    iou0 = _raster_iou(scene, cam0, target)
    cam, res = fit_camera(scene, cam0, cfg.camera, cfg)
    err = _reprojection(scene, cam, sc.gt_camera)
    iou = _raster_iou(scene, cam, target)
    assert err0 > 5.0 and iou0 < 0.7  # the start is genuinely off
    assert iou > 0.9, (iou0, iou)
    assert err < 3.0, (err0, err)
    assert res.name == "camera" and res.iterations > 0
    assert res.losses[-1]["iou"] < res.losses[0]["iou"]
    assert res.stop_reason in ("stop_loss", "patience", "max_iters")


def test_initial_camera_from_masks(hand):
    sc, scene, cfg = _setup("box", hand)
    cam, note = initial_camera(scene, cfg.camera, sc.inp.amodal_mask, SIZE)
    assert note["init"] == "mask_box" and note["rotation"] == "+x+y+z"  # canonical view
    assert len(note["candidates"]) == 24
    target = scene.masks_at(SIZE, SIZE)["amodal"]
    assert _raster_iou(scene, cam, target) > 0.75
    assert _reprojection(scene, cam, sc.gt_camera) < 4.0
    # without init_from_masks: the reference's centred camera at distance 4.5
    cam_d, note_d = initial_camera(
        scene, replace(cfg.camera, init_from_masks=False), sc.inp.amodal_mask, SIZE
    )
    assert note_d["init"] == "default"
    centre_cam = cam_d.world_to_camera(scene.center)
    np.testing.assert_allclose(centre_cam.numpy(), [0.0, 0.0, 4.5], atol=1e-5)


def test_fit_box_matches_box():
    rng = np.random.default_rng(0)
    verts = rng.uniform(-1, 1, size=(200, 3)) * [1.0, 0.6, 0.4]
    box = np.array([30.0, 20.0, 70.0, 48.0])
    R = np.eye(3)
    t = fit_box(verts, R, 100.0, (50.0, 40.0), box, verts.mean(axis=0))
    P = verts @ R.T + t
    uv = 100.0 * P[:, :2] / P[:, 2:3] + [50.0, 40.0]
    got = np.array([*uv.min(axis=0), *uv.max(axis=0)])
    np.testing.assert_allclose(0.5 * (got[:2] + got[2:]), 0.5 * (box[:2] + box[2:]), atol=0.1)
    area = np.prod(got[2:] - got[:2])
    assert abs(area / np.prod(box[2:] - box[:2]) - 1.0) < 0.01


def test_fit_box_on_the_hull_points_equals_all_points():
    import trimesh
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    meshes = [trimesh.creation.box((1.0, 2.0, 3.0)), trimesh.creation.icosphere(3),
              trimesh.creation.cylinder(1.0, 3.0, sections=48)]  # fmt: skip
    blob = rng.normal(size=(400, 3)) * [1.0, 0.5, 0.3]  # most points inside the hull
    clouds = [np.asarray(m.vertices) for m in meshes] + [blob]
    rotations = [R for _, R in candidate_rotations("cube")]
    rotations += list(Rotation.random(6, random_state=2).as_matrix())
    for v in clouds:
        ids = hull_vertex_ids(v)
        assert ids is not None and len(ids) <= len(v)
        c = 0.5 * (v.min(axis=0) + v.max(axis=0))
        for R in rotations:
            box = np.array([100.0, 80.0, 100 + rng.uniform(20, 200), 80 + rng.uniform(20, 200)])
            full = fit_box(v, R, 500.0, (320.0, 240.0), box, c)
            assert np.array_equal(fit_box(v, R, 500.0, (320.0, 240.0), box, c, ids), full)
    assert len(hull_vertex_ids(blob)) < len(blob) // 4
    # a point cloud without volume has no hull: every point is used
    assert hull_vertex_ids(np.c_[rng.normal(size=(50, 2)), np.zeros(50)]) is None


def test_sinkhorn_gradient_pulls_camera_when_masks_do_not_overlap(hand):
    """IoU has no gradient without overlap; the Sinkhorn term moves the object to the mask."""
    sc, scene, _ = _setup("box", hand)
    target = scene.masks_at(48, 48)["amodal"]
    gt = sc.gt_camera.to(torch.float32)
    shift = torch.tensor([1.6, 0.0, 0.0], requires_grad=True)  # object far to the right
    cam = Camera(gt.K, gt.R, gt.t + shift, gt.width, gt.height).resized(48, 48)
    sil = soft_silhouette(scene.object_verts, scene.object_faces, cam, 0.1)
    assert float((sil * target).sum()) < 0.5  # (pixels of overlap)
    loss = sinkhorn_mask_loss(sil, target, grid=16)
    loss.backward()
    assert float(shift.grad[0]) > 0  # descent decreases the x shift: back towards the mask


def test_candidate_rotations():
    yaw = candidate_rotations("yaw")
    cube = candidate_rotations("cube")
    assert [lab for lab, _ in yaw] == ["yaw 0", "yaw 90", "yaw 180", "yaw 270"]
    assert len(cube) == 24 and len({lab for lab, _ in cube}) == 24
    mats = np.stack([R for _, R in cube])
    eye = np.broadcast_to(np.eye(3), mats.shape)
    np.testing.assert_allclose(mats @ mats.transpose(0, 2, 1), eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(mats), 1.0, atol=1e-12)
    assert len({tuple(R.ravel()) for R in mats}) == 24  # all distinct: the whole cube group
    for (_, Ry), (_, Rc) in zip(yaw, cube[:4], strict=True):  # the yaws come first
        np.testing.assert_allclose(Rc, Ry, atol=1e-12)
    assert cube[0][0] == "+x+y+z" and cube[1][0] == "+z+y-x"
    np.testing.assert_allclose(cube[1][1], _yaw(90.0), atol=1e-12)


def test_cube_init_finds_a_mesh_given_in_a_rotated_frame(hand):
    """A scan in its own frame (here: the box turned 90 deg about x and z) is found by "cube"."""
    from easyhoi.geometry.transforms import axis_angle_to_matrix

    sc, _, cfg = _setup("box", hand)

    def rot(*aa):
        return axis_angle_to_matrix(torch.tensor(aa, dtype=torch.float64))

    turn = rot(0.0, 0.0, np.pi / 2) @ rot(np.pi / 2, 0.0, 0.0)
    mesh = sc.inp.object_mesh.copy()
    mesh.vertices = mesh.vertices @ turn.numpy().T
    scene = Scene.from_input(replace(sc.inp, object_mesh=mesh), hand, torch.float32)
    target = scene.masks_at(SIZE, SIZE)["amodal"]
    ious = {}
    for kind in ("yaw", "cube"):
        c = replace(cfg.camera, init_rotations=kind)
        cam, note = initial_camera(scene, c, sc.inp.amodal_mask, SIZE)
        ious[kind] = _raster_iou(scene, cam, target)
    assert ious["cube"] > 0.75 and ious["cube"] > ious["yaw"] + 0.1, ious


def test_square_pixels_keep_one_focal(hand):
    """With square pixels the fit moves one focal for both axes (fx == fy throughout) and still
    recovers the camera; with separate focals the two drift apart on the same start."""
    sc, scene, cfg = _setup("box", hand)
    cam0 = _perturbed(sc.gt_camera)
    square = replace(cfg.camera, square_pixels=True)
    cam, _ = fit_camera(scene, cam0, square, cfg)
    assert float(cam.fx) == float(cam.fy)
    assert abs(float(cam.fx) / float(cam0.fx) - 1.0) > 1e-3  # the focal did move
    assert _reprojection(scene, cam, sc.gt_camera) < 3.0
    free, _ = fit_camera(scene, cam0, replace(cfg.camera, square_pixels=False), cfg)
    assert float(free.fx) != float(free.fy)


def _farther(kind, hand, k):
    """The scene of ``kind``, its ground-truth camera, the amodal target, the object's centre in
    that camera, and the camera moved ``k`` (a fraction) farther along the ray through it."""
    sc, scene, cfg = _setup(kind, hand)
    gt = sc.gt_camera.to(torch.float32)
    target = scene.masks_at(SIZE, SIZE)["amodal"]
    c = gt.R @ scene.center + gt.t
    return scene, cfg, gt, target, c, Camera(gt.K, gt.R, gt.t + k * c, gt.width, gt.height)


def test_sharpen_depth_undoes_a_distance_error_and_ties_keep_the_camera(hand):
    """The object's hard silhouette at the ground-truth distance is the mask; from 5 % farther
    the search along the ray through the object's centre comes back (factor 1/1.05), and at the
    right distance it keeps the camera (factor 1)."""
    from easyhoi.optim.camera import DEPTH_FACTORS, sharp_iou, sharpen_depth

    scene, _, gt, target, c, far = _farther("cylinder", hand, 0.05)
    iou_far = sharp_iou(scene, far, SIZE, SIZE, target)
    cam, iou, f = sharpen_depth(scene, far, SIZE, SIZE, target)
    assert 1 / 1.05 - 0.015 <= f <= 1 / 1.05 + 0.015 and f in DEPTH_FACTORS
    assert iou > iou_far + 0.02 and iou == pytest.approx(sharp_iou(scene, cam, SIZE, SIZE, target))
    np.testing.assert_allclose((cam.R @ scene.center + cam.t).numpy(), (f * 1.05 * c).numpy(),
                               rtol=1e-5)  # fmt: skip
    _, iou_gt, f_gt = sharpen_depth(scene, gt, SIZE, SIZE, target)
    assert f_gt == 1.0 and iou_gt >= iou - 1e-9


def test_a_start_that_already_fits_is_kept(hand):
    """From the ground-truth camera the soft IoU fit still moves (the blurred silhouette's
    optimum is not the sharp one's): a start whose sharp silhouette already fits runs no
    iteration, and one that fits better than where the fit ends is returned."""
    sc, scene, cfg = _setup("box", hand)
    gt = sc.gt_camera.to(torch.float32)
    target = scene.masks_at(SIZE, SIZE)["amodal"]
    cam, res = fit_camera(scene, gt, cfg.camera, cfg)
    assert res.iterations == 0 and res.stop_reason == "stop_loss" and res.extra["kept_start"]
    assert res.extra["final_mask_iou"] == res.extra["start_mask_iou"] == 1.0
    torch.testing.assert_close(cam.K, gt.K)
    torch.testing.assert_close(cam.t, gt.t)
    assert _raster_iou(scene, cam, target) == 1.0


def test_a_start_below_the_stop_runs_the_fit_and_ends_sharper(hand):
    """With the start check off (stop_loss 0), a start 2 % farther than the truth runs the soft
    fit, and the camera returned has a sharper fit than the start (the distance search after
    the soft fit)."""
    from easyhoi.optim.camera import sharp_iou

    scene, cfg, _, target, _, far = _farther("box", hand, 0.02)
    start = sharp_iou(scene, far, SIZE, SIZE, target)
    cam, res = fit_camera(scene, far, replace(cfg.camera, stop_loss=0.0), cfg)
    assert res.iterations > 0 and not res.extra["kept_start"]
    assert res.extra["start_mask_iou"] == pytest.approx(start) and start < 0.97
    assert res.extra["final_mask_iou"] > 0.98
    assert _raster_iou(scene, cam, target) == pytest.approx(res.extra["final_mask_iou"])
