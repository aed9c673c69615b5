"""optim.close_gap: a hand left beside its object is brought back onto it along the camera rays,
keeping its projection; a touching, a penetrating or a laterally displaced hand is left alone."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from easyhoi.config import get_preset
from easyhoi.optim.close_gap import close_gap
from easyhoi.optim.refine import PUSH_OUT_MAX
from easyhoi.optim.state import Scene
from easyhoi.testing.optim_scenes import make_scene


@pytest.fixture(scope="module")
def box():
    sc = make_scene("box")
    scene = Scene.from_input(sc.inp, sc.model, torch.float64)
    cam = sc.gt_camera.to(torch.float64)
    cfg = get_preset("fast").optim.refine
    return sc, scene, cam, cfg


def _along_rays(p, m, eye, k):
    """The same metric hand in the camera with its object-unit vertices scaled by ``k`` about
    the camera centre: (params, metric scale)."""
    m_new = m / k
    return replace(p, transl=p.transl + (m_new - m) * eye[None]), m_new


def _k_for(scene, sc, p, m, eye, move):
    """The factor that moves the hand's centroid by ``move`` normalised object units along its
    ray (positive: away from the camera)."""
    with torch.no_grad():
        dist = float((sc.model(p).vertices[0].mean(0) / m - eye).norm())
    return 1.0 + move * float(scene.extent) / dist


def _nearest(scene, sc, p, m, res):
    with torch.no_grad():
        return float(scene.sdf(sc.model(p).vertices[0] / m, res).min())


def _pixels(sc, p, m, cam):
    with torch.no_grad():
        uv, _ = cam.project(sc.model(p).keypoints[0] / m)
    return uv


def test_a_hand_backed_off_along_the_rays_is_brought_back_to_touch(box):
    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    eye = cam.center.double()
    off, m_off = _along_rays(p, m, eye, _k_for(scene, sc, p, m, eye, -0.08))  # off the object
    gap = _nearest(scene, sc, off, m_off, cfg.sdf_resolution)
    assert gap > 0.01
    target = 0.5 * cfg.penetration_threshold
    k, note = close_gap(scene, off, m_off, cam, cfg.sdf_resolution, target, PUSH_OUT_MAX)
    assert note["moved"] and k > 1.0 and note["gap_before"] == pytest.approx(gap)
    back, m_back = _along_rays(off, m_off, eye, k)
    d = _nearest(scene, sc, back, m_back, cfg.sdf_resolution)
    assert target - 1e-3 <= d <= target  # touching, a hair inside
    assert d == pytest.approx(note["gap_after"], abs=1e-9)
    # the photo sees the same hand: every keypoint on the same pixel
    moved = (_pixels(sc, back, m_back, cam) - _pixels(sc, off, m_off, cam)).norm(dim=1)
    assert float(moved.max()) < 1e-6
    # the smallest move: not past the object to its far side
    assert abs(note["distance"]) <= PUSH_OUT_MAX


def test_touching_penetrating_and_laterally_displaced_hands_are_left_alone(box):
    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    eye = cam.center.double()
    target = 0.5 * cfg.penetration_threshold
    res = cfg.sdf_resolution
    sunk, m_sunk = _along_rays(p, m, eye, _k_for(scene, sc, p, m, eye, 0.08))
    assert _nearest(scene, sc, sunk, m_sunk, res) < 0
    k, note = close_gap(scene, sunk, m_sunk, cam, res, target, PUSH_OUT_MAX)
    assert k == 1.0 and not note["moved"]
    # moved sideways, across the rays, far beyond the object: no depth brings it back
    with torch.no_grad():
        v = sc.model(p).vertices[0] / m
    ray = v.mean(0) - eye
    side = torch.linalg.cross(ray, torch.tensor([0.0, 1.0, 0.0], dtype=ray.dtype))
    side = side / side.norm()
    aside = replace(p, transl=p.transl + (1.5 * scene.extent * m) * side[None])
    assert _nearest(scene, sc, aside, m, res) > 0.2
    k, note = close_gap(scene, aside, m, cam, res, target, PUSH_OUT_MAX)
    assert k == 1.0 and not note["moved"]


def test_refinement_with_close_gap_ends_touching(box):
    """fit_refine with close_gap on a hand that starts off the object ends in contact, and its
    keypoints where the same refinement without the closing puts them."""
    from easyhoi.optim.refine import fit_refine

    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    eye = cam.center.double()
    off, m_off = _along_rays(p, m, eye, _k_for(scene, sc, p, m, eye, -0.12))
    optim_cfg = get_preset("fast").optim
    quick = replace(cfg, max_iters=8, patience=0, resolution_schedule=(0.5,))
    out = {}
    for flag in (False, True):
        c = replace(quick, close_gap=flag)
        params, res = fit_refine(scene, off, m_off, cam, c, optim_cfg)
        out[flag] = (params, res)
    p0, r0 = out[False]
    p1, r1 = out[True]
    assert _nearest(scene, sc, p0, r0.metric_scale, cfg.sdf_resolution) > 0.01  # left off
    d1 = _nearest(scene, sc, p1, r1.metric_scale, cfg.sdf_resolution)
    assert cfg.penetration_threshold - 1e-3 <= d1 <= 0.0
    assert r1.extra["close_gap"]["moved"] and r0.extra["close_gap"] is None
    diff = (_pixels(sc, p1, r1.metric_scale, cam) - _pixels(sc, p0, r0.metric_scale, cam)).norm(
        dim=1
    )
    assert float(diff.max()) < 1e-6
