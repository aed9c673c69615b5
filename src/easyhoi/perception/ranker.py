"""The ranking of held-object hypotheses: which region proposal is the object the hand holds.

Every hypothesis touching the hand on its grip side is described by the cues of
:mod:`easyhoi.perception.held_object` and :mod:`easyhoi.perception.grasp_cues`. The cheap cues
(summed per base segment) pick the :data:`RANK_TOP` best by the hand-set score; those get the cues
that need their mask drawn, and :func:`ranker_score` orders them: the hand-set score plus a
weighted sum of the cues (:data:`FEATURES`). The weights were fitted on the tuning half of the
development photos by ``benchmarks/fit_ranker.py`` (a listwise ranking loss, each weight kept to
the sign its cue's reason gives); the hand-set score stays the evidence that a region is a held
object at all (``Hypotheses.evidence``).
"""

from __future__ import annotations

import numpy as np

from easyhoi.perception import grasp_cues as gc
from easyhoi.perception import held_object as ho
from easyhoi.perception.proposals import Proposals

#: Hypotheses (best by the cheap cues) that get every cue before the final ranking.
RANK_TOP = 160
#: Features of the learned ranking (:func:`ranker_features`): the hand-set score of
#: :func:`held_object.score`, then the cues (the grasp cues times the same object-likeness gate
#: as in that score, lengths and areas capped as there, the area also as its logarithm).
FEATURES = (
    "score",
    "fingers",
    "thumb",
    "grasp",
    "contact",
    "skin",
    "border",
    "size",
    "far",
    "contrast",
    "solidity",
    *gc.EXTRA,
    "log_area",
)
#: Weights of the learned ranking, fitted by ``benchmarks/fit_ranker.py`` (listwise ranking loss
#: on the tuning half of the development photos, L2 0.1, each weight of the sign its cue's reason
#: gives, the hand-set score's weight fixed at 1); zero where the fit found no use for a cue.
RANKER_WEIGHTS = {
    "score": 1.0,
    "fingers": 0.843,
    "thumb": 0.0,
    "grasp": 1.053,
    "contact": 0.124,
    "skin": 0.0,
    "border": 0.0,
    "size": 0.0,
    "far": 0.0,
    "contrast": 0.785,
    "solidity": 1.605,
    "sides": 0.0,
    "back": 0.0,
    "cross": 0.0,
    "pinch": 0.0,
    "wrap": -0.667,
    "spread": 0.0,
    "flanks": -2.436,
    "amodal": 0.0,
    "log_area": 0.374,
}


def ranker_features(cues: np.ndarray) -> np.ndarray:
    """(n, len(FEATURES)) features of (n, len(CUES)) cues (see :data:`FEATURES`)."""
    c = {k: cues[:, j] for j, k in enumerate(ho.CUES)}
    lo, hi = ho.AREA_RANGE
    area = np.maximum(c["area"], 1e-6)
    # grasp evidence counts only as much as the region looks like an object, as in the
    # hand-set score: a thin halo around the fingers touches all of them but is no object
    gate = (0.25 + 0.75 * c["contrast"]) * (0.25 + 0.75 * c["solidity"])
    f = {
        "score": ho.score(cues),
        "fingers": gate * np.minimum(c["fingers"], 4.0),
        "thumb": gate * c["thumb"],
        "grasp": gate * c["grasp"],
        "contact": gate * np.minimum(c["contact"], 2.0),
        "skin": c["skin"],
        "border": np.minimum(c["border"], ho.BORDER_CAP),
        "size": np.abs(np.log(area / np.clip(area, lo, hi))),
        "far": c["far"],
        "contrast": c["contrast"],
        "solidity": c["solidity"],
        "sides": c["sides"],
        "back": np.minimum(c["back"], 2.0),
        "cross": c["cross"],
        "pinch": c["pinch"],
        "wrap": c["wrap"],
        "spread": c["spread"],
        "flanks": c["flanks"],
        "amodal": c["amodal"],
        "log_area": np.log(area),
    }
    return np.stack([f[k] for k in FEATURES], 1)


def ranker_score(cues: np.ndarray, weights=None) -> np.ndarray:
    """Learned score of (n, len(CUES)) cues: :data:`RANKER_WEIGHTS` (or ``weights``, a dict by
    feature name or an array in :data:`FEATURES` order) times :func:`ranker_features`."""
    w = RANKER_WEIGHTS if weights is None else weights
    if isinstance(w, dict):
        w = np.array([w[k] for k in FEATURES])
    return ranker_features(cues) @ np.asarray(w, np.float64)


def candidate_cues(props: Proposals, scene: ho.Scene, top: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``top`` hypotheses touching the hand's grip side, best by the cheap cues first, and
    the cues of every hypothesis, the drawn ones filled in for those: (indices, (n, len(CUES)))."""
    cues = ho.describe(props, scene)
    s = ho.score(cues, gated=False)
    touching = cues[:, ho.CUES.index("contact")] > 0
    s = np.where(touching, s, -np.inf)  # a held object touches the hand on its grip side
    order = [int(i) for i in np.argsort(-s, kind="stable")[:top] if np.isfinite(s[i])]
    ho.drawn_cues(props, scene, cues, order)
    return np.asarray(order, np.int64), cues


def rank(props: Proposals, scene: ho.Scene, top: int = RANK_TOP) -> ho.Hypotheses:
    """Cues and scores of all hypotheses: the ``top`` best by the cheap cues also get the cues
    that need the mask drawn, and are ranked by :func:`ranker_score` (the others score -inf);
    their hand-set :func:`held_object.score` is the ``evidence``."""
    idx, cues = candidate_cues(props, scene, top)
    s2 = np.full(len(cues), -np.inf)
    ev = np.full(len(cues), -np.inf)
    if len(idx):
        s2[idx] = ranker_score(cues[idx])
        ev[idx] = ho.score(cues[idx])
    return ho.Hypotheses(props, cues, s2, ev)
