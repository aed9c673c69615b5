"""Ray engine on a local 2-CPU cluster bound to 127.0.0.1 (slow: the cluster takes ~10-20 s)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from easyhoi.batch import discover_images, item_seed, run_batch, summarize_photo

pytestmark = pytest.mark.slow

ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'easyhoi[distributed]')")


@pytest.fixture(scope="module")
def cluster():
    from easyhoi.distributed import _ray_init

    assert _ray_init(ray, 2, None) is True  # the engine's own local-cluster start
    assert _ray_init(ray, 2, None) is False  # an initialised session is reused
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    d = tmp_path_factory.mktemp("photos")
    rng = np.random.default_rng(0)
    for i in range(5):
        Image.fromarray(rng.integers(0, 256, (40, 56, 3), dtype=np.uint8)).save(d / f"p{i}.png")
    (d / "zero.jpg").write_bytes(b"")
    (d / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x01" * 40)
    return d


def _summaries(out):
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(out.rglob("summary.json"))}


def test_ray_engine_matches_local_engine(cluster, photos, tmp_path):
    images = discover_images(photos)
    progress = []
    on_ray = run_batch(
        images, tmp_path / "ray", summarize_photo, engine="ray", workers=2, seed=9,
        progress=lambda rec, done, total: progress.append((rec.path, done, total)),
    )  # fmt: skip
    local = run_batch(images, tmp_path / "local", summarize_photo, engine="inline", seed=9)
    status = {r.path: (r.status, r.error_type, r.exit_code) for r in on_ray.records}
    assert status == {r.path: (r.status, r.error_type, r.exit_code) for r in local.records}
    assert status["zero.jpg"] == ("failed", "InvalidInputError", 2)
    assert status["broken.png"][0] == "failed"
    assert sum(s[0] == "ok" for s in status.values()) == 5
    # same per-photo seeds and outputs as the local run
    assert _summaries(tmp_path / "ray") == _summaries(tmp_path / "local")
    assert {k: v["seed"] for k, v in _summaries(tmp_path / "ray").items()} == {
        f"p{i}": item_seed(9, f"p{i}.png") for i in range(5)
    }
    # live progress: one call per photo, counting up
    assert [p[1:] for p in progress] == [(i, 7) for i in range(1, 8)]
    assert sorted(p[0] for p in progress) == sorted(status)
    # the session the test started is reused and left running
    assert cluster.is_initialized()
    assert cluster.cluster_resources().get("CPU") == 2
    assert [n["NodeManagerAddress"] for n in cluster.nodes()] == ["127.0.0.1"]


def test_ray_resume_skips_finished(cluster, photos, tmp_path):
    images = discover_images(photos)
    run_batch(images, tmp_path / "o", summarize_photo, engine="ray", workers=2)
    again = run_batch(images, tmp_path / "o", summarize_photo, engine="ray", workers=2,
                      resume=True)  # fmt: skip
    assert (again.skipped, again.failed, again.ok) == (5, 2, 0)
