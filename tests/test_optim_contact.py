"""Stage 2 (contact alignment) on synthetic scenes with the ground-truth object camera."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from easyhoi.config import get_preset
from easyhoi.optim.contact import ContactState, fit_contact, initial_hand
from easyhoi.optim.registration import contact_points, register_contacts
from easyhoi.optim.state import Scene
from easyhoi.testing.optim_scenes import make_scene

SIZE = 96
NOISE = dict(rot_noise=0.05, trans_noise=0.02, depth_noise=0.05, pose_noise=0.03)


def _setup(kind, hand, **noise):
    sc = make_scene(kind, size=SIZE, **noise)
    scene = Scene.from_input(sc.inp, hand, torch.float32)
    cfg = replace(get_preset("fast").optim, render_size=SIZE)
    cam = sc.gt_camera.to(torch.float32)
    return sc, scene, cfg, cam


def _gt_verts(sc, hand):
    return hand(sc.gt_hand.to(dtype=torch.float32)).vertices[0] / sc.gt_metric_scale


def test_initial_hand_reproduces_the_estimate_in_the_object_camera(hand):
    """Without estimator noise the placement is exact up to the (unknown) metric scale."""
    sc, scene, cfg, cam = _setup("cylinder", hand, rot_noise=0, trans_noise=0, depth_noise=0,
                                 pose_noise=0)  # fmt: skip
    p, m, note = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, sc.gt_metric_scale)
    err = float((st.verts_obj().detach() - _gt_verts(sc, hand)).norm(dim=-1).max())
    assert err < 1e-3  # object units (2 units = 10 cm): < 0.05 mm
    assert note["overlap_pixels"] > 0
    assert abs(m / sc.gt_metric_scale - 1.0) < 0.15  # depth from the photo's occlusions


@pytest.mark.parametrize("kind", ["cylinder", "box"])
def test_contact_stage_brings_hand_into_contact(kind, hand):
    """These toy scenes touch at ONE point (the object is pushed until the closest hand vertex
    meets it), the closest-vertex depth scan's model (scan_band 0); the contact-band scan of the
    fast preset, made for grasps whose contact zones lie on the object, is tested on a held
    synthetic grasp below. The start is 30 % off in depth, which the placement's wide scan
    corrects in a run; here the stage's own scans must, so they are as wide and as strict as
    the placement's (rescan_range 2, no tie margin: the fast preset's re-scan margin is in
    units of the contact-band term, not of the closest vertex's distance)."""
    sc, scene, cfg, cam = _setup(kind, hand, **NOISE)
    cfg = replace(
        cfg, contact=replace(cfg.contact, scan_band=0.0, rescan_range=2.0, rescan_tie_margin=0.0)
    )
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, 0.7 * m)  # a start at the wrong depth (off the object)
    gt = _gt_verts(sc, hand)
    v0 = st.verts_obj().detach()
    d0 = float(scene.sdf(v0, 48).min()) * scene.extent * sc.gt_metric_scale  # metres
    err0 = float((v0 - gt).norm(dim=-1).mean()) * sc.gt_metric_scale
    res = fit_contact(scene, st, cfg.contact, cfg)
    v = hand(res.hand_params).vertices[0] / res.metric_scale
    np.testing.assert_allclose(v.detach().numpy(), st.verts_obj().detach().numpy(), atol=1e-4)
    d = float(scene.sdf(v.detach(), 48).min()) * scene.extent * sc.gt_metric_scale
    err = float((v.detach() - gt).norm(dim=-1).mean()) * sc.gt_metric_scale
    first, last = res.losses[0], res.losses[-1]
    assert abs(d0) > 0.01  # the start is 1 cm or more away from touching
    assert abs(d) < 0.004, (d0, d)  # touching within 4 mm
    assert err < 0.6 * err0 and err < 0.03, (err0, err)
    assert res.extra["final_mask_iou"] > 0.85
    assert last["iou"] < first["iou"]
    assert len(res.extra["registrations"]) == 2
    assert abs(res.metric_scale / sc.gt_metric_scale - 1.0) < 0.15


