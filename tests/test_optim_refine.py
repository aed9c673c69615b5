"""Stage 3 (refinement): penetration removed, mask and pose kept; every term's gradient sign."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from easyhoi.config import get_preset
from easyhoi.optim.refine import fit_refine, refine_terms
from easyhoi.optim.run import plausibility
from easyhoi.optim.state import Scene
from easyhoi.structures import HandParams
from easyhoi.testing.optim_scenes import make_scene

SIZE = 96


@pytest.fixture(scope="module")
def box_scene(hand):
    sc = make_scene("box", size=SIZE)
    scene = Scene.from_input(sc.inp, hand, torch.float32)
    cfg = replace(get_preset("fast").optim, render_size=SIZE)
    return sc, scene, cfg


def _pushed(sc, scene, hand, dist):
    """The ground-truth hand moved by ``dist`` metres towards the object's centre."""
    gt = sc.gt_hand.to(dtype=torch.float32)
    wc = hand(gt).vertices[0].mean(0)
    oc = scene.center * sc.gt_metric_scale
    d = (oc - wc) / (oc - wc).norm()
    return HandParams(gt.global_orient, gt.transl + dist * d, gt.pose), d


@pytest.mark.parametrize("kind", ["cylinder", "box"])
def test_refine_removes_penetration(kind, hand):
    sc = make_scene(kind, size=SIZE)
    scene = Scene.from_input(sc.inp, hand, torch.float32)
    cfg = replace(get_preset("fast").optim, render_size=SIZE)
    # 1 cm in: the fast preset's grasp settles pressing ~2 mm into the object (its penetration
    # weight lets a grasp press, as a held object needs, its opposition radius pulls the thumb
    # and index onto the object, and its keypoint, prior and regularisation terms keep the
    # fingers' articulation: box 2.8 -> 2.4 mm deepest after the push-out took the hand out and
    # contact pressed it back), so the deepest vertex must come up, not to the surface
    p0, _ = _pushed(sc, scene, hand, 0.01)
    m, cam = sc.gt_metric_scale, sc.gt_camera.to(torch.float32)
    before = plausibility(scene, p0, m, cam, SIZE)
    p, res = fit_refine(scene, p0, m, cam, cfg.refine, cfg)
    after = plausibility(scene, p, m, cam, SIZE)
    assert before["penetration_depth_cm"] > 0.15 and before["intersection_volume_cm3"] > 0
    assert after["penetration_depth_cm"] < 0.9 * before["penetration_depth_cm"]
    assert after["penetration_depth_cm"] < 0.25
    assert after["intersection_volume_cm3"] <= before["intersection_volume_cm3"]  # 5 mm voxels
    assert after["in_contact"]
    assert after["hand_mask_iou"] > 0.8
    assert after["hand_mask_iou"] >= before["hand_mask_iou"] - 0.02
    assert float((p.pose - p0.pose).abs().sum()) < 2.0  # 45 angles, radians: stays near
    assert res.losses[-1]["total"] < res.losses[0]["total"]
    assert set(res.losses[0]) >= {"mask", "penetration", "contact", "reg", "total"}


def _grad(scene, params, m, cfg, cam, masks, theta0, **weights):
    zero = dict(hand_mask_weight=0.0, penetration_weight=0.0, contact_weight=0.0, reg_weight=0.0)
    rc = replace(cfg.refine, **{**zero, **weights})
    tr = params.transl.clone().requires_grad_(True)
    pose = params.pose.clone().requires_grad_(True)
    p = HandParams(params.global_orient, tr, pose)
    terms = refine_terms(scene, p, m, theta0, rc, cam, masks)
    terms["total"].backward()
    grad = lambda x: torch.zeros_like(x[0]) if x.grad is None else x.grad[0]  # noqa: E731
    return grad(tr), grad(pose), terms


def test_penetration_gradient_pushes_the_hand_out(box_scene, hand):
    sc, scene, cfg = box_scene
    p0, inward = _pushed(sc, scene, hand, 0.01)
    cam = sc.gt_camera.to(torch.float32).resized(SIZE, SIZE)
    g, _, terms = _grad(scene, p0, sc.gt_metric_scale, cfg, cam, None, p0.pose,
                        penetration_weight=1.0)  # fmt: skip
    assert float(terms["penetration"]) > 0
    assert float(-g @ inward) < 0  # descent moves the hand away from the object's centre


