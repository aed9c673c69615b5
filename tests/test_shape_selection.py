"""``benchmarks/shape_selection.py``: the family selection re-scored from the recorded scores
reproduces the object step's own winner, and other constants pick what the adjusted scores say."""

from __future__ import annotations

import numpy as np

from easyhoi.perception import shapes
from tests.helpers import load_script


def _row(mask: np.ndarray, name: str) -> dict:
    _, _, info = shapes.fit_shape(mask)
    # a made-up oracle: each family's C.D. is its index + 1 (revolution best)
    oracle = {f: float(i + 1) for i, f in enumerate(shapes.FAMILIES)}
    return {"object": name, "seed": 0, "shape": info["shape"], "scores": info["scores"],
            "flat_by_grip": info["flat_by_grip"], "oracle": oracle, "box_cd": 2.5}  # fmt: skip


def _masks() -> list[tuple[np.ndarray, str]]:
    yy, xx = np.mgrid[:120, :160]
    ellipse = ((xx - 80) / 50.0) ** 2 + ((yy - 60) / 30.0) ** 2 <= 1
    box = np.zeros((120, 160), bool)
    box[30:90, 20:140] = True
    blob = ellipse.copy()
    blob[55:65, 20:80] = False  # a notch: no family but the free ones fits it
    return [(ellipse, "ellipse"), (box, "box"), (blob, "blob")]


def test_stored_constants_reproduce_the_steps_winner():
    sel = load_script("benchmarks/shape_selection.py")
    rows = [_row(m, n) for m, n in _masks()]
    a = sel.arrays(rows)
    idx = sel.choose(a, shapes.COMPLEXITY, shapes.EDGE_WEIGHT)
    assert [sel.FAMILIES[i] for i in idx] == [r["shape"] for r in rows]


def test_other_constants_follow_the_adjusted_scores():
    sel = load_script("benchmarks/shape_selection.py")
    rows = [_row(m, n) for m, n in _masks()]
    a = sel.arrays(rows)
    # every family but the inflation priced out: the inflation wins everywhere
    comp = {f: (0.0 if f == "inflation" else 5.0) for f in shapes.FAMILIES}
    idx = sel.choose(a, comp, 0.0)
    assert all(sel.FAMILIES[i] == "inflation" for i in idx)
    res = sel.evaluate(rows, a, idx)
    inf = shapes.FAMILIES.index("inflation") + 1.0  # the made-up oracle C.D. of the inflation
    assert np.isclose(res["log_cd"], np.log(inf))
    assert res["cd_median"] == inf
    assert res["beats_box"] == int(inf < 2.5) * len(rows)  # one scene per object here
    # a mixed setting: the vectorised choice agrees with a naive re-scoring of every scene
    comp = dict(shapes.COMPLEXITY, cuboid=0.0, inflation=0.12)
    idx = sel.choose(a, comp, 0.1)
    for r, i in zip(rows, idx, strict=True):
        naive = {}
        for f, s in r["scores"].items():
            bonus = s.get("edge_bonus", 0.0)
            edge = 0.1 * bonus / shapes.EDGE_WEIGHT
            naive[f] = round(s["score"] + s["complexity"] - comp[f] - bonus + edge, 6)
        assert sel.FAMILIES[i] == max(naive, key=naive.get)
