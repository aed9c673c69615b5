"""Region proposals: superpixels grouped hierarchically into object hypotheses.

A held object is rarely one colour, and no single threshold on one segmentation finds it in
every photo. Instead of committing to one segmentation, the working crop is over-segmented
(Felzenszwalb-Huttenlocher graph segmentation, which follows image edges) and the segments are
merged pairwise, most similar neighbours first (the selective-search grouping: colour histogram
similarity, preference for merging small regions, and for merges that fill their bounding box).
Every region created along the way is a hypothesis, from single segments up to large parts of the
crop, so an object made of several coloured parts (a can with a label, a bottle with a cap)
appears as one hypothesis at some level of the hierarchy while the background next to it stays
another.

The automatic path pools the hierarchies of several Felzenszwalb scales on their common
refinement (:func:`propose_scales`): the right granularity differs between photos and objects.

Hypotheses are represented by the set of base segments they contain; per-segment statistics
(summed by :func:`segment_sums`) give most cues of a hypothesis without drawing its mask.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

#: Histogram bins per Lab channel used for the colour similarity.
BINS = 12


@dataclass(frozen=True)
class Proposals:
    """Base segments and the hypotheses grouped from them.

    Attributes:
        labels: (h, w) int base-segment label per pixel, -1 on excluded pixels (the hands).
        regions: tuple of frozensets of base labels, one per hypothesis (base segments first,
            then every merge in the order it happened).
        sizes: (n_base,) pixel count of each base segment.
    """

    labels: np.ndarray
    regions: tuple[frozenset, ...]
    sizes: np.ndarray

    @property
    def n_base(self) -> int:
        return len(self.sizes)

    def mask(self, region: frozenset) -> np.ndarray:
        """(h, w) bool mask of a hypothesis."""
        lut = np.zeros(self.n_base + 1, bool)
        lut[np.fromiter(region, int, len(region)) + 1] = True
        return lut[self.labels + 1]


def base_segments(
    image: np.ndarray, exclude: np.ndarray, scale: float, min_size: int, sigma: float = 0.8
) -> np.ndarray:
    """(h, w) int labels 0..n-1 of Felzenszwalb segments split into connected pieces outside
    ``exclude`` (labelled -1).

    OpenCV's implementation (``ximgproc``, from the ``opencv-contrib-python`` that MediaPipe
    requires) is used when present, scikit-image's otherwise (same algorithm, a few times
    slower)."""
    import cv2
    from skimage.measure import label

    if hasattr(cv2, "ximgproc"):
        gs = cv2.ximgproc.segmentation.createGraphSegmentation(sigma, float(scale), int(min_size))
        seg = gs.processImage(np.ascontiguousarray(image)).astype(np.int64)
    else:
        from skimage.segmentation import felzenszwalb

        seg = felzenszwalb(image, scale=scale, sigma=sigma, min_size=min_size)
    seg = np.where(exclude, -1, seg)
    # a segment cut in two by the hand becomes two segments (pieces on either side of a finger
    # are separate hypotheses until the grouping decides they belong together): 4-connected
    # pieces of equal label, numbered in raster order
    return label(seg, background=-1, connectivity=1).astype(np.int64) - 1


def segment_sums(labels: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Per-segment sums of a per-pixel ``values`` (h, w) array (pixels labelled -1 ignored)."""
    ok = labels >= 0
    return np.bincount(labels[ok], weights=values[ok].astype(np.float64), minlength=n)


