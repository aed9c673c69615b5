"""The user's prompts drawn on a picture of the photo: where they clicked, in one style for the
web demo's photo and the result's ``masks.png``.

Object points are green discs, the hand point an orange disc, background points red discs with
a white cross, all outlined in white; the object box a green rectangle, and a box's first
corner, before the second is given, a green square. The object regions offered for
``--object-choice`` are yellow (:data:`REGION_COLOUR`) in both places too.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BACKGROUND_COLOUR", "HAND_COLOUR", "OBJECT_COLOUR", "REGION_COLOUR", "draw_marks"]

OBJECT_COLOUR = (40, 220, 90)
HAND_COLOUR = (255, 140, 0)
BACKGROUND_COLOUR = (230, 40, 60)
#: The object regions offered for ``--object-choice`` (the demo's preview and ``masks.png``).
REGION_COLOUR = (255, 200, 0)


def draw_marks(rgb: np.ndarray, prompts: dict, sx: float, sy: float) -> np.ndarray:
    """A copy of ``rgb`` with the prompts drawn.

    Args:
        rgb (np.ndarray): (h, w, 3) uint8 picture of the photo.
        prompts (dict): Prompts in photo pixels, with the keys of
            :meth:`easyhoi.perception.prompts.Prompts.to_dict` (``object_points``,
            ``object_box``, ``hand_point``, ``background_points``; missing or empty ones are not
            drawn) and optionally ``box_corner`` (a box's first corner, [x, y]).
        sx (float): Picture pixels per photo pixel along x.
        sy (float): The same along y.

    Returns:
        np.ndarray: (h, w, 3) uint8.
    """
    from PIL import Image, ImageDraw

    img = np.ascontiguousarray(np.asarray(rgb, np.uint8))
    h, w = img.shape[:2]
    r = max(3, round(min(w, h) / 60))
    pil = Image.fromarray(img.copy())
    draw = ImageDraw.Draw(pil)
    if prompts.get("object_box"):
        x0, y0, x1, y1 = prompts["object_box"]
        draw.rectangle((x0 * sx, y0 * sy, x1 * sx, y1 * sy), outline=OBJECT_COLOUR, width=2)
    if prompts.get("box_corner"):
        u, v = prompts["box_corner"][0] * sx, prompts["box_corner"][1] * sy
        draw.rectangle((u - r, v - r, u + r, v + r), fill=OBJECT_COLOUR, outline=(255, 255, 255))
    points = [(p, OBJECT_COLOUR) for p in prompts.get("object_points") or []]
    if prompts.get("hand_point"):
        points.append((prompts["hand_point"], HAND_COLOUR))
    points += [(p, BACKGROUND_COLOUR) for p in prompts.get("background_points") or []]
    for (x, y), colour in points:
        u, v = x * sx, y * sy
        draw.ellipse((u - r, v - r, u + r, v + r), fill=colour, outline=(255, 255, 255), width=2)
        if colour == BACKGROUND_COLOUR:  # a cross: "not this"
            d = 0.5 * r
            draw.line((u - d, v - d, u + d, v + d), fill=(255, 255, 255), width=2)
            draw.line((u - d, v + d, u + d, v - d), fill=(255, 255, 255), width=2)
    return np.asarray(pil)
