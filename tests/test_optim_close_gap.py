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


def _aside(scene, sc, p, m, cam, move):
    """The hand moved ``move`` normalised object units across its camera ray (sideways)."""
    eye = cam.center.double()
    with torch.no_grad():
        v = sc.model(p).vertices[0] / m
    ray = v.mean(0) - eye
    side = torch.linalg.cross(ray, torch.tensor([0.0, 1.0, 0.0], dtype=ray.dtype))
    side = side / side.norm()
    return replace(p, transl=p.transl + (move * scene.extent * m) * side[None])


def test_a_hand_beside_its_object_is_met_by_the_object_and_keeps_its_pixels(box, monkeypatch):
    """optim.close_gap.meet: the object moves onto a hand a little beside it (the camera with
    the hand, so every keypoint stays on its pixel), by the smallest move that makes them touch
    in the direction that shifts it least in the photo; no move along the rays could (close_gap
    leaves it)."""
    from easyhoi.optim import close_gap as close_gap_module
    from easyhoi.optim.close_gap import MEET_MAX_M, meet, moved_with_camera

    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    res, target = cfg.sdf_resolution, 0.5 * cfg.penetration_threshold
    limit = min(PUSH_OUT_MAX, MEET_MAX_M / (m * float(scene.extent)))
    aside = _aside(scene, sc, p, m, cam, -0.1)
    gap = _nearest(scene, sc, aside, m, res)
    assert target < gap < limit
    k, _ = close_gap(scene, aside, m, cam, res, target, PUSH_OUT_MAX)
    assert k == 1.0  # no move along the rays makes it touch
    delta, note = meet(scene, aside, m, cam, res, target, PUSH_OUT_MAX)
    assert delta is not None and note["moved"] and note["gap_before"] == pytest.approx(gap)
    met, cam2 = moved_with_camera(aside, m, cam, delta)
    d = _nearest(scene, sc, met, m, res)
    assert target - 1e-3 <= d <= target and d == pytest.approx(note["gap_after"], abs=1e-9)
    # the photo sees the same hand through the moved camera; the camera moved with it
    moved = (_pixels(sc, met, m, cam2) - _pixels(sc, aside, m, cam)).norm(dim=1)
    assert float(moved.max()) < 1e-6
    assert torch.allclose(cam2.center.double() - cam.center.double(), delta, atol=1e-9)
    # at least the gap, at most the limit
    assert gap * 0.99 <= note["distance"] <= limit
    assert note["distance_cm"] == pytest.approx(note["distance"] * scene.extent * m * 100)
    # the object's centre moves in the photo by the reported shift, and no more than the move
    # along the surface normal alone would move it
    centre = scene.object_verts.double().mean(0)[None]
    shift = float((cam2.project(centre)[0] - cam.project(centre)[0]).norm())
    assert shift == pytest.approx(note["shift_px"], abs=1e-6)
    monkeypatch.setattr(close_gap_module, "MEET_RAY_MIX", (0.0,))
    _, normal_only = meet(scene, aside, m, cam, res, target, PUSH_OUT_MAX)
    assert normal_only["moved"] and note["shift_px"] <= normal_only["shift_px"] + 1e-9


def test_meet_leaves_touching_far_and_too_distant_hands(box):
    from easyhoi.optim.close_gap import MEET_MAX_M, meet

    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    res, target = cfg.sdf_resolution, 0.5 * cfg.penetration_threshold
    # touching or penetrating: nothing to close
    eye = cam.center.double()
    sunk, m_sunk = _along_rays(p, m, eye, _k_for(scene, sc, p, m, eye, 0.08))
    assert _nearest(scene, sc, sunk, m_sunk, res) <= target
    delta, note = meet(scene, sunk, m_sunk, cam, res, target, PUSH_OUT_MAX)
    assert delta is None and not note["moved"]
    limit = min(PUSH_OUT_MAX, MEET_MAX_M / (m * float(scene.extent)))
    far = _aside(scene, sc, p, m, cam, -(3 * limit + 0.05))
    assert _nearest(scene, sc, far, m, res) > limit + target
    delta, note = meet(scene, far, m, cam, res, target, PUSH_OUT_MAX)
    assert delta is None and not note["moved"]
    # the metric cap: with a smaller max_move the same small gap is too far
    aside = _aside(scene, sc, p, m, cam, -0.1)
    gap = _nearest(scene, sc, aside, m, res)
    delta, note = meet(scene, aside, m, cam, res, target, 0.5 * (gap - target))
    assert delta is None and not note["moved"]


def test_refinement_meets_a_hand_beside_its_object(box):
    """fit_refine with close_gap on a hand beside the object (no move along the rays reaches it)
    ends touching, through a moved camera in which its keypoints are where the same refinement
    without the closing puts them in the original camera."""
    from easyhoi.optim.refine import fit_refine

    sc, scene, cam, cfg = box
    p, m = sc.gt_hand.to(dtype=torch.float64), sc.gt_metric_scale
    aside = _aside(scene, sc, p, m, cam, -0.1)
    optim_cfg = get_preset("fast").optim
    quick = replace(cfg, max_iters=8, patience=0, resolution_schedule=(0.5,))
    p0, r0 = fit_refine(scene, aside, m, cam, replace(quick, close_gap=False), optim_cfg)
    p1, r1 = fit_refine(scene, aside, m, cam, replace(quick, close_gap=True), optim_cfg)
    assert _nearest(scene, sc, p0, r0.metric_scale, cfg.sdf_resolution) > 0.01  # left beside
    d1 = _nearest(scene, sc, p1, r1.metric_scale, cfg.sdf_resolution)
    assert cfg.penetration_threshold - 1e-3 <= d1 <= 0.0
    note = r1.extra["close_gap"]
    assert not note["moved"] and note["meet"]["moved"]
    assert float((r1.camera.t - cam.t).norm()) > 0 and torch.equal(r0.camera.t, cam.t)
    diff = _pixels(sc, p1, r1.metric_scale, r1.camera) - _pixels(sc, p0, r0.metric_scale, cam)
    assert float(diff.norm(dim=1).max()) < 1e-6


def test_the_result_reports_how_far_the_object_was_moved_onto_the_hand():
    from types import SimpleNamespace

    from easyhoi.optim.run import _object_moved_to_hand_cm

    def stage(name, note):
        return SimpleNamespace(name=name, extra={"close_gap": note} if note else {})

    met = {"moved": False, "meet": {"moved": True, "distance_cm": 1.25}}
    assert _object_moved_to_hand_cm([stage("contact", None), stage("refine", met)]) == 1.25
    left = {"moved": False, "meet": {"moved": False}}
    assert _object_moved_to_hand_cm([stage("refine", left)]) is None
    assert _object_moved_to_hand_cm([stage("refine", {"moved": True})]) is None
    assert _object_moved_to_hand_cm([stage("refine", None)]) is None
