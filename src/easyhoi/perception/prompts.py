"""User prompts that steer perception when the automatic choice is wrong.

A prompt is one gesture on the photo: a point inside the held object (``--object-point X,Y``,
repeatable), a box around it (``--object-box X0,Y0,X1,Y1``), a point on the hand that holds it
(``--hand-point X,Y``) or a point that is not the object (``--background-point X,Y``,
repeatable: where the mask takes in what is not the object). Coordinates are pixels of the
original photo, x right, y down. Without a photo viewer at hand, one number does it: the
automatic path shows its best distinct object regions, numbered, in ``masks.png``, and
``--object-choice K`` takes region K instead of region 1. With an object point, the regions
are the point's own distinct outlines (the whole object, a part of it, the object with what
lies behind it), and ``--object-choice K`` takes the K-th of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from easyhoi.errors import InvalidInputError

#: Object regions offered for ``--object-choice`` (the one used included), by the automatic
#: path and around an object point. On the development photos the automatic choice reaches
#: IoU >= 0.5 on 32 %, the best of four regions on 42 %; a point's first region on 45-55 % of
#: fresh copies of the photos, the best of its four on 68-71 % (docs/prompts.md).
N_CHOICES = 4


@dataclass(frozen=True)
class Prompts:
    """Pixel prompts for one photo (all optional).

    Attributes:
        object_points: ((x, y), ...) points inside the held object.
        object_box: (x0, y0, x1, y1) box around the held object, or None.
        hand_point: (x, y) point on the hand that holds the object, or None.
        background_points: ((x, y), ...) points that are not the object.
        object_choice: K >= 1: the K-th object region (1 is the one chosen without it;
            ``masks.png`` numbers them) of the automatic path or, with object points, of the
            first point's distinct outlines; or None.
    """

    object_points: tuple[tuple[float, float], ...] = ()
    object_box: tuple[float, float, float, float] | None = None
    hand_point: tuple[float, float] | None = None
    background_points: tuple[tuple[float, float], ...] = ()
    object_choice: int | None = None

    def __post_init__(self):
        k = self.object_choice
        if k is None:
            return
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise InvalidInputError(f"--object-choice must be a whole number >= 1, got {k!r}")
        if self.object_box is not None:
            raise InvalidInputError(
                "--object-choice picks one of the object regions of the automatic path or of "
                "an object point; it cannot be combined with --object-box"
            )

    @property
    def empty(self) -> bool:
        return (
            not self.object_points
            and self.object_box is None
            and self.hand_point is None
            and not self.background_points
            and self.object_choice is None
        )

    @property
    def has_object_prompt(self) -> bool:
        return bool(self.object_points) or self.object_box is not None

    @property
    def steers_object(self) -> bool:
        """Whether any prompt steers the object's segmentation: object points, a box,
        background points or a region choice (a hand point only picks the hand)."""
        return (
            self.has_object_prompt or bool(self.background_points) or self.object_choice is not None
        )

    def check(self, width: int, height: int) -> Prompts:
        """Return self if every prompt lies inside a ``width`` x ``height`` photo, else raise."""
        for name, pts in (
            ("--object-point", self.object_points),
            ("--hand-point", () if self.hand_point is None else (self.hand_point,)),
            ("--background-point", self.background_points),
        ):
            for x, y in pts:
                if not (0 <= x < width and 0 <= y < height):
                    raise InvalidInputError(
                        f"{name} {x:g},{y:g} lies outside the {width}x{height} photo "
                        f"(x in [0, {width}), y in [0, {height}))"
                    )
        if self.object_box is not None:
            x0, y0, x1, y1 = self.object_box
            if not (x0 < x1 and y0 < y1):
                raise InvalidInputError(
                    f"--object-box {x0:g},{y0:g},{x1:g},{y1:g} must have x0 < x1 and y0 < y1"
                )
            if x1 <= 0 or y1 <= 0 or x0 >= width or y0 >= height:
                raise InvalidInputError(
                    f"--object-box {x0:g},{y0:g},{x1:g},{y1:g} does not overlap the "
                    f"{width}x{height} photo"
                )
        return self

    def to_dict(self) -> dict:
        return {
            "object_points": [list(p) for p in self.object_points],
            "object_box": None if self.object_box is None else list(self.object_box),
            "hand_point": None if self.hand_point is None else list(self.hand_point),
            "background_points": [list(p) for p in self.background_points],
            "object_choice": self.object_choice,
        }

    @classmethod
    def from_dict(cls, d: dict) -> Prompts:
        """Inverse of :meth:`to_dict`; validates types (raises InvalidInputError)."""
        if not isinstance(d, dict):
            raise InvalidInputError(f"prompts must be a mapping, got {type(d).__name__}")
        keys = {"object_points", "object_box", "hand_point", "background_points", "object_choice"}
        unknown = set(d) - keys
        if unknown:
            raise InvalidInputError(f"unknown prompt keys: {', '.join(sorted(unknown))}")
        pts = d.get("object_points") or []
        box = d.get("object_box")
        hp = d.get("hand_point")
        bg = d.get("background_points") or []
        for name, seq in (("object_points", pts), ("background_points", bg)):
            if not isinstance(seq, (list, tuple)):
                raise InvalidInputError(f"{name} must be a list of [x, y] points, got {seq!r}")
        return cls(
            object_points=tuple(_numbers(p, 2, "object_points entry") for p in pts),
            object_box=None if box is None else _numbers(box, 4, "object_box"),
            hand_point=None if hp is None else _numbers(hp, 2, "hand_point"),
            background_points=tuple(_numbers(p, 2, "background_points entry") for p in bg),
            object_choice=d.get("object_choice"),
        )


def _numbers(value, n: int, name: str) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be {n} numbers, got {value!r}") from exc
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in arr)


def parse_numbers(text: str, n: int, flag: str) -> tuple[float, ...]:
    """Parse ``"X,Y"`` (n=2) or ``"X0,Y0,X1,Y1"`` (n=4) from a command-line flag."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != n or not all(np.isfinite(vals)):
        form = "X,Y" if n == 2 else "X0,Y0,X1,Y1"
        raise InvalidInputError(f"{flag} expects {form} (pixels), got {text!r}")
    return vals