def test_contact_gradient_pulls_a_separated_hand_in(box_scene, hand):
    sc, scene, cfg = box_scene
    p0, inward = _pushed(sc, scene, hand, -0.01)  # 1 cm away from the object
    cam = sc.gt_camera.to(torch.float32).resized(SIZE, SIZE)
    g, _, terms = _grad(scene, p0, sc.gt_metric_scale, cfg, cam, None, p0.pose,
                        contact_weight=1.0, contact_max_distance=None)  # fmt: skip
    assert float(terms["contact"]) > 0
    assert float(-g @ inward) > 0  # descent moves the hand towards the object


def test_mask_gradient_moves_the_hand_back_onto_the_mask(box_scene, hand):
    sc, scene, cfg = box_scene
    gt = sc.gt_hand.to(dtype=torch.float32)
    cam = sc.gt_camera.to(torch.float32).resized(SIZE, SIZE)
    right = cam.R[0] * sc.gt_metric_scale  # image-right direction, metric object frame
    off = right / right.norm() * 0.01
    p0 = HandParams(gt.global_orient, gt.transl + off, gt.pose)
    masks = scene.masks_at(SIZE, SIZE)
    g, _, terms = _grad(scene, p0, sc.gt_metric_scale, cfg, cam, masks, p0.pose,
                        hand_mask_weight=1.0)  # fmt: skip
    assert float(terms["mask"]) > 0
    assert float(-g @ off) < 0  # descent moves it back (against the offset)


def test_reg_gradient_is_the_sign_of_the_deviation(box_scene, hand):
    sc, scene, cfg = box_scene
    gt = sc.gt_hand.to(dtype=torch.float32)
    theta0 = gt.pose + 0.1 * torch.sign(
        torch.randn(1, 45, generator=torch.Generator().manual_seed(1))
    )
    cam = sc.gt_camera.to(torch.float32).resized(SIZE, SIZE)
    _, gp, terms = _grad(scene, gt, sc.gt_metric_scale, cfg, cam, None, theta0, reg_weight=1.0)
    assert float(terms["reg"]) == pytest.approx(4.5, rel=1e-4)
    assert torch.equal(gp, torch.sign(gt.pose - theta0)[0])


def test_contact_term_is_rescaled_to_manos_contact_vertex_count(box_scene, hand):
    """contact = (115 / |C|) * sum over the contact zones of max(0, d), d < max distance."""
    from easyhoi.optim.losses import MANO_CONTACT_VERTICES, contact_loss

    sc, scene, cfg = box_scene
    p0, _ = _pushed(sc, scene, hand, -0.003)  # 3 mm off the object
    m = sc.gt_metric_scale
    only = dict(hand_mask_weight=0.0, penetration_weight=0.0, reg_weight=0.0, contact_weight=1.0)
    rc = replace(cfg.refine, **only, contact_max_distance=0.2, opposition_max_distance=None)
    assert rc.contact_reference_count == 115.0 == MANO_CONTACT_VERTICES
    got = float(refine_terms(scene, p0, m, p0.pose, rc, None, None)["contact"])
    # naive reference, vertex by vertex
    with torch.no_grad():
        d = scene.sdf(hand(p0).vertices[0] / m, rc.sdf_resolution)
    cv = scene.regions.contact_vertices.tolist()
    raw = sum(float(d[i]) for i in cv if 0.0 < float(d[i]) < rc.contact_max_distance)
    n_in = sum(0.0 < float(d[i]) < rc.contact_max_distance for i in cv)
    assert len(cv) == 285 and 0 < n_in < len(cv)  # OpenHand: 285 contact vertices
    assert got == pytest.approx(raw * 115.0 / len(cv), rel=1e-5)
    # None keeps the plain sum (the paper's term as written, for MANO-size contact zones)
    plain = replace(rc, contact_reference_count=None)
    assert float(refine_terms(scene, p0, m, p0.pose, plain, None, None)["contact"]) == (
        pytest.approx(raw, rel=1e-5)
    )
    # the rescaled term is resolution independent: duplicating every vertex changes nothing
    dc = d[scene.regions.contact_vertices]
    one = contact_loss(dc, rc.contact_max_distance, reference_count=115.0)
    two = contact_loss(torch.cat([dc, dc]), rc.contact_max_distance, reference_count=115.0)
    assert float(two) == pytest.approx(float(one), rel=1e-6)
    with pytest.raises(Exception, match="reference_count"):
        contact_loss(dc, reference_count=0.0)


