"""Reference 2D hand keypoints on a few perception development photos.

Each file ``tests/data/keypoint_refs/<stem>.json`` holds the 21 keypoints of one hand of the
photo ``photos-dev/<stem>`` in the shared data folder, drawn by eye:

- ``image``: path relative to the shared data folder;
- ``hand_side``: the person's hand ("left"/"right"), matching a hand of the photo's
  perception reference (``tests/data/perception_refs/photos-dev__<stem>.json``);
- ``keypoints``: 21 ``[x, y, visible]`` in pixels of the original image, in the OpenPose / MANO
  order wrist, thumb 1-4, index 1-4, middle 1-4, ring 1-4, little 1-4 (1 = the joint at the
  base of the digit: the thumb's CMC, the fingers' MCP; 4 = the tip). ``visible`` is 1 where
  the joint can be seen, 0 where it is hidden (by the object or the hand itself) and its
  position is an estimate.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

KEYPOINT_REFS_DIR = Path(__file__).resolve().parent / "data" / "keypoint_refs"
KEYPOINT_NAMES = ("wrist",) + tuple(
    f"{finger}{j}"
    for finger in ("thumb", "index", "middle", "ring", "little")
    for j in (1, 2, 3, 4)
)
# For each finger, the indices of its four keypoints, base to tip.
FINGERS = {
    name: tuple(1 + 4 * f + j for j in range(4))
    for f, name in enumerate(("thumb", "index", "middle", "ring", "little"))
}


@dataclass(frozen=True)
class KeypointRef:
    key: str
    image: str
    hand_side: str
    keypoints: np.ndarray  # (21, 3) float: x, y, visible
    note: str

    @property
    def xy(self) -> np.ndarray:
        """(21, 2) float pixel coordinates."""
        return self.keypoints[:, :2]

    @property
    def visible(self) -> np.ndarray:
        """(21,) bool."""
        return self.keypoints[:, 2] > 0.5


def parse_keypoint_ref(data: dict, key: str) -> KeypointRef:
    for field in ("image", "hand_side", "keypoints"):
        if field not in data:
            raise ValueError(f"{key}: missing field {field!r}")
    if data["hand_side"] not in ("left", "right"):
        raise ValueError(f"{key}: hand_side must be 'left' or 'right', got {data['hand_side']!r}")
    kp = data["keypoints"]
    if not isinstance(kp, list) or len(kp) != len(KEYPOINT_NAMES):
        raise ValueError(f"{key}: expected {len(KEYPOINT_NAMES)} keypoints")
    for i, p in enumerate(kp):
        if not (isinstance(p, list) and len(p) == 3 and p[2] in (0, 1)):
            raise ValueError(f"{key}: keypoint {KEYPOINT_NAMES[i]} must be [x, y, 0 or 1]: {p}")
    arr = np.asarray(kp, dtype=np.float64)
    return KeypointRef(key, data["image"], data["hand_side"], arr, str(data.get("note", "")))


def load_keypoint_ref(name: str | Path) -> KeypointRef:
    path = Path(name)
    if not path.is_file():
        path = KEYPOINT_REFS_DIR / f"{Path(name).stem}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no keypoint reference {name!r} in {KEYPOINT_REFS_DIR}")
    return parse_keypoint_ref(json.loads(path.read_text()), path.stem)


def keypoint_ref_keys() -> list[str]:
    return sorted(p.stem for p in KEYPOINT_REFS_DIR.glob("*.json"))


def load_keypoint_refs() -> list[KeypointRef]:
    return [load_keypoint_ref(k) for k in keypoint_ref_keys()]
