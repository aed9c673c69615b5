"""Reference outlines of hands and held objects on the perception development photos.

Each photo of ``photos-dev/`` and ``images/`` in the shared data folder has one JSON file in
``tests/data/perception_refs/`` named ``<folder>__<stem>.json``. The outlines were drawn by eye on
the photo (no segmentation algorithm was involved), so they can judge any segmenter:

- ``hands``: every clearly visible hand, ``side`` is the person's hand ("left"/"right"),
  ``holds_object`` whether that hand holds one of the listed objects;
- ``objects``: only the held object(s); ``held_by`` lists hand indices and ``visibly_held``
  is false when the grip itself is hidden or ambiguous;
- ``polygons``: lists of ``[x, y]`` vertices in pixels of the original image, several polygons
  per item when it is split into visible pieces. They outline the *visible* parts: fingers in
  front of an object are cut out of the object's polygons.

A mask is the union of its polygons filled with ``cv2.fillPoly`` (boundary pixels included).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

REFS_DIR = Path(__file__).resolve().parent / "data" / "perception_refs"
SIDES = ("left", "right")

Polygon = tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class HandRef:
    side: str
    polygons: tuple[Polygon, ...]
    holds_object: bool


@dataclass(frozen=True)
class ObjectRef:
    name: str
    polygons: tuple[Polygon, ...]
    held_by: tuple[int, ...]
    visibly_held: bool


@dataclass(frozen=True)
class PerceptionRef:
    """One annotated photo; ``image`` is relative to the shared data folder."""

    key: str
    image: str
    width: int
    height: int
    hands: tuple[HandRef, ...]
    objects: tuple[ObjectRef, ...]
    note: str

    def image_path(self, data_root: Path) -> Path:
        return Path(data_root) / self.image


class RefFormatError(ValueError):
    """A reference file does not follow the format described in this module."""


def _polygons(raw, where: str) -> tuple[Polygon, ...]:
    if not isinstance(raw, list) or not raw:
        raise RefFormatError(f"{where}: 'polygons' must be a non-empty list")
    out = []
    for k, poly in enumerate(raw):
        if not isinstance(poly, list) or len(poly) < 3:
            raise RefFormatError(f"{where}: polygon {k} needs at least 3 vertices")
        pts = []
        for p in poly:
            if not (isinstance(p, list) and len(p) == 2 and all(_is_number(v) for v in p)):
                raise RefFormatError(f"{where}: polygon {k} has a vertex that is not [x, y]: {p}")
            pts.append((float(p[0]), float(p[1])))
        out.append(tuple(pts))
    return tuple(out)


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def parse_ref(data: dict, key: str) -> PerceptionRef:
    """Check one decoded reference file and turn it into a :class:`PerceptionRef`."""
    for field in ("image", "width", "height", "hands", "objects", "note"):
        if field not in data:
            raise RefFormatError(f"{key}: missing field {field!r}")
    hands = []
    for i, h in enumerate(data["hands"]):
        where = f"{key} hand {i}"
        if h.get("side") not in SIDES:
            raise RefFormatError(f"{where}: side must be one of {SIDES}, got {h.get('side')!r}")
        if not isinstance(h.get("holds_object"), bool):
            raise RefFormatError(f"{where}: 'holds_object' must be true or false")
        hands.append(HandRef(h["side"], _polygons(h.get("polygons"), where), h["holds_object"]))
    objects = []
    for j, o in enumerate(data["objects"]):
        where = f"{key} object {j}"
        held_by = o.get("held_by")
        if not isinstance(held_by, list) or any(
            not isinstance(i, int) or not 0 <= i < len(hands) for i in held_by
        ):
            raise RefFormatError(f"{where}: 'held_by' must list hand indices, got {held_by!r}")
        if not isinstance(o.get("name"), str) or not o["name"]:
            raise RefFormatError(f"{where}: 'name' must be a non-empty string")
        if not isinstance(o.get("visibly_held"), bool):
            raise RefFormatError(f"{where}: 'visibly_held' must be true or false")
        objects.append(
            ObjectRef(
                o["name"], _polygons(o.get("polygons"), where), tuple(held_by), o["visibly_held"]
            )
        )
    w, h = data["width"], data["height"]
    if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
        raise RefFormatError(f"{key}: width and height must be positive integers")
    return PerceptionRef(key, data["image"], w, h, tuple(hands), tuple(objects), str(data["note"]))


def load_ref(name: str | Path) -> PerceptionRef:
    """Load one reference by key (``photos-dev__ihoi-demo_01``) or by path."""
    path = Path(name)
    if not path.is_file():
        path = REFS_DIR / f"{Path(name).stem}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no perception reference {name!r} in {REFS_DIR}")
    return parse_ref(json.loads(path.read_text()), path.stem)


def ref_keys() -> list[str]:
    return sorted(p.stem for p in REFS_DIR.glob("*.json"))


def load_refs() -> list[PerceptionRef]:
    """Every reference, sorted by key."""
    return [load_ref(k) for k in ref_keys()]


def rasterize(polygons, height: int, width: int) -> np.ndarray:
    """(H, W) bool: the union of the filled polygons (vertices rounded to pixel centres)."""
    mask = np.zeros((height, width), np.uint8)
    for poly in polygons:
        pts = np.round(np.asarray(poly, dtype=np.float64)).astype(np.int32)
        cv2.fillPoly(mask, [pts.reshape(-1, 1, 2)], 1)
    return mask.astype(bool)


def hand_mask(ref: PerceptionRef) -> np.ndarray:
    """(H, W) bool: the union of all hands."""
    return rasterize([p for h in ref.hands for p in h.polygons], ref.height, ref.width)


def object_masks(ref: PerceptionRef) -> list[np.ndarray]:
    """One (H, W) bool mask per listed object."""
    return [rasterize(o.polygons, ref.height, ref.width) for o in ref.objects]


def held_object_mask(ref: PerceptionRef) -> np.ndarray:
    """(H, W) bool: the union of the objects held by at least one hand (empty if none)."""
    held = [p for o in ref.objects if o.held_by for p in o.polygons]
    return rasterize(held, ref.height, ref.width)


def object_point(ref: PerceptionRef) -> tuple[int, int] | None:
    """(x, y) of the deepest interior pixel of the held-object mask, or None without one.

    The pixel farthest from the mask's border is where a user asked to click "on the object"
    would click; it stands in for one click in prompted-segmentation benchmarks.
    """
    return deepest_point(held_object_mask(ref))


def deepest_point(mask: np.ndarray) -> tuple[int, int] | None:
    """(x, y) of the deepest interior pixel of ``mask`` (see :func:`object_point`), or None
    when it is empty."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return None
    dist = inner_distance(mask)
    # Ties (a ridge of equally deep pixels, as in a long bar): take the tied pixel nearest to
    # the middle of the ridge, so the point does not depend on the scan order.
    ys, xs = np.nonzero(dist >= dist.max() - 1e-3)
    k = int(np.argmin((xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2))
    return int(xs[k]), int(ys[k])


def inner_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float distance of every pixel of ``mask`` to its outline (0 outside); the image
    border counts as outside."""
    padded = np.pad(np.asarray(mask, bool).astype(np.uint8), 1)
    return cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]


def drawn_point(mask: np.ndarray, share: float, key: str) -> tuple[float, float]:
    """(x, y) of a click drawn among the pixels of the non-empty ``mask`` at least ``share``
    times as deep as its deepest one (:func:`inner_distance`), seeded by ``key``: users click
    inside the object, not always at its middle."""
    dist = inner_distance(mask)
    ys, xs = np.nonzero(dist >= share * dist.max())
    k = np.random.default_rng(zlib.crc32(key.encode())).integers(len(xs))
    return float(xs[k]), float(ys[k])


def object_box(mask: np.ndarray, grow: float = 0.05) -> tuple[float, float, float, float]:
    """The box a user draws round the object ``mask``: its bounding box grown by ``grow`` of its
    width and height on every side, inside the photo; (x0, y0, x1, y1)."""
    ys, xs = np.nonzero(mask)
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
    gx, gy = grow * (x1 - x0), grow * (y1 - y0)
    h, w = mask.shape
    return (max(0.0, x0 - gx), max(0.0, y0 - gy), min(w - 1.0, x1 + gx), min(h - 1.0, y1 + gy))


def second_point(mask: np.ndarray | None, ref: np.ndarray) -> tuple[float, float] | None:
    """Where a user adds a second object point: the deepest pixel of the part of the reference
    object ``ref`` that the one-point ``mask`` misses, when it misses more than it takes in
    beyond the object (else None: a further object point cannot take away a leak)."""
    from scipy import ndimage

    miss = ref & ~mask if mask is not None else ref
    extra = (mask & ~ref).sum() if mask is not None else 0
    if miss.sum() <= extra or not miss.any():
        return None
    dist = ndimage.distance_transform_edt(miss)
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return float(c) + 0.5, float(r) + 0.5


def background_point(mask: np.ndarray | None, ref: np.ndarray) -> tuple[float, float] | None:
    """Where a user adds a background point: the deepest pixel of the part of ``mask`` that lies
    beyond the reference object ``ref``, when it takes in at least as much as it misses and is
    a region one sees, not a rim along the outline (at its deepest at least a quarter as deep as
    the object); else None (a further object point adds what the mask misses)."""
    from scipy import ndimage

    if mask is None:
        return None
    extra = mask & ~ref
    if not extra.any() or extra.sum() < (ref & ~mask).sum():
        return None
    dist = ndimage.distance_transform_edt(extra)
    if dist.max() < max(3.0, 0.25 * float(ndimage.distance_transform_edt(ref).max())):
        return None
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return float(c) + 0.5, float(r) + 0.5


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks (1.0 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)