def test_rotation_prior_keeps_the_estimators_rotation(hand):
    """Stage 2's prior w * ||r||^2 keeps the hand's rotation relative to the camera."""
    sc, scene, cfg, cam = _setup("cylinder", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    angles = {}
    for w in (0.0, 100.0):
        c = replace(cfg.contact, rotation_prior_weight=w, max_iters=40, register_at=(),
                    patience=0, stop_loss=0.0)  # fmt: skip
        st = ContactState(scene, p, cam, m)
        res = fit_contact(scene, st, c, cfg)
        angles[w] = float(st.r.detach().norm())
        assert ("rot_prior" in res.losses[-1]) == (w > 0)
    assert cfg.contact.rotation_prior_weight == 100.0  # the fast preset uses it
    assert get_preset("paper").optim.contact.rotation_prior_weight == 0.0  # the paper: free
    assert angles[0.0] > 0.02  # the mask alone turns the hand by more than a degree
    assert angles[100.0] < 0.25 * angles[0.0], angles


def test_registration_icp_is_iterative(hand):
    """The ICP is a real iteration: on partial overlaps it beats one centroid shift."""
    from scipy.spatial import cKDTree

    sc, scene, cfg, cam = _setup("cylinder", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, m * 0.8)  # push the hand off the object along the rays
    masks = scene.masks_at(SIZE, SIZE)
    args = (scene, st.verts_obj().detach(), cam.resized(SIZE, SIZE), masks, cfg.contact)
    src, tgt, _ = contact_points(*args)
    D, anchor, info = register_contacts(*args)
    assert D is not None and len(src) >= 10 and len(src) == len(tgt)
    np.testing.assert_allclose(anchor, src.mean(axis=0))
    assert info["icp_iterations"] > 1
    assert info["rmse_last"] < info["rmse_first"]
    tree = cKDTree(tgt)
    rmse = lambda t: float(np.sqrt(np.mean(tree.query(src + t)[0] ** 2)))  # noqa: E731
    shift = tgt.mean(axis=0) - src.mean(axis=0)  # the reference's single update
    np.testing.assert_allclose(shift, info["centroid_shift"])
    assert rmse(D) == pytest.approx(info["rmse_last"], rel=1e-6)
    assert rmse(D) < 0.95 * rmse(shift)


def test_depth_registration_keeps_the_projection(hand):
    """A registration move along the camera ray changes the metric scale, not the image."""
    sc, scene, cfg, cam = _setup("box", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, m)
    v0 = st.verts_obj().detach()
    uv0, _ = cam.project(v0)
    anchor = v0.mean(0).double().numpy()
    ray = anchor - cam.center.double().numpy()
    D = 0.2 * ray / np.linalg.norm(ray)
    out = st.apply_translation(D, anchor, use_scale=True)
    v1 = st.verts_obj().detach()
    uv1, _ = cam.project(v1)
    assert float((uv1 - uv0).norm(dim=-1).max()) < 1e-2
    assert out["scale_factor"] != pytest.approx(1.0)
    moved = v1.mean(0).double().numpy() - anchor  # the map is affine: the centroid follows
    np.testing.assert_allclose(moved, D, atol=1e-4)
    # without scale the same move is a pure translation of every vertex
    st2 = ContactState(scene, p, cam, m)
    st2.apply_translation(D, anchor, use_scale=False)
    np.testing.assert_allclose((st2.verts_obj().detach() - v0).double().numpy(),
                               np.broadcast_to(D, v0.shape), atol=1e-4)  # fmt: skip


@pytest.mark.parametrize("side", ["right", "left"])
def test_move_hand_is_a_rigid_motion_of_the_vertices(side, hand):
    from easyhoi.geometry.transforms import axis_angle_to_matrix
    from easyhoi.optim.placement import move_hand, rest_wrist
    from easyhoi.structures import HandParams

    g = torch.Generator().manual_seed(3)
    p = HandParams(torch.randn(1, 3, generator=g), torch.randn(1, 3, generator=g) * 0.1,
                   torch.randn(1, 45, generator=g) * 0.2, side=side)  # fmt: skip
    R = axis_angle_to_matrix(torch.tensor([0.3, -0.5, 0.9]))
    t = torch.tensor([0.1, -0.2, 0.3])
    q = move_hand(p, R, t, rest_wrist(hand, p.betas))
    assert q.side == side
    want = hand(p).vertices[0] @ R.T + t
    torch.testing.assert_close(hand(q).vertices[0], want, atol=1e-5, rtol=0)


def test_scan_scale_tie_margin_prefers_the_nearest_depth(hand):
    """Margin 0: the best-scoring depth; a margin covering every candidate: the start depth
    (factor 1); a margin just above the start's deficit: still the start, just below: not."""
    from easyhoi.optim.contact import SCALE_SCAN, scan_scale

    sc, scene, cfg, cam = _setup("cylinder", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    verts = hand(p).vertices[0].detach()
    m0 = 0.6 * m  # off the object: factor 1 is not the best depth
    m_best, s_best = scan_scale(scene, verts, cam, m0, 48, SIZE)
    m_near, s_near = scan_scale(scene, verts, cam, m0, 48, SIZE, tie_margin=10.0)
    assert abs(m_best / m0 - 1.0) > 0.05 and s_near > s_best
    assert m_near == pytest.approx(m0, rel=1e-12)  # factor 1.0 is in the scan
    assert min(SCALE_SCAN, key=lambda f: abs(np.log(f))) == pytest.approx(1.0, rel=1e-12)
    gap = s_near - s_best
    assert scan_scale(scene, verts, cam, m0, 48, SIZE, gap + 1e-9)[0] == pytest.approx(m0)
    m_less, s_less = scan_scale(scene, verts, cam, m0, 48, SIZE, gap - 1e-6)
    assert m_less != pytest.approx(m0) and s_less <= s_best + gap - 1e-6


@pytest.fixture(scope="module")
def held_grasp():
    """A held synthetic grasp (the benchmark's first scene), its input and the GT object camera."""
    from easyhoi.synth.benchmark import BenchmarkSettings
    from easyhoi.synth.evaluate import gt_hand_state
    from easyhoi.synth.perturb import get_perturbation
    from easyhoi.synth.scene import make_scene as make_synth_scene

    st = BenchmarkSettings()
    s = make_synth_scene(0, "cylinder", "power", image_size=st.image_size, hold=True)
    inp = s.to_hoi_input(get_perturbation(st.perturbation), seed=0)
    _, m_gt, cam = gt_hand_state(s, inp)
    scene = Scene.from_input(inp, s.hand_model, torch.float32)
    return s, inp, scene, cam.to(torch.float32), m_gt


def test_scan_band_finds_the_grasp_depth_of_a_held_grasp(held_grasp):
    """On a real grasp (contact zones on the surface) the contact-band scan recovers the metric
    scale from starts 30 % too small or 40 % too large (the closest-vertex scan: 14 % off), and
    its score is the naive recomputation: (1 - IoU) + mean over the contact zones of
    min(|d|, band) / band at the chosen depth."""
    from easyhoi.optim.contact import scan_scale
    from easyhoi.render.raster import depth_map

    s, inp, scene, cam, m_gt = held_grasp
    size = get_preset("fast").optim.render_size
    p, _, _ = initial_hand(scene, inp, cam, size)
    verts = s.hand_model(p).vertices[0].detach()
    found = {
        (band, f): scan_scale(scene, verts, cam, f * m_gt, 48, size, band=band)
        for band in (0.0, 0.02)
        for f in (0.7, 1.4)
    }
    errs = {k: abs(m / m_gt - 1) for k, (m, _) in found.items()}
    band_errs = [errs[0.02, f] for f in (0.7, 1.4)]
    assert min(errs[0.0, f] for f in (0.7, 1.4)) > 0.1 > 0.05 > max(band_errs), errs
    m, score = found[0.02, 0.7]
    h, w = scene.render_size(0.5, size)
    c = cam.resized(w, h)
    v = (verts / m - c.t) @ c.R
    with torch.no_grad():
        zh = depth_map(v, s.hand_model.faces, c)
        vis = torch.isfinite(zh) & (zh <= scene.object_depth(c))
        target = scene.masks_at(h, w)["hand"] > 0.5
        iou = float((vis & target).sum()) / float((vis | target).sum())
        d = scene.sdf(v, 48)[scene.regions.contact_vertices].numpy()
    naive = (1 - iou) + float(np.mean([min(abs(x), 0.02) for x in d])) / 0.02
    assert score == pytest.approx(naive, abs=1e-5)


def test_depth_only_registration_keeps_the_hand_on_its_silhouette(hand):
    """With depth_only the in-plane part of a registration is dropped: same pixels, new m."""
    sc, scene, cfg, cam = _setup("box", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, m)
    v0 = st.verts_obj().detach()
    uv0, _ = cam.project(v0)
    anchor = v0.mean(0).double().numpy()
    ray = anchor - cam.center.double().numpy()
    side = np.cross(ray, [0.0, 1.0, 0.0])
    D = 0.2 * ray / np.linalg.norm(ray) + 0.3 * side / np.linalg.norm(side)
    delta0 = st.delta.detach().clone()
    out = st.apply_translation(D, anchor, use_scale=True, depth_only=True)
    uv1, _ = cam.project(st.verts_obj().detach())
    assert float((uv1 - uv0).norm(dim=-1).max()) < 1e-2
    assert torch.equal(st.delta.detach(), delta0) and out["shift_m"] == 0.0
    assert out["scale_factor"] != pytest.approx(1.0)


@pytest.mark.slow
def test_score_band_keeps_a_held_grasp_on_the_object(held_grasp):
    """From the held grasp at its true depth, the stage scored by the contact band ends with
    the contact zones on the surface about as well as it began, and the score it records is
    the band term; scored by the closest vertex, it backs the hand off instead (its contact
    zones end farther from the surface)."""
    from easyhoi.optim.contact import _touch

    s, inp, scene, cam, m_gt = held_grasp
    fast = get_preset("fast").optim
    # the mask fit alone (no keypoint terms), whose drift the two scores judge differently
    short = dict(max_iters=40, register_at=(10,), patience=10, keypoint_weight=0.0)
    ends = {}
    for score_band in (True, False):
        cfg = replace(fast, contact=replace(fast.contact, score_band=score_band, **short))
        p, _, _ = initial_hand(scene, inp, cam, fast.render_size, cfg.contact)
        st = ContactState(scene, p, cam, m_gt)
        start = _touch(scene, st.verts_obj().detach(), 48, 0.02)
        res = fit_contact(scene, st, cfg.contact, cfg)
        v = s.hand_model(res.hand_params).vertices[0].detach() / res.metric_scale
        ends[score_band] = _touch(scene, v, 48, 0.02)
        if score_band:
            # the stage's score is mask fit + rotation prior + band term, so the band term alone
            # may give back a hundredth of a band for a better mask fit
            assert ends[True] <= start + 0.01
            assert abs(res.metric_scale / m_gt - 1) < 0.1
    assert ends[True] < ends[False], ends


def test_contact_band_term_sees_a_hand_off_the_object(hand):
    """The band term is the naive mean of min(|d|, band) / band over the contact zones, plus,
    when no contact zone lies in the band, the closest one's distance beyond it (in bands): a
    hand moved off the object scores worse the farther it is, where the band term alone is
    flat (every contact zone clamped; the toy hand touches with one vertex outside the contact
    zones, so none is in the band even at its true place)."""
    from easyhoi.optim.contact import _touch

    sc, scene, _, _ = _setup("box", hand)
    gt = _gt_verts(sc, hand)
    away = gt.mean(0) - scene.center
    away = away / away.norm()
    band, scores = 0.02, []
    for shift in (0.0, 0.1, 0.2, 0.3):  # normalised object units
        v = gt + shift * scene.extent * away
        got = _touch(scene, v, 48, band)
        d = scene.sdf(v, 48)[scene.regions.contact_vertices].abs().tolist()
        naive = sum(min(x, band) for x in d) / len(d) / band + max(min(d) - band, 0.0) / band
        assert got == pytest.approx(naive, rel=1e-5)
        scores.append(got)
    assert scores[0] < scores[1] < scores[2] < scores[3], scores


def test_contact_keypoints_project_like_the_returned_hand(hand):
    """The stage's keypoints are those of the hand it returns, through the object camera, and
    the metric scale (a move along the camera rays) does not change them."""
    sc, scene, cfg, cam = _setup("cylinder", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    st = ContactState(scene, p, cam, m)
    with torch.no_grad():
        st.r.copy_(torch.tensor([0.1, -0.2, 0.05]))
        st.delta.copy_(torch.tensor([0.03, -0.02, 0.01]))
    H, W = scene.image_size
    uv = st.keypoints_uv(W, H).detach()
    for scale in (st.m, 1.3 * st.m):
        st.m = scale
        k = hand(st.hand_params()).keypoints[0] / st.m
        ref, _ = cam.resized(W, H).project(k)
        np.testing.assert_allclose(uv.numpy(), ref.detach().numpy(), atol=1e-3)


def test_keypoint_term_holds_the_hand_where_the_detector_saw_it(hand):
    """A hand mask shifted off the hand (a mask that is wrong, as on real photos) drags the
    rigid mask fit with it; the detector's keypoints hold the hand in place. (The best state
    is judged by the closest vertex's contact, not the contact band: a hand moved sideways off
    this toy object's one touching point would lose to the start by the band's score.)"""
    from easyhoi.optim.state import PhotoKeypoints

    sc, scene, cfg, cam = _setup("cylinder", hand, rot_noise=0, trans_noise=0, depth_noise=0,
                                 pose_noise=0)  # fmt: skip
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    H, W = scene.image_size
    truth = ContactState(scene, p, cam, m).keypoints_uv(W, H).detach()
    scene.keypoints = PhotoKeypoints(truth, torch.ones(21), float(np.ptp(truth.numpy(), 0).max()))
    shift = 6  # pixels to the right
    scene.masks = dict(scene.masks, hand=torch.roll(scene.masks["hand"], shift, dims=1))
    scene._mask_cache.clear()
    moved = {}
    for w in (0.0, 8.0):
        c = replace(cfg.contact, keypoint_weight=w, keypoint_drift_weight=w / 2, max_iters=150,
                    register_at=(), patience=0, stop_loss=0.0, score_band=False)  # fmt: skip
        st = ContactState(scene, p, cam, m)
        res = fit_contact(scene, st, c, cfg)
        du = (st.keypoints_uv(W, H).detach() - truth)[:, 0].mean()
        moved[w] = float(du)
        assert ("keypoints" in res.losses[-1]) == (w > 0)
    assert moved[0.0] > 0.4 * shift, moved  # the mask alone follows the shifted mask
    assert abs(moved[8.0]) < 0.25 * moved[0.0], moved


@pytest.mark.parametrize("band", [0.0, 0.02])
def test_scan_scale_matches_rendering_every_candidate(hand, band):
    """The scan renders one z-buffer and scales its depths by m0 / m; the naive scan renders the
    hand at every candidate depth. Same scores, same choice."""
    import math

    from easyhoi.optim.contact import SCALE_SCAN, _touch, scan_scale
    from easyhoi.render.raster import depth_map

    sc, scene, cfg, cam = _setup("cylinder", hand, **NOISE)
    p, m, _ = initial_hand(scene, sc.inp, cam, SIZE)
    verts = hand(p).vertices[0].detach()
    m0 = 0.8 * m
    h, w = scene.render_size(0.5, SIZE)
    c = cam.detach().to(scene.dtype).resized(w, h)
    target = scene.masks_at(h, w)["hand"] > 0.5
    zo = scene.object_depth(c)
    naive = []
    for f in SCALE_SCAN:
        v = (verts / (m0 * f) - c.t) @ c.R
        zh = depth_map(v, scene.hand_model.faces, c)
        vis = torch.isfinite(zh) & (zh <= zo)
        iou = float((vis & target).sum()) / max(1, int((vis | target).sum()))
        naive.append(((1.0 - iou) + _touch(scene, v, 48, band), abs(math.log(f)), m0 * f))
    s_ref, _, m_ref = min(naive)
    m_got, s_got = scan_scale(scene, verts, cam, m0, 48, SIZE, band=band)
    assert m_got == pytest.approx(m_ref, rel=1e-12)
    assert s_got == pytest.approx(s_ref, abs=1e-6)
    assert len({round(s, 6) for s, _, _ in naive}) > 5  # the candidates differ: the test bites


def test_contact_band_term_looks_up_the_zones_alone_with_the_same_values(hand):
    """The band term queries the SDF at the contact-zone vertices only: the same numbers, to
    the bit, as the lookup of every vertex taken at those vertices (the SDF is per point)."""
    from easyhoi.optim.contact import _touch_batch

    sc, scene, _, _ = _setup("box", hand)
    gt = _gt_verts(sc, hand)
    batch = torch.stack([gt * s for s in (0.9, 1.0, 1.1)])
    band = 0.02
    got = _touch_batch(scene, batch, 48, band)
    d = scene.sdf(batch.reshape(-1, 3), 48).reshape(3, -1)
    near = d[:, scene.regions.contact_vertices].abs()
    beyond = (near.min(dim=1).values - band).clamp_min(0.0)
    assert torch.equal(got, (near.clamp_max(band).mean(dim=1) + beyond) / band)