def test_opposition_radius_attracts_only_thumb_and_index_from_farther(box_scene, hand):
    """With opposition_max_distance the thumb's and index's contact vertices are attracted
    from that far, the other contact vertices only within contact_max_distance."""
    from easyhoi.hand.regions import DIGIT_JOINTS
    from easyhoi.optim.refine import contact_radii

    sc, scene, cfg = box_scene
    p0, _ = _pushed(sc, scene, hand, -0.01)  # 1 cm off the object
    m = sc.gt_metric_scale
    only = dict(hand_mask_weight=0.0, penetration_weight=0.0, reg_weight=0.0, contact_weight=1.0)
    near, far = 0.05, 0.3
    rc = replace(cfg.refine, **only, contact_max_distance=near, opposition_max_distance=far)
    radii = contact_radii(scene, rc)
    cv = scene.regions.contact_vertices.tolist()
    part = scene.regions.vertex_part.tolist()
    opposing = {*DIGIT_JOINTS["thumb"], *DIGIT_JOINTS["index"]}
    expect = [far if part[i] in opposing else near for i in cv]
    assert radii.tolist() == pytest.approx(expect)
    assert 0 < sum(r == far for r in expect) < len(cv)  # both kinds present
    got = float(refine_terms(scene, p0, m, p0.pose, rc, None, None)["contact"])
    with torch.no_grad():
        d = scene.sdf(hand(p0).vertices[0] / m, rc.sdf_resolution)
    raw = sum(float(d[i]) for i, r in zip(cv, expect, strict=True) if 0.0 < float(d[i]) < r)
    assert got == pytest.approx(raw * 115.0 / len(cv), rel=1e-5)

    # the far radius attracts more than the near one alone, less than attracting everything
    def contact(**kw):
        return float(refine_terms(scene, p0, m, p0.pose, replace(rc, **kw), None, None)["contact"])

    plain = contact(opposition_max_distance=None)
    everything = contact(contact_max_distance=far, opposition_max_distance=None)
    assert plain < got < everything
    # unset contact_max_distance (the paper: all attracted) ignores the opposition radius
    assert contact_radii(scene, replace(rc, contact_max_distance=None)) is None


@pytest.mark.parametrize("lr", [1e-3, 4e-3])
def test_translation_steps_are_in_object_sizes(box_scene, hand, lr):
    # a hand pushed into the box, only the global pose free, no early stopping: each Adam step
    # moves every translation coordinate by at most ~lr object sizes (metres: lr * L * m)
    sc, scene, cfg = box_scene
    # 1 cm in, so the penetration term drives every step (6 mm in, with fast's penetration
    # weight 2000 the box scene's hand moved less than 0.5 lr per step at lr 1e-3)
    p0, _ = _pushed(sc, scene, hand, 0.01)
    m, cam = sc.gt_metric_scale, sc.gt_camera.to(torch.float32)
    # (every penetrating vertex counts, the pads too, so that the penetration term drives them)
    rc = replace(cfg.refine, lr_transl=lr, lr_global=1e-6, optimise_pose=False, patience=0,
                 max_iters=6, resolution_schedule=(1.0,), push_out_steps=0,
                 pad_tolerance_m=0.0)  # fmt: skip
    p, res = fit_refine(scene, p0, m, cam, rc, cfg)
    unit = scene.extent * m  # metres per object size
    moved = (p.transl - p0.transl).abs().max().item()
    assert 0.5 * lr * unit < moved <= 6 * lr * unit * 1.01
    assert res.losses[-1]["penetration"] < res.losses[0]["penetration"]


def test_rigid_first_moves_only_the_global_pose_in_the_first_phase(box_scene, hand):
    sc, scene, cfg = box_scene
    p0, _ = _pushed(sc, scene, hand, 0.005)
    m, cam = sc.gt_metric_scale, sc.gt_camera.to(torch.float32)
    # no push-out: the phases alone are under test
    rc = replace(cfg.refine, rigid_first=True, max_iters=6, patience=0,
                 resolution_schedule=(1.0,), push_out_steps=0)  # fmt: skip
    p, _ = fit_refine(scene, p0, m, cam, rc, cfg)
    assert torch.equal(p.pose, p0.pose.to(p.pose.dtype))  # one phase: the fingers never move
    assert float((p.transl - p0.transl).abs().max()) > 0
    rc2 = replace(rc, resolution_schedule=(0.5, 1.0), max_iters=12)
    p2, _ = fit_refine(scene, p0, m, cam, rc2, cfg)
    assert not torch.equal(p2.pose, p0.pose.to(p2.pose.dtype))  # the second phase bends them


