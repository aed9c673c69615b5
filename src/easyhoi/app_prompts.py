"""Click-to-prompt for the web demo: points on the shown photo, drawn, and a mask preview.

The page shows the photo downscaled (at most :data:`PREVIEW_SIDE` pixels); a click there gives
pixel coordinates of that thumbnail, kept here in pixels of the photo as stored (the same
coordinates as ``easyhoi reconstruct --object-point``). The state of one page is a small JSON
dict (see :func:`new_state`), so it lives in the browser session and needs no server storage.

Nothing here imports gradio: :mod:`easyhoi.app` wires these functions to the page, and the
tests call them directly.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from easyhoi.errors import EasyHOIError, InvalidInputError
from easyhoi.perception.prompts import Prompts

logger = logging.getLogger(__name__)

__all__ = [
    "MODES",
    "PREVIEW_SIDE",
    "add_click",
    "choice_label",
    "choice_labels",
    "draw_prompts",
    "draw_regions",
    "load_preview",
    "mask_preview",
    "new_state",
    "prompt_text",
    "segment_for_preview",
    "set_choice",
    "state_prompts",
]

#: Longer side of the photo as shown on the page, in pixels.
PREVIEW_SIDE = 512
#: What a click adds: a point on the held object (repeatable), the point on the holding hand, a
#: point that is not the object (repeatable: where the mask takes in too much), or a corner of a
#: box round the object (two clicks, opposite corners; a new box replaces the old one).
MODES = ("object point", "hand point", "background point", "object box corner")
#: At most this many object points, and as many background points (a few clicks are enough;
#: more is a stuck mouse).
MAX_OBJECT_POINTS = 16

#: The state's prompts taken as they are (the object region: see :func:`state_prompts`).
_STATE_PROMPTS = ("object_points", "object_box", "hand_point", "background_points")


def new_state(photo_size: tuple[int, int] | None = None) -> dict:
    """An empty prompt state for a photo of ``photo_size`` (width, height) as stored."""
    size = None if photo_size is None else [int(photo_size[0]), int(photo_size[1])]
    return {
        "object_points": [],
        "hand_point": None,
        "background_points": [],
        "object_box": None,
        "box_corner": None,
        "object_choice": None,
        "photo_size": size,
    }


def choice_labels() -> list[str]:
    """The page's menu of object regions: the automatic choice, then regions 2 to
    :data:`~easyhoi.perception.prompts.N_CHOICES` (``--object-choice K``)."""
    from easyhoi.perception.prompts import N_CHOICES

    return ["1 (automatic)"] + [str(k) for k in range(2, N_CHOICES + 1)]


def choice_label(state: dict | None) -> str:
    """The *Object region* menu's entry (:func:`choice_labels`) for the state's choice."""
    k = (state or {}).get("object_choice") or 1
    return choice_labels()[k - 1]


def set_choice(state: dict | None, label: str | None) -> dict:
    """The state with the object region of menu entry ``label`` (:func:`choice_labels`);
    the automatic entry (or none) clears it."""
    state = dict(state or new_state())
    k = int(str(label).split()[0]) if label else 1
    state["object_choice"] = None if k == 1 else k
    return state


def load_preview(path, max_upload_mb: float) -> tuple[np.ndarray | None, str, dict]:
    """``(thumbnail RGB or None, error message or "", fresh state)`` of an upload."""
    from easyhoi.app_request import check_upload

    rgb, err = check_upload(path, max_upload_mb)
    if rgb is None:
        return None, err, new_state()
    from easyhoi.io.image import load_image

    try:
        size = load_image(path, max_side=PREVIEW_SIDE).original_size
    except InvalidInputError as exc:  # pragma: no cover - check_upload decoded it already
        return None, str(exc), new_state()
    return rgb, "", new_state(size)


def add_click(state: dict | None, mode: str, xy, shown_size: tuple[int, int]) -> dict:
    """The state after a click at ``xy`` (pixels of the shown image of ``shown_size`` (w, h)).

    ``mode`` is one of :data:`MODES`: an object point is appended (beyond
    :data:`MAX_OBJECT_POINTS`, the oldest but the first is dropped), the hand point replaced,
    a background point appended (beyond :data:`MAX_OBJECT_POINTS`, the oldest dropped); a box
    corner is kept until the next one, and the two make the object box (replacing any; a
    second corner on the first one's row or column is ignored: a box needs width and height).
    A click outside the image (or before a photo is loaded) leaves the state as it is.
    """
    state = dict(state or new_state())
    size = state.get("photo_size")
    if size is None or xy is None:
        return state
    x, y = float(xy[0]), float(xy[1])
    w, h = shown_size
    if not (0 <= x < w and 0 <= y < h):
        return state
    W, H = size
    # pixel centres of the thumbnail to coordinates of the stored photo
    px = round(min((x + 0.5) * W / w, W - 0.5), 1)
    py = round(min((y + 0.5) * H / h, H - 0.5), 1)
    if mode == MODES[1]:
        state["hand_point"] = [px, py]
    elif mode == MODES[0]:
        if not state.get("object_points"):  # the regions to pick from are now the point's
            state["object_choice"] = None
        pts = list(state.get("object_points") or []) + [[px, py]]
        # the first point frames the object and picks the hand: past the cap, the oldest of
        # the further points goes
        state["object_points"] = pts[:1] + pts[1:][-(MAX_OBJECT_POINTS - 1) :]
    elif mode == MODES[2]:
        pts = list(state.get("background_points") or []) + [[px, py]]
        state["background_points"] = pts[-MAX_OBJECT_POINTS:]
    elif mode == MODES[3]:
        corner = state.get("box_corner")
        if corner is None:
            state["box_corner"] = [px, py]
        elif corner[0] != px and corner[1] != py:
            x0, x1 = sorted((corner[0], px))
            y0, y1 = sorted((corner[1], py))
            state["object_box"], state["box_corner"] = [x0, y0, x1, y1], None
    else:
        raise InvalidInputError(f"unknown click mode {mode!r}; one of {', '.join(MODES)}")
    return state


def state_prompts(state: dict | None) -> Prompts | None:
    """The :class:`Prompts` of a state (photo pixels), or None when there is none. The chosen
    region is one of the automatic path's or, with object points, of the first point's; a box
    has no numbered regions, so with one the choice does not count."""
    if not state:
        return None
    d = {k: state.get(k) for k in _STATE_PROMPTS}
    if not state.get("object_box"):
        d["object_choice"] = state.get("object_choice")
    p = Prompts.from_dict(d)
    return None if p.empty else p


def prompt_text(state: dict | None) -> str:
    """One line for the page: the points so far (photo pixels), or how to add them."""
    p = state_prompts(state)
    corner = (state or {}).get("box_corner")
    pending = (
        []
        if corner is None
        else [f"box corner ({corner[0]:.0f}, {corner[1]:.0f}): click the opposite corner"]
    )
    if p is None:
        return "; ".join(pending) or (
            "Click on the held object in the photo to add a point (optional: the automatic "
            "choice is used without)."
        )
    parts = []
    if p.object_points:
        pts = ", ".join(f"({x:.0f}, {y:.0f})" for x, y in p.object_points)
        parts.append(f"object point{'s' if len(p.object_points) > 1 else ''}: {pts}")
    if p.object_box is not None:
        x0, y0, x1, y1 = p.object_box
        parts.append(f"object box: ({x0:.0f}, {y0:.0f})-({x1:.0f}, {y1:.0f})")
    if p.hand_point is not None:
        parts.append(f"hand point: ({p.hand_point[0]:.0f}, {p.hand_point[1]:.0f})")
    if p.background_points:
        pts = ", ".join(f"({x:.0f}, {y:.0f})" for x, y in p.background_points)
        parts.append(f"not the object: {pts}")
    if p.object_choice is not None:
        parts.append(f"object region {p.object_choice}")
    elif state.get("object_choice") and p.object_box is not None:
        parts.append("(the object region chosen counts only without a box)")
    return "; ".join(parts + pending)


def draw_prompts(rgb: np.ndarray, state: dict | None, masks=None) -> np.ndarray:
    """The thumbnail with the prompts drawn (:func:`easyhoi.viz.marks.draw_marks`: object
    points green, the hand point orange, background points red and crossed, the object box a
    green rectangle and its pending first corner a green square) and ``masks`` = (hand,
    object) tinted, if given."""
    from easyhoi.viz.marks import HAND_COLOUR, OBJECT_COLOUR, draw_marks

    img = np.asarray(rgb, np.uint8).copy()
    h, w = img.shape[:2]
    if masks is not None:
        for mask, colour in zip(masks, (HAND_COLOUR, OBJECT_COLOUR), strict=True):
            if mask is not None:
                m = _resize_mask(mask, (w, h))
                img[m] = (0.45 * img[m] + 0.55 * np.asarray(colour)).astype(np.uint8)
    size = (state or {}).get("photo_size")
    if not size:
        return img
    return draw_marks(img, state, w / size[0], h / size[1])


def _resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    m = np.asarray(mask).astype(np.uint8)
    if m.shape[::-1] != tuple(size):
        m = cv2.resize(m, size, interpolation=cv2.INTER_NEAREST)
    return m.astype(bool)


# ----------------------------------------------------------------------------------------------
# mask preview
# ----------------------------------------------------------------------------------------------

#: ``(rgb, config, prompts) -> (hand mask, object mask, facts)``: masks (H, W) bool of ``rgb``.
SegmentFn = Callable[[np.ndarray, object, Prompts | None], tuple]


def segment_for_preview(rgb: np.ndarray, config, prompts: Prompts | None):
    """Hand detection and segmentation of the perception chain, with the prompts.

    The hand is chosen as in :func:`easyhoi.perception.chain.perceive`
    (:func:`~easyhoi.perception.chain.segment_hands`). Returns
    ``(hand mask, object mask, facts)``; facts holds ``hands_found``, ``hand_index``, ``side``,
    ``confidence`` (mask name -> the JSON form of its MaskConfidence) and, when the segmenter
    offers object regions to choose from, ``regions`` ((H, W) bool masks, region 1 first).
    """
    from easyhoi.device import resolve_device
    from easyhoi.errors import NoHandError, NoObjectError
    from easyhoi.perception.chain import _backend, segment_hands

    pc = config.perception
    H, W = rgb.shape[:2]
    prompts = None if prompts is None else prompts.check(W, H)
    seed, device = config.optim.seed, resolve_device(config.device)
    segmenter = _backend(pc, "segmenter", pc.segmenter, seed, device)
    hands = _backend(pc, "hand", pc.hand, seed, device).detect(rgb)
    if not hands:
        raise NoHandError("no hand found in the photo")
    i, seg, _, _ = segment_hands(rgb, hands, segmenter, prompts, name=pc.segmenter)
    if seg is None:
        raise NoObjectError(f"found {len(hands)} hand(s) but no held object")
    facts = {"hands_found": len(hands), "hand_index": i, "side": hands[i].side,
             "confidence": {k: v.to_dict() for k, v in seg.confidence.items()}}  # fmt: skip
    if seg.candidates:
        facts["regions"] = list(seg.candidates)  # drawn numbered on the preview, not sent
    return seg.hand_mask, seg.object_mask, facts


def mask_preview(
    path,
    state: dict | None,
    config,
    segment_fn: SegmentFn | None = None,
) -> tuple[np.ndarray | None, str]:
    """``(thumbnail with the masks tinted and the points drawn, one sentence)`` of an upload.

    The photo is segmented at the size the reconstruction uses (prompts scaled to it), so the
    preview shows the mask the reconstruction will start from. Failures become the sentence.
    """
    from easyhoi.app_request import _readable
    from easyhoi.io.image import load_image
    from easyhoi.pipeline import scale_prompts

    if not path:
        return None, "Please upload a photo first."
    try:
        work = load_image(path)
        thumb = load_image(path, max_side=PREVIEW_SIDE).rgb
        prompts = state_prompts(state)
        if prompts is not None:
            prompts = prompts.check(*work.original_size)
            h, w = work.rgb.shape[:2]
            prompts = scale_prompts(prompts, work.scale, (w, h))
        hand, obj, facts = (segment_fn or segment_for_preview)(work.rgb, config, prompts)
    except Exception as exc:  # noqa: BLE001 - every failure becomes a sentence on the page
        if not isinstance(exc, EasyHOIError):
            logger.exception("mask preview failed")
        hint = " Click on the held object to point at it." if state_prompts(state) is None else ""
        return None, _readable(exc, {str(path): f"'{Path(str(path)).name}'"}) + hint
    from easyhoi.perception.feedback import low_confidence_lines

    share = float(np.mean(obj)) * 100
    text = f"Object mask: {share:.1f}% of the photo (green); hand (orange)"
    if facts.get("hand_index"):
        text += f"; hand {facts['hand_index']} ({facts.get('side')}) of {facts['hands_found']}"
    conf = facts.get("confidence") or {}
    if conf:
        text += "; confidence " + ", ".join(f"{k} {c['score']:.2f}" for k, c in conf.items())
    regions = facts.get("regions") or ()
    if regions:
        text += (f"; {len(regions)} object regions to choose from, numbered in "
                 "yellow ('Object region')")  # fmt: skip
    prompted = prompts is not None and prompts.has_object_prompt
    warnings = low_confidence_lines({"confidence": conf}, "demo", prompted)
    text += "." + "".join(f" {w[0].upper()}{w[1:]}." for w in warnings)
    shown = draw_prompts(thumb, state, (hand, obj))
    return draw_regions(shown, regions), text


def draw_regions(rgb: np.ndarray, regions) -> np.ndarray:
    """``rgb`` with the outline of each object region offered (the automatic path's or the
    first click's), numbered as the *Object region* menu numbers them (``--object-choice K``)."""
    import cv2
    from PIL import Image, ImageDraw

    from easyhoi.viz.marks import REGION_COLOUR

    if not len(regions):
        return rgb
    img = np.ascontiguousarray(np.asarray(rgb, np.uint8).copy())
    h, w = img.shape[:2]
    labels = []
    for k, region in enumerate(regions, start=1):
        m = _resize_mask(region, (w, h)).astype(np.uint8)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            continue
        cv2.drawContours(img, contours, -1, REGION_COLOUR, 2)
        # the number at the region's deepest pixel (inside it, whatever its shape); of a ridge
        # of nearly as deep pixels (a bar), the one nearest the ridge's middle
        depth = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        ys, xs = np.nonzero(depth >= depth.max() - 1.0)
        i = int(np.argmin((xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2))
        labels.append((k, float(xs[i]), float(ys[i])))
    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    r = max(6, round(min(w, h) / 40))
    placed: list[tuple[float, float]] = []
    for k, u, v in labels:
        # a number another one already covers moves down (up at the bottom edge) until free
        step = 2 * r if v + 2 * r < h - r else -2 * r
        while any(abs(u - a) < 2 * r and abs(v - b) < 2 * r for a, b in placed):
            v = float(np.clip(v + step, r, h - r))
            if v in (r, h - r):
                break
        placed.append((u, v))
        draw.ellipse((u - r, v - r, u + r, v + r), fill=REGION_COLOUR, outline=(0, 0, 0))
        draw.text((u, v), str(k), fill=(0, 0, 0), anchor="mm")
    return np.asarray(pil)
