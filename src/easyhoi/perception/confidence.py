"""How sure perception is of each mask, and why.

Every perception result carries, per mask (``hand``, ``object``, ``amodal``), a
:class:`MaskConfidence`: a score in [0, 1] and the cues that were weak. A score below
:data:`LOW_CONFIDENCE` is reported as a warning that names the prompt that fixes it. When the
hand detector measures how sure it is of each keypoint, the hand's keypoints get one too
(``keypoints``, :func:`keypoints_confidence`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Scores below this are "low": the result warns, and ``--strict`` turns it into an exit code.
LOW_CONFIDENCE = 0.5


@dataclass(frozen=True)
class MaskConfidence:
    """Score in [0, 1] of one mask and the reasons it is not higher (weak cues, in words)."""

    score: float
    reasons: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self):
        s = float(self.score)
        if not 0.0 <= s <= 1.0:
            raise ValueError(f"confidence score must lie in [0, 1], got {s}")
        object.__setattr__(self, "score", s)
        object.__setattr__(self, "reasons", tuple(str(r) for r in self.reasons))

    @property
    def low(self) -> bool:
        return self.score < LOW_CONFIDENCE

    def to_dict(self) -> dict:
        return {"score": round(self.score, 4), "low": self.low, "reasons": list(self.reasons)}


def keypoints_confidence(confidences) -> MaskConfidence:
    """The hand's keypoints as a whole: the median of the 21 per-keypoint confidences (the
    detector's, e.g. :meth:`~easyhoi.perception.mediapipe_hand.MediaPipeHands.
    keypoint_confidence`). Low when most keypoints are unsure: the hand's pose, which the
    optimizer keeps close to them, is then a guess. Keypoints below :data:`LOW_CONFIDENCE` are
    counted in the reason. ``None`` (the detector could not measure them: it does not find the
    hand again around its own keypoints) scores 0."""
    if confidences is None:
        return MaskConfidence(0.0, ("the detector does not find the hand again around them",))
    c = np.asarray(confidences, dtype=np.float64).reshape(-1)
    if c.size == 0 or not np.isfinite(c).all():
        raise ValueError("keypoint confidences must be finite values")
    unsure = int((c < LOW_CONFIDENCE).sum())
    reasons = (f"{unsure} of {c.size} keypoints move when the detector's crop moves",)
    return MaskConfidence(float(np.clip(np.median(c), 0.0, 1.0)), reasons if unsure else ())
