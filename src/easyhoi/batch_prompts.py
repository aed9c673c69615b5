"""Per-photo prompts for a batch, from a sidecar file (``easyhoi batch --prompts FILE``).

Two formats, chosen by the file's extension:

* JSON (``.json``): an object mapping a photo name to its prompts, with the keys of
  :meth:`easyhoi.perception.prompts.Prompts.from_dict`::

      {"IMG_1.jpg": {"object_points": [[412, 310]], "hand_point": [200, 420]},
       "sub/IMG_2.jpg": {"object_box": [100, 80, 380, 300]}}

* CSV (``.csv``): a header ``photo,kind,x,y,x1,y1`` (``x1``, ``y1`` optional) and one row per
  prompt; ``kind`` is ``object_point`` (repeatable), ``object_box`` (``x,y`` = top left,
  ``x1,y1`` = bottom right), ``hand_point``, ``background_point`` (repeatable) or
  ``object_choice`` (``x`` = K, object region K of the automatic path or of the photo's first
  object point; no ``y``)::

      photo,kind,x,y,x1,y1
      IMG_1.jpg,object_point,412,310,,
      IMG_2.jpg,object_box,100,80,380,300
      IMG_3.jpg,object_choice,2,,,

A photo name is its path inside the batch folder (``sub/IMG_2.jpg``) or, when no two photos
share it, its file name. Coordinates are pixels of the photo as stored (x right, y down).
Everything is checked before any photo is processed: the file's syntax, unknown or ambiguous
photo names, and prompts that lie outside their photo; each error names the file, the photo
and, for CSV, the line.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

from easyhoi.errors import InvalidInputError
from easyhoi.perception.prompts import Prompts

__all__ = ["load_prompts_file", "parse_prompts_csv", "parse_prompts_json", "photo_size"]

_KINDS = ("object_point", "object_box", "hand_point", "background_point", "object_choice")
_COLUMNS = {"object_box": ("x", "y", "x1", "y1"), "object_choice": ("x",)}
_REPEATABLE = {"object_point": "object_points", "background_point": "background_points"}


def parse_prompts_json(text: str, source: str = "prompts file") -> dict[str, Prompts]:
    """``{photo name: Prompts}`` from the JSON form (raises :class:`InvalidInputError`)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{source} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InvalidInputError(
            f"{source} must be a JSON object mapping photo names to prompts, "
            f"got {type(data).__name__}"
        )
    out = {}
    for name, entry in data.items():
        try:
            out[str(name)] = Prompts.from_dict(entry)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{source}, photo '{name}': {exc}") from None
    return out


def parse_prompts_csv(text: str, source: str = "prompts file") -> dict[str, Prompts]:
    """``{photo name: Prompts}`` from the CSV form (raises :class:`InvalidInputError`)."""
    rows = csv.reader(io.StringIO(text))
    header = next(rows, None)
    cols = [c.strip().lower() for c in header or ()]
    if cols[:4] != ["photo", "kind", "x", "y"] or any(c not in ("x1", "y1") for c in cols[4:]):
        raise InvalidInputError(
            f"{source} must start with the header photo,kind,x,y[,x1,y1], got {header!r}"
        )
    found: dict[str, dict] = {}
    for row in rows:
        line = rows.line_num
        if not any(c.strip() for c in row):
            continue
        where = f"{source}, line {line}"
        if len(row) > len(cols):
            raise InvalidInputError(f"{where}: {len(row)} fields, the header has {len(cols)}")
        cells = dict(zip(cols, (c.strip() for c in row), strict=False))
        photo, kind = cells.get("photo", ""), cells.get("kind", "")
        if not photo:
            raise InvalidInputError(f"{where}: the photo name is empty")
        if kind not in _KINDS:
            raise InvalidInputError(
                f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}"
            )
        names = _COLUMNS.get(kind, ("x", "y"))
        extra = [n for n in ("y", "x1", "y1") if n not in names and cells.get(n)]
        if extra:
            raise InvalidInputError(f"{where}: a {kind} has no {' or '.join(extra)}")
        try:
            values = [float(cells.get(n) or "nan") for n in names]
        except ValueError:
            values = [float("nan")]
        if any(v != v or v in (float("inf"), float("-inf")) for v in values):
            need = ",".join(names)
            raise InvalidInputError(f"{where}: a {kind} needs numbers {need}, got {row!r}")
        if kind == "object_choice":
            if values[0] != int(values[0]) or values[0] < 1:
                raise InvalidInputError(f"{where}: an object_choice is a whole number >= 1")
            values = int(values[0])
        entry = found.setdefault(photo, {"object_points": [], "background_points": []})
        if kind in _REPEATABLE:
            entry[_REPEATABLE[kind]].append(values)
        elif kind in entry:
            raise InvalidInputError(f"{where}: photo '{photo}' has a second {kind}")
        else:
            entry[kind] = values
    out = {}
    for photo, entry in found.items():
        try:
            out[photo] = Prompts.from_dict(entry)
        except InvalidInputError as exc:  # an object choice next to object points
            raise InvalidInputError(f"{source}, photo '{photo}': {exc}") from None
    return out


def photo_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of a photo as :func:`easyhoi.io.image.load_image` turns it upright.

    Reads the header only (the EXIF orientation swaps the sides of rotated photos).
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            w, h = im.size
            orientation = im.getexif().get(0x0112, 1)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise InvalidInputError(f"cannot read photo {path}: {exc}") from None
    return (h, w) if orientation in (5, 6, 7, 8) else (w, h)


def _resolve(name: str, keys: Sequence[str]) -> str:
    if name in keys:
        return name
    by_file = [k for k in keys if Path(k).name == name]
    if len(by_file) == 1:
        return by_file[0]
    if by_file:
        raise InvalidInputError(
            f"photo name '{name}' is ambiguous: {', '.join(by_file)}; use the path inside the "
            "batch folder"
        )
    raise InvalidInputError(
        f"unknown photo '{name}': not among the {len(keys)} photos of the batch"
    )


def load_prompts_file(
    path: str | Path, photos: Mapping[str, str | Path], check_sizes: bool = True
) -> dict[str, Prompts]:
    """Prompts per batch photo from a sidecar file, everything checked.

    Args:
        path: the JSON or CSV sidecar.
        photos: batch photo name (path inside the batch folder, POSIX) -> photo file.
        check_sizes: check every prompt against its photo's size (:func:`photo_size`).

    Returns:
        dict: batch photo name -> :class:`Prompts` (photos without prompts are absent).

    Raises:
        InvalidInputError: Missing or unreadable file, unknown extension, bad syntax or values,
            unknown or ambiguous photo names, the same photo named twice, prompts outside their
            photo.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"cannot read the prompts file {p}: {exc}") from None
    source = f"prompts file {p.name}"
    ext = p.suffix.lower()
    if ext == ".json":
        parsed = parse_prompts_json(text, source)
    elif ext == ".csv":
        parsed = parse_prompts_csv(text, source)
    else:
        raise InvalidInputError(f"prompts file {p} must be .json or .csv, got '{ext}'")
    keys = sorted(photos)
    out: dict[str, Prompts] = {}
    for name, prompts in parsed.items():
        try:
            key = _resolve(name, keys)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{source}: {exc}") from None
        if key in out:
            raise InvalidInputError(f"{source}: photo '{key}' is named twice")
        if prompts.empty:
            continue
        if check_sizes:
            try:
                prompts.check(*photo_size(photos[key]))
            except InvalidInputError as exc:
                raise InvalidInputError(f"{source}, photo '{key}': {exc}") from None
        out[key] = prompts
    return out