def test_push_out_is_kept_only_when_the_stage_loss_falls(box_scene, hand):
    """The push-out judges its move by the summed penetration depth; the stage keeps the pushed
    hand only when its whole loss is lower there. With penetration counting, a hand 1 cm in
    is pushed out; with penetration weighing nothing, the same move only costs (contact, mask)
    and the hand stays where it was."""
    from easyhoi.optim.refine import _accept_push, push_out

    sc, scene, cfg = box_scene
    p0, _ = _pushed(sc, scene, hand, 0.01)
    m, cam = sc.gt_metric_scale, sc.gt_camera.to(torch.float32)
    kept = {}
    for w in (cfg.refine.penetration_weight, 0.0):
        rc = replace(cfg.refine, penetration_weight=w)
        push = push_out(scene, p0, m, rc, cam, as_scale=True)
        assert push[1]["steps"] >= 1  # the push-out itself moves the hand either way
        tr, m1 = _accept_push(scene, p0, m, p0.pose, cam, rc, cfg, push)
        note = push[1]
        kept[w] = note["kept"]
        assert note["kept"] == (note["loss_after"] < note["loss_before"])
        if note["kept"]:
            assert m1 != m and not torch.equal(tr, p0.transl)
        else:
            assert m1 == m and torch.equal(tr, p0.transl)
    assert kept == {cfg.refine.penetration_weight: True, 0.0: False}


def test_pad_tolerance_against_a_vertex_by_vertex_reference(box_scene, hand):
    """pad_tolerance_m: the contact-zone vertices count as penetrating only deeper than the
    tolerance (metres), the others from penetration_threshold; the term's gradient is -1/V at
    the vertices that count and 0 elsewhere."""
    sc, scene, cfg = box_scene
    m = sc.gt_metric_scale
    p0, _ = _pushed(sc, scene, hand, 0.004)  # 4 mm into the object
    only = dict(hand_mask_weight=0.0, reg_weight=0.0, keypoint_weight=0.0, prior_weight=0.0)
    base = replace(cfg.refine, **only, penetration_weight=1.0, contact_weight=1.0,
                   contact_max_distance=0.05, opposition_max_distance=None,
                   pad_tolerance_m=0.0)  # fmt: skip
    with torch.no_grad():
        d = scene.sdf(hand(p0).vertices[0] / m, base.sdf_resolution).double()
    unit = m * float(scene.extent)  # metres per normalised object unit
    pads = set(scene.regions.contact_vertices.tolist())
    tol = 0.002
    # naive references, vertex by vertex
    thr = [(min(-tol / unit, base.penetration_threshold) if i in pads
            else base.penetration_threshold) for i in range(len(d))]  # fmt: skip
    pen = sum(-float(v) for v, t in zip(d, thr, strict=True) if float(v) < t) / len(d)
    cv = scene.regions.contact_vertices.tolist()
    pads_in = sum(float(d[i]) < base.penetration_threshold for i in cv)
    pads_deep = sum(float(d[i]) < -tol / unit for i in cv)
    assert pads_deep < pads_in  # some pads lie within the tolerance: the cases differ
    rc = replace(base, pad_tolerance_m=tol)
    got = refine_terms(scene, p0, m, p0.pose, rc, None, None)
    assert float(got["penetration"]) == pytest.approx(pen, rel=1e-4)
    # off (0): the plain threshold for every vertex
    plain = refine_terms(scene, p0, m, p0.pose, base, None, None)
    ref = sum(-float(v) for v in d if float(v) < base.penetration_threshold) / len(d)
    assert float(plain["penetration"]) == pytest.approx(ref, rel=1e-4)
    assert float(plain["penetration"]) > float(got["penetration"])
    # the gradient: -1/V at every vertex that counts, 0 at the pads within the tolerance
    from easyhoi.optim.losses import penetration_loss
    from easyhoi.optim.refine import penetration_thresholds

    dd = d.clone().requires_grad_(True)
    penetration_loss(dd, penetration_thresholds(scene, rc, m, dd)).backward()
    want = torch.tensor([-1.0 / len(d) if float(v) < t else 0.0
                         for v, t in zip(d, thr, strict=True)],
                        dtype=torch.float64)  # fmt: skip
    assert torch.allclose(dd.grad, want)
    assert penetration_thresholds(scene, base, m, dd) == base.penetration_threshold
