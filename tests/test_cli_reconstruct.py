"""``easyhoi reconstruct`` with several photos runs through the batch runner."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from PIL import Image

from easyhoi.batch import MANIFEST_JSONL, item_seed, read_manifest
from easyhoi.cli import main


def _photo(path: Path, value: int, fmt: str | None = None) -> Path:
    Image.fromarray(np.full((48, 64, 3), value, np.uint8)).save(path, format=fmt)
    return path


def _fake_pipeline(monkeypatch) -> dict:
    """A stand-in reconstruction that writes one file into the folder it is given."""
    import easyhoi.pipeline as pipeline
    from easyhoi.io.image import load_image

    seen = {}

    def reconstruct_photo(image, folder, settings, seed=None, **kw):
        img = load_image(image)
        seen[str(image)] = (Path(folder), seed, settings.hand_model.name)
        Path(folder).mkdir(parents=True, exist_ok=True)
        doc = {"image": str(image), "mean": float(img.rgb.mean())}
        (Path(folder) / "result.json").write_text(json.dumps(doc))
        return SimpleNamespace(
            files=[Path(folder) / "result.json"], seconds=0.0, perception={"notes": []}
        )

    monkeypatch.setattr(pipeline, "reconstruct_photo", reconstruct_photo)
    return seen


def test_same_stem_photos_get_distinct_folders_and_a_manifest(tmp_path, monkeypatch, capsys):
    seen = _fake_pipeline(monkeypatch)
    a = _photo(tmp_path / "x.png", 10)
    b = _photo(tmp_path / "x.jpg", 200, "JPEG")
    sub = tmp_path / "sub"
    sub.mkdir()
    c = _photo(sub / "y.png", 90)
    out = tmp_path / "out"
    assert main(["reconstruct", str(a), str(b), str(c), "--out", str(out), "--seed", "2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "manifest.csv", "manifest.jsonl", "sub", "x_jpg", "x_png",
    ]  # fmt: skip
    assert [p.name for p in (out / "sub").iterdir()] == ["y"]  # the tree is kept, no nesting
    docs = {f: json.loads((out / f / "result.json").read_text()) for f in ("x_png", "x_jpg")}
    assert docs["x_png"]["image"] == str(a) and docs["x_jpg"]["image"] == str(b)
    assert docs["x_png"]["mean"] == 10 and docs["x_jpg"]["mean"] > 150  # never one replacing
    # each photo's seed is derived from the run's seed and its name, as in `batch`
    assert seen[str(a)] == (out / "x_png", item_seed(2, "x.png"), "openhand")
    assert seen[str(c)][1] == item_seed(2, "sub/y.png")
    records = read_manifest(out / MANIFEST_JSONL)
    assert sorted(r["path"] for r in records) == ["sub/y.png", "x.jpg", "x.png"]
    assert all(r["status"] == "ok" for r in records)
    assert "3 photos: 3 ok, 0 failed" in capsys.readouterr().out


def test_one_photo_goes_to_out_stem(tmp_path, monkeypatch):
    seen = _fake_pipeline(monkeypatch)
    a = _photo(tmp_path / "x.png", 10)
    out = tmp_path / "out"
    assert main(["reconstruct", str(a), "--out", str(out), "-q"]) == 0
    assert [p.name for p in out.iterdir()] == ["x"]
    assert seen[str(a)][0] == out / "x"


def test_a_failing_photo_among_several_exits_8(tmp_path, monkeypatch, capsys):
    _fake_pipeline(monkeypatch)
    a = _photo(tmp_path / "a.png", 10)
    bad = tmp_path / "b.png"
    bad.write_bytes(b"not an image")
    out = tmp_path / "out"
    assert main(["reconstruct", str(a), str(bad), "--out", str(out)]) == 8
    records = {r["path"]: r for r in read_manifest(out / MANIFEST_JSONL)}
    assert records["a.png"]["status"] == "ok"
    assert (records["b.png"]["status"], records["b.png"]["exit_code"]) == ("failed", 2)
    assert "b.png: InvalidInputError" in capsys.readouterr().err


def test_an_existing_result_is_refused_unless_overwrite(tmp_path, monkeypatch, capsys):
    _fake_pipeline(monkeypatch)
    a = _photo(tmp_path / "x.png", 10)
    out = tmp_path / "out"
    assert main(["reconstruct", str(a), "--out", str(out), "-q"]) == 0
    first = (out / "x" / "result.json").read_text()
    _photo(a, 99)  # the photo changes; its result folder is there already
    assert main(["reconstruct", str(a), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "already exists; pass --overwrite" in err and "Traceback" not in err
    assert (out / "x" / "result.json").read_text() == first  # untouched
    assert main(["reconstruct", str(a), "--out", str(out), "-q", "--overwrite"]) == 0
    assert json.loads((out / "x" / "result.json").read_text())["mean"] == 99
