"""MediaPipe graphs are built once per process and shared: same keypoints as fresh graphs."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from easyhoi.io.image import load_image  # noqa: E402
from easyhoi.perception import mediapipe_hand as mph  # noqa: E402


def _keypoints(dets):
    return [(d.side, d.keypoints2d.round(9).tolist(), d.meta["pass"]) for d in dets]


def test_shared_graphs_give_the_keypoints_of_fresh_ones(shared_data, monkeypatch):
    palm = load_image(shared_data / "images" / "hort-can.png").rgb
    # grey-scale controller photo: the palm detector misses, the ROI search finds the hand
    roi = load_image(shared_data / "images" / "easyhoi-game-controller.jpg").rgb
    monkeypatch.setattr(mph, "_GRAPHS", {})
    first = [_keypoints(mph.MediaPipeHands().detect(im)) for im in (palm, roi)]
    assert first[0] and first[0][0][2] == "palm"
    assert first[1] and first[1][0][2] == "roi_search"
    graphs = dict(mph._GRAPHS)
    assert len(graphs) == 2  # one palm pipeline, one landmark-only graph
    # a second detector reuses them, in the other order, and finds the same keypoints
    again = [_keypoints(mph.MediaPipeHands().detect(im)) for im in (roi, palm)][::-1]
    assert mph._GRAPHS == graphs
    assert again == first
    # other settings get their own graph
    mph.MediaPipeHands(max_hands=1).detect(palm)
    assert len(mph._GRAPHS) == 3
    assert np.isfinite(np.array(first[0][0][1])).all()