def segment_minima(labels: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(k, n) per-segment minima of each of the (k, h, w) maps ``values`` over the segments
    0..n-1 (other labels, -1 included, ignored), in their dtype; 0 for a segment without
    pixels. The values of ``scipy.ndimage.minimum(v, labels + 1, range(1, n + 1))`` (a minimum
    does not depend on the order it is taken in), which sorts every map's values to get them."""
    ok = (labels >= 0) & (labels < n)
    lab = labels[ok]
    out = np.full((len(values), n), np.inf, values.dtype)
    for row, v in zip(out, values, strict=True):
        np.minimum.at(row, lab, v[ok])
    out[:, np.bincount(lab, minlength=n) == 0] = 0
    return out


def adjacency(labels: np.ndarray) -> set[tuple[int, int]]:
    """Pairs (a < b) of base segments that share a 4-neighbour edge."""
    pairs = set()
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        m = (a != b) & (a >= 0) & (b >= 0)
        lo, hi = np.minimum(a[m], b[m]), np.maximum(a[m], b[m])
        pairs.update(zip(lo.tolist(), hi.tolist(), strict=True))
    return pairs


def fill_excluded(labels: np.ndarray) -> np.ndarray:
    """``labels`` with every excluded pixel (-1) given the label of the nearest segment.

    Used for adjacency only: the parts of an object on either side of a finger become
    neighbours, so the grouping can join an object the fingers cross."""
    import cv2

    ex = labels < 0
    if not ex.any() or ex.all():
        return labels
    _, idx = cv2.distanceTransformWithLabels(
        ex.astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    zy, zx = np.nonzero(~ex)  # DIST_LABEL_PIXEL numbers the zero pixels in raster order from 1
    out = labels.copy()
    k = idx[ex] - 1
    out[ex] = labels[zy[k], zx[k]]
    return out


def _histograms(lab: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """(n, 3 * BINS) L1-normalised Lab colour histograms of the base segments."""
    ok = labels >= 0
    out = np.zeros((n, 3 * BINS))
    for c in range(3):  # OpenCV's 8-bit Lab: every channel in [0, 255]
        b = np.clip((lab[..., c] / 255.0 * BINS).astype(np.int64), 0, BINS - 1)
        out[:, c * BINS : (c + 1) * BINS] = np.bincount(
            labels[ok] * BINS + b[ok], minlength=n * BINS
        ).reshape(n, BINS)
    return out / np.maximum(out.sum(1, keepdims=True), 1.0)


def group(
    labels: np.ndarray, lab: np.ndarray, max_size: float | None = None
) -> tuple[tuple[frozenset, ...], np.ndarray]:
    """Selective-search grouping of base segments.

    Args:
        labels ((h, w) int): Base segments 0..n-1 (-1 excluded).
        lab ((h, w, 3)): Lab image (OpenCV 8-bit ranges).
        max_size (float, optional): Merged regions larger than this many pixels are not recorded
            (nor merged further).

    Returns:
        regions (tuple of frozenset): The n base segments, then every merged region.
        sizes ((n,) float): Base segment sizes.
    """
    n = int(labels.max()) + 1 if (labels >= 0).any() else 0
    if n == 0:
        return (), np.zeros(0)
    total = float((labels >= 0).sum())
    sizes = segment_sums(labels, np.ones(labels.shape), n)
    hist = list(_histograms(lab, labels, n))
    from scipy.ndimage import find_objects

    bbox = np.array(
        [
            (sl[1].start, sl[0].start, sl[1].stop - 1, sl[0].stop - 1)
            for sl in find_objects(labels + 1)
        ],
        np.float64,
    )
    regions: list[frozenset] = [frozenset((i,)) for i in range(n)]
    size = list(sizes)
    box = [tuple(b) for b in bbox]
    neigh: dict[int, set[int]] = {i: set() for i in range(n)}
    for a, b in adjacency(fill_excluded(labels)):
        neigh[a].add(b)
        neigh[b].add(a)

    def sim(a: int, b: int) -> float:
        colour = float(np.minimum(hist[a], hist[b]).sum()) / 3.0
        small = 1.0 - (size[a] + size[b]) / total
        bx = (
            max(box[a][2], box[b][2]) - min(box[a][0], box[b][0]) + 1,
            max(box[a][3], box[b][3]) - min(box[a][1], box[b][1]) + 1,
        )
        fill = 1.0 - (bx[0] * bx[1] - size[a] - size[b]) / total
        return colour + small + fill

    # a heap of candidate merges with lazy deletion: a merge whose pair no longer exists (one of
    # its regions was merged since) is skipped when popped; ties go to the lowest labels
    alive: set[tuple[int, int]] = set()
    heap: list[tuple[float, int, int]] = []

    def push(a: int, b: int) -> None:
        alive.add((a, b))
        heapq.heappush(heap, (-sim(a, b), a, b))

    for a in neigh:
        for b in neigh[a]:
            if a < b:
                push(a, b)
    while heap:
        _, a, b = heapq.heappop(heap)
        if (a, b) not in alive:
            continue
        alive.discard((a, b))
        merged_size = size[a] + size[b]
        if max_size is not None and merged_size > max_size:
            continue  # too large to be a held object: this merge is not made
        new = len(regions)
        regions.append(regions[a] | regions[b])
        size.append(merged_size)
        hist.append((hist[a] * size[a] + hist[b] * size[b]) / merged_size)
        box.append(
            (
                min(box[a][0], box[b][0]),
                min(box[a][1], box[b][1]),
                max(box[a][2], box[b][2]),
                max(box[a][3], box[b][3]),
            )
        )
        nb = (neigh[a] | neigh[b]) - {a, b}
        for k in (a, b):
            for j in neigh.pop(k):
                alive.discard((min(j, k), max(j, k)))
                if j in neigh:
                    neigh[j].discard(k)
        neigh[new] = nb
        for j in nb:
            neigh[j].add(new)
            push(j, new)
    return tuple(regions), sizes


def propose(
    image: np.ndarray,
    lab: np.ndarray,
    exclude: np.ndarray,
    scale: float,
    min_size: int,
    max_size: float | None = None,
) -> Proposals:
    """Base segments of ``image`` outside ``exclude`` and their hierarchical grouping."""
    labels = base_segments(image, exclude, scale, min_size)
    regions, sizes = group(labels, lab, max_size)
    return Proposals(labels=labels, regions=regions, sizes=sizes)


def overlay(label_maps: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The common refinement of several segmentations of one image.

    Returns:
        labels ((h, w) int): One label per distinct combination of the input labels (-1 where
            the inputs are -1; they share their excluded pixels).
        parents (list of (n,) int): For each input, the label every common piece lies in.
    """
    ok = label_maps[0] >= 0
    key = np.zeros(int(ok.sum()), np.int64)
    for m in label_maps:
        key = key * (int(m.max()) + 2) + m[ok] + 1
    uniq, inv = np.unique(key, return_inverse=True)
    labels = np.full(label_maps[0].shape, -1, np.int64)
    labels[ok] = inv
    _, first = np.unique(inv, return_index=True)  # one pixel of each piece
    parents = [m[ok][first] for m in label_maps]
    return labels, parents


def propose_scales(
    image: np.ndarray,
    lab: np.ndarray,
    exclude: np.ndarray,
    scales: tuple[float, ...],
    min_size: int,
    max_size: float | None = None,
) -> Proposals:
    """Hypotheses grouped from Felzenszwalb segmentations at several ``scales``, on one set of
    base segments (their common refinement), duplicates removed.

    The right granularity differs between photos and between objects in one photo: a fine
    segmentation keeps a small object (a pen, a lid) apart from the fingers and the table, a
    coarse one keeps a textured object (a printed box, a board game) in few pieces that the
    grouping can join. Pooling the hierarchies of both lets the held-object cues choose."""
    maps = [base_segments(image, exclude, s, min_size) for s in scales]
    labels, parents = overlay(maps)
    sizes = segment_sums(labels, np.ones(labels.shape), len(parents[0]))
    regions: list[frozenset] = []
    seen: set[frozenset] = set()
    for m, par in zip(maps, parents, strict=True):
        order = np.argsort(par, kind="stable")
        starts = np.searchsorted(par[order], np.arange(int(m.max()) + 2))
        pieces = [order[starts[b] : starts[b + 1]] for b in range(int(m.max()) + 1)]
        for reg in group(m, lab, max_size)[0]:
            r = frozenset(np.concatenate([pieces[b] for b in reg]).tolist())
            if r not in seen:
                seen.add(r)
                regions.append(r)
    return Proposals(labels=labels, regions=tuple(regions), sizes=sizes)


def membership(props: Proposals):
    """(n_regions, n_base) sparse 0/1 matrix: which base segments each hypothesis contains."""
    from scipy.sparse import csr_matrix

    lens = np.fromiter((len(r) for r in props.regions), np.int64, len(props.regions))
    cols = np.fromiter((i for r in props.regions for i in r), np.int64, int(lens.sum()))
    indptr = np.concatenate([[0], np.cumsum(lens)])
    data = np.ones(len(cols))
    return csr_matrix((data, cols, indptr), shape=(len(props.regions), props.n_base))
