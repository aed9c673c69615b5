"""GrabCut's colour models (:func:`easyhoi.perception.skin.gmm_model`) against clusters of known
parameters, and GrabCut (:func:`easyhoi.perception.skin.grabcut`) on a drawn object: right and the
same whatever the random generator's seed."""

from __future__ import annotations

import cv2
import numpy as np

from easyhoi.perception.skin import GMM_COMPONENTS, gmm_model, grabcut

MEANS = np.array([[30, 40, 200], [200, 30, 40], [40, 200, 30], [220, 220, 60], [90, 90, 90]], float)
SIGMAS = np.array([3.0, 5.0, 4.0, 6.0, 2.0])
COUNTS = np.array([4000, 2500, 1500, 1200, 800])


def clusters(rng):
    return np.concatenate([
        m + s * rng.standard_normal((n, 3)) for m, s, n in zip(MEANS, SIGMAS, COUNTS, strict=True)
    ])  # fmt: skip


def unpack(model):
    k = GMM_COMPONENTS
    v = model.ravel()
    return v[:k], v[k : 4 * k].reshape(k, 3), v[4 * k :].reshape(k, 3, 3)


def test_gmm_model_recovers_known_clusters_at_every_seed():
    x = clusters(np.random.default_rng(1))
    for seed in range(4):
        model = gmm_model(x, seed)
        assert model.shape == (1, 65)
        w, mu, cov = unpack(model)
        order = [int(np.argmin(((mu - m) ** 2).sum(1))) for m in MEANS]
        assert sorted(order) == list(range(GMM_COMPONENTS))  # one component per cluster
        # the model is made of a regular subsample of 2000: weights to a sampling step, means to
        # about four standard errors of a few hundred samples
        np.testing.assert_allclose(w[order], COUNTS / COUNTS.sum(), atol=0.01)
        np.testing.assert_allclose(mu[order], MEANS, atol=1.5)
        for j, s in zip(order, SIGMAS, strict=True):
            np.testing.assert_allclose(cov[j], s**2 * np.eye(3), atol=0.25 * s**2 + 0.5)


def test_gmm_model_of_too_few_samples_is_left_to_opencv():
    assert gmm_model(np.zeros((2 * GMM_COMPONENTS - 1, 3)), 0) is None


def test_gmm_model_regularises_a_single_colour():
    w, mu, cov = unpack(gmm_model(np.full((500, 3), 77.0), 0))
    assert np.isclose(w.sum(), 1.0)
    used = w > 0
    np.testing.assert_allclose(mu[used], 77.0)
    for c in cov[used]:  # a flat cluster gets OpenCV's 0.01 on its diagonal, so it is invertible
        np.testing.assert_allclose(c, 0.01 * np.eye(3), atol=1e-9)


def drawn_scene(size=120):
    """A two-coloured disk (object) on a background of four colour patches with noise."""
    rng = np.random.default_rng(3)
    img = np.zeros((size, size, 3))
    h = size // 2
    corners = [(0, 0), (0, h), (h, 0), (h, h)]
    colours = [(60, 120, 60), (150, 150, 160), (90, 60, 30), (200, 190, 150)]
    for (r, c), col in zip(corners, colours, strict=True):
        img[r : r + h, c : c + h] = col
    yy, xx = np.mgrid[:size, :size]
    disk = (yy - h) ** 2 + (xx - h) ** 2 < (size // 4) ** 2
    img[disk & (yy < h)] = (200, 40, 40)
    img[disk & (yy >= h)] = (40, 40, 200)
    img = np.clip(img + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8)
    init = np.full((size, size), cv2.GC_BGD, np.uint8)
    init[(yy - h) ** 2 + (xx - h) ** 2 < (size // 3) ** 2] = cv2.GC_PR_BGD
    init[disk] = cv2.GC_PR_FGD
    init[(yy - h) ** 2 + (xx - h) ** 2 < 5**2] = cv2.GC_FGD
    return img, init, disk


def test_grabcut_finds_the_drawn_object_the_same_at_every_seed():
    img, init, disk = drawn_scene()
    # a start that overshoots the object by a band of background
    yy, xx = np.mgrid[: disk.shape[0], : disk.shape[1]]
    init[((yy - 60) ** 2 + (xx - 60) ** 2 < 36**2) & (init == cv2.GC_PR_BGD)] = cv2.GC_PR_FGD
    masks = [grabcut(img, init, 3, seed) for seed in range(4)]
    for m in masks:
        iou = (m & disk).sum() / (m | disk).sum()
        assert iou > 0.95
    for m in masks[1:]:
        assert (m != masks[0]).sum() == 0


def patchwork_scene(seed, size=120):
    """A three-coloured disk on 16 background patches of random colours, with noise: more
    colours than GrabCut's five clusters, so how k-means groups them is not obvious."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    img = rng.uniform(0, 255, (16, 3))[(yy // 30) * 4 + xx // 30]
    h = size // 2
    disk = (yy - h) ** 2 + (xx - h) ** 2 < (size // 4) ** 2
    sector = ((np.arctan2(yy - h, xx - h) + np.pi) / (2 * np.pi) * 3).astype(int) % 3
    img[disk] = rng.uniform(0, 255, (3, 3))[sector[disk]]
    img = np.clip(img + rng.normal(0, 8, img.shape), 0, 255).astype(np.uint8)
    init = np.full((size, size), cv2.GC_BGD, np.uint8)
    init[(yy - h) ** 2 + (xx - h) ** 2 < 38**2] = cv2.GC_PR_FGD
    init[(yy - h) ** 2 + (xx - h) ** 2 < 5**2] = cv2.GC_FGD
    return img, init, disk


def opencv_own_start(img, init, iterations, seed):
    """The reference: GrabCut started by OpenCV's own single k-means run."""
    cv2.setRNGSeed(seed)
    m = init.copy()
    cv2.grabCut(img, m, None, np.zeros((1, 65)), np.zeros((1, 65)), iterations,
                cv2.GC_INIT_WITH_MASK)  # fmt: skip
    return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)


def test_grabcut_depends_on_the_seed_far_less_than_opencvs_own_start():
    def measure(fn):
        varying, ious = 0, []
        for scene in range(100, 120):
            img, init, disk = patchwork_scene(scene)
            masks = [fn(img, init, 3, seed) for seed in range(4)]
            varying += any((m != masks[0]).any() for m in masks)
            ious += [(m & disk).sum() / (m | disk).sum() for m in masks]
        return varying, float(np.mean(ious))

    ours, ours_iou = measure(grabcut)
    own, own_iou = measure(opencv_own_start)
    assert own >= 8  # the scenes are ones where one k-means start decides (11 of 20)
    assert ours <= 5  # 3 of 20 with the most compact of several starts
    assert ours_iou > own_iou - 0.02  # and the outlines are as good (0.860 against 0.863)
