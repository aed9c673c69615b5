"""A shaded RGB "photo" of a hand holding an object, from hard rasterizer fragments.

Shading: per-pixel normals interpolated from vertex normals with the rasterizer's
perspective-correct barycentrics, Lambert diffuse with one directional key light plus an ambient
term and a weak Blinn-Phong highlight; skin albedo from a palette of realistic tones with a
slight redness towards the fingertips; objects coloured with a procedural texture evaluated on
the 3D surface position in the object's frame (stripes, checker, bands: no UVs needed).
Background: a two-colour gradient with large blurred shapes (a table edge, blobs) and fine
noise. A screen-space soft shadow of the hand darkens what lies behind it; boundaries are
anti-aliased by blending a blurred copy along silhouette edges; sensor noise is added last.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Skin tones (sRGB 0-255), light to dark.
SKIN_TONES = (
    (241, 204, 181),
    (234, 189, 157),
    (224, 172, 138),
    (205, 150, 115),
    (186, 128, 94),
    (160, 106, 74),
    (125, 82, 56),
    (92, 60, 42),
)


@dataclass(frozen=True)
class SurfaceLayer:
    """One mesh seen by the camera (hard raster, nearest layer).

    Attributes:
        face_ids ((H, W) int64): Face hit per pixel, -1 where missed.
        bary ((H, W, 3) float): Perspective-correct barycentrics of the hit.
        depth ((H, W) float): Camera z of the hit, ``inf`` where missed.
        vertices ((V, 3) float): World positions (metres).
        faces: (F, 3) int
    """

    face_ids: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    return vn / np.linalg.norm(vn, axis=1, keepdims=True).clip(1e-12)


def _interpolate(layer: SurfaceLayer, attr: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """(N, C) attribute at the hit pixels ``hit`` (H, W) bool."""
    fid = layer.face_ids[hit]
    return np.einsum("nk,nkc->nc", layer.bary[hit], attr[layer.faces[fid]])


def background(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float in [0, 1]: gradient, blurred shapes, fine noise."""

    def muted():
        c = rng.uniform(0.2, 0.9, size=3)
        return c * 0.45 + c.mean() * 0.55  # walls, tables and cloth are mostly desaturated

    base = muted()
    other = np.clip(base * rng.uniform(0.6, 1.1) + rng.normal(0, 0.05, size=3), 0.05, 0.95)
    ang = rng.uniform(0, 2 * np.pi)
    yy, xx = np.mgrid[0:height, 0:width] / max(height, width)
    t = np.clip(0.5 + (np.cos(ang) * (xx - 0.5) + np.sin(ang) * (yy - 0.5)), 0, 1)
    img = base * (1 - t[..., None]) + other * t[..., None]
    canvas = np.zeros((height, width, 3), np.float32)
    weight = np.zeros((height, width), np.float32)
    if rng.random() < 0.6:  # a table edge: the lower part gets another colour
        y0 = int(rng.uniform(0.55, 0.85) * height)
        tilt = rng.uniform(-0.2, 0.2)
        rows = y0 + tilt * (np.arange(width) - width / 2)
        table = yy * max(height, width) > rows[None, :]
        canvas[table] = np.clip(muted() * rng.uniform(0.6, 1.0), 0, 1)
        weight[table] = 1.0
    for _ in range(int(rng.integers(2, 6))):
        m = np.zeros((height, width), np.uint8)
        c = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
        axes = (int(rng.uniform(0.05, 0.3) * width), int(rng.uniform(0.05, 0.3) * height))
        cv2.ellipse(m, c, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        sel = m > 0
        canvas[sel] = muted()
        weight[sel] = rng.uniform(0.2, 0.6)
    k = int(2 * round(0.04 * max(height, width)) + 1)
    canvas = cv2.GaussianBlur(canvas, (k, k), 0)
    weight = cv2.GaussianBlur(weight, (k, k), 0)[..., None]
    img = img * (1 - weight) + canvas * weight
    noise = cv2.GaussianBlur(rng.normal(0, 1, (height, width)).astype(np.float32), (3, 3), 0)
    return np.clip(img + 0.02 * noise[..., None], 0, 1)


def object_albedo(points: np.ndarray, color, secondary, texture: str, scale: float) -> np.ndarray:
    """(N, 3) albedo of a procedurally textured object at (N, 3) object-frame points.

    ``scale`` is the object's size (metres); stripes, checks and bands scale with it.
    """
    color, secondary = np.asarray(color, float), np.asarray(secondary, float)
    if texture == "stripes":
        s = np.sin(2 * np.pi * (points @ np.array([0.3, 0.2, 0.93])) / (0.12 * scale)) > 0.3
    elif texture == "checker":
        cell = np.floor(points / (0.15 * scale)).astype(int)
        s = (cell.sum(axis=1) % 2) == 0
    elif texture == "bands":
        z = points[:, int(np.argmax(np.ptp(points, axis=0)))] / scale
        s = np.abs(z) < 0.18
    else:
        s = np.zeros(len(points), bool)
    return np.where(s[:, None], secondary, color)


def shade_photo(
    hand: SurfaceLayer,
    obj: SurfaceLayer,
    camera_center: np.ndarray,
    light: np.ndarray,
    skin: np.ndarray,
    obj_albedo_fn,
    rng: np.random.Generator,
) -> np.ndarray:
    """Compose the photo.

    Args:
        hand, obj (SurfaceLayer): Nearest-surface fragments of the hand and of the object (same
            camera).
        camera_center ((3,) float): Camera centre in world coordinates (for the view vector).
        light ((3,) float): Unit direction towards the key light (world).
        skin ((3,) float): Skin albedo in [0, 1].
        obj_albedo_fn (callable): (N, 3) world points -> (N, 3) albedo of the object.
        rng: numpy Generator

    Returns:
        (H, W, 3) uint8
    """
    H, W = hand.face_ids.shape
    img = background(H, W, rng)
    hand_hit = (hand.face_ids >= 0) & (hand.depth <= obj.depth)
    obj_hit = (obj.face_ids >= 0) & (obj.depth < hand.depth)
    light = np.asarray(light, float) / np.linalg.norm(light)
    ambient = rng.uniform(0.3, 0.45)

    # screen-space soft shadow of the hand over what lies behind it
    shift = rng.normal(0, 0.03, 2) * max(H, W)
    M = np.float32([[1, 0, shift[0]], [0, 1, abs(shift[1])]])
    shadow = cv2.warpAffine((hand.face_ids >= 0).astype(np.float32), M, (W, H))
    k = int(2 * round(0.03 * max(H, W)) + 1)
    shadow = cv2.GaussianBlur(shadow, (k, k), 0) * rng.uniform(0.25, 0.45)
    img = img * (1 - shadow[..., None] * (~hand_hit)[..., None])

    for layer, hit, albedo_of, spec in (
        (hand, hand_hit, None, 0.08),
        (obj, obj_hit, obj_albedo_fn, 0.35),
    ):
        if not hit.any():
            continue
        vn = _vertex_normals(layer.vertices, layer.faces)
        n = _interpolate(layer, vn, hit)
        n /= np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
        p = _interpolate(layer, layer.vertices, hit)
        to_cam = camera_center - p
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        n = np.where((n * to_cam).sum(1, keepdims=True) < 0, -n, n)  # insides of mugs
        if albedo_of is None:
            tone = skin * (1 + rng.normal(0, 0.015, 3))
            albedo = np.broadcast_to(tone, p.shape)
        else:
            albedo = albedo_of(p)
        diffuse = np.clip(n @ light, 0, 1)[:, None]
        half = light + to_cam
        half /= np.linalg.norm(half, axis=1, keepdims=True)
        highlight = spec * np.clip((n * half).sum(1), 0, 1)[:, None] ** 40
        colour = albedo * (ambient + (1 - ambient) * diffuse) + highlight
        img[hit] = np.clip(colour, 0, 1)

    # anti-aliasing along silhouettes and between the two surfaces
    label = np.where(hand_hit, 1, np.where(obj_hit, 2, 0)).astype(np.uint8)
    edges = cv2.morphologyEx(label, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    soft = cv2.GaussianBlur(img.astype(np.float32), (3, 3), 0.8)
    img[edges] = 0.5 * img[edges] + 0.5 * soft[edges]
    img = cv2.GaussianBlur(img.astype(np.float32), (3, 3), 0.5)
    img = img + rng.normal(0, 0.012, img.shape)
    return (np.clip(img, 0, 1) ** (1 / 1.1) * 255 + 0.5).astype(np.uint8)


def skin_tone(rng: np.random.Generator) -> np.ndarray:
    """(3,) skin albedo in [0, 1], a palette tone with a little variation."""
    tone = np.asarray(SKIN_TONES[int(rng.integers(len(SKIN_TONES)))], float) / 255.0
    return np.clip(tone * rng.uniform(0.92, 1.05) + rng.normal(0, 0.01, 3), 0, 1)


__all__ = [
    "SKIN_TONES",
    "SurfaceLayer",
    "background",
    "object_albedo",
    "shade_photo",
    "skin_tone",
]
