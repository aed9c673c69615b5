"""Per-photo prompts of a batch from a JSON or CSV sidecar: parsing, checks, CLI wiring."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from easyhoi.batch_prompts import (
    load_prompts_file,
    parse_prompts_csv,
    parse_prompts_json,
    photo_size,
)
from easyhoi.cli import main
from easyhoi.errors import InvalidInputError
from easyhoi.perception.prompts import Prompts
from tests.test_batch import _fake_pipeline


def _photo(path: Path, size=(64, 48)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    w, h = size
    Image.fromarray(np.full((h, w, 3), 120, np.uint8)).save(path)
    return path


def test_json_and_csv_give_the_same_prompts():
    js = parse_prompts_json(json.dumps({
        "a.jpg": {"object_points": [[10, 20], [12.5, 22]], "hand_point": [3, 4],
                  "background_points": [[7, 8], [9, 1]]},
        "sub/b.png": {"object_box": [1, 2, 30, 40]},
    }))  # fmt: skip
    cs = parse_prompts_csv(
        "photo,kind,x,y,x1,y1\n"
        "a.jpg,object_point,10,20,,\n"
        "\n"
        "a.jpg,background_point,7,8\n"
        "sub/b.png, object_box ,1,2,30,40\n"
        "a.jpg,hand_point,3,4\n"
        "a.jpg,object_point,12.5,22,,\n"
        "a.jpg,background_point,9,1\n"
    )
    assert js == cs
    assert js["a.jpg"] == Prompts(
        ((10.0, 20.0), (12.5, 22.0)), None, (3.0, 4.0), ((7.0, 8.0), (9.0, 1.0))
    )
    assert js["sub/b.png"] == Prompts((), (1.0, 2.0, 30.0, 40.0), None)
    assert parse_prompts_csv("photo,kind,x,y\nc.jpg,object_point,5,6\n") == {
        "c.jpg": Prompts(((5.0, 6.0),))
    }


@pytest.mark.parametrize(
    "text, message",
    [
        ("{nope", "is not valid JSON"),
        ("[1, 2]", "must be a JSON object mapping photo names to prompts, got list"),
        ('{"a.jpg": {"object_point": [1, 2]}}', "photo 'a.jpg': unknown prompt keys: object_point"),
        ('{"a.jpg": {"hand_point": [1, 2, 3]}}', "photo 'a.jpg': hand_point must be 2 finite"),
        ('{"a.jpg": {"object_points": [[1, "x"]]}}', "photo 'a.jpg': object_points entry must be"),
        ('{"a.jpg": [1, 2]}', "photo 'a.jpg': prompts must be a mapping, got list"),
    ],
)
def test_broken_json(text, message):
    with pytest.raises(InvalidInputError, match="prompts file") as exc:
        parse_prompts_json(text)
    assert message in str(exc.value)


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "must start with the header photo,kind,x,y[,x1,y1], got None"),
        ("name,kind,x,y\n", "must start with the header"),
        ("photo,kind,x,y,z\n", "must start with the header"),
        ("photo,kind,x,y\na.jpg,object_pt,1,2\n", "line 2: kind must be one of object_point"),
        ("photo,kind,x,y\na.jpg,object_point,1\n", "line 2: a object_point needs numbers x,y"),
        ("photo,kind,x,y\n\na.jpg,hand_point,1,b\n", "line 3: a hand_point needs numbers x,y"),
        ("photo,kind,x,y,x1,y1\na.jpg,object_box,1,2,3\n", "needs numbers x,y,x1,y1"),
        ("photo,kind,x,y,x1,y1\na.jpg,object_point,1,2,3,4\n", "a object_point has no x1 or y1"),
        ("photo,kind,x,y\na.jpg,object_point,1,2,3\n", "line 2: 5 fields, the header has 4"),
        ("photo,kind,x,y\n,object_point,1,2\n", "line 2: the photo name is empty"),
        ("photo,kind,x,y\na.jpg,hand_point,1,2\na.jpg,hand_point,3,4\n",
         "line 3: photo 'a.jpg' has a second hand_point"),
        ("photo,kind,x,y\na.jpg,object_point,inf,2\n", "needs numbers x,y"),
    ],
)  # fmt: skip
def test_broken_csv(text, message):
    with pytest.raises(InvalidInputError, match="prompts file") as exc:
        parse_prompts_csv(text)
    assert message in str(exc.value)


def test_names_sizes_and_files(tmp_path):
    a = _photo(tmp_path / "a.jpg")
    b1 = _photo(tmp_path / "x" / "b.png")
    b2 = _photo(tmp_path / "y" / "b.png", size=(200, 100))
    photos = {"a.jpg": a, "x/b.png": b1, "y/b.png": b2}
    side = tmp_path / "p.json"

    def load(doc):
        side.write_text(json.dumps(doc))
        return load_prompts_file(side, photos)

    # a unique file name or the path inside the batch folder; photos without prompts are absent
    got = load({"a.jpg": {"object_points": [[63.5, 47.5]]}, "y/b.png": {"hand_point": [150, 90]},
                "x/b.png": {}})  # fmt: skip
    assert got == {"a.jpg": Prompts(((63.5, 47.5),)), "y/b.png": Prompts(hand_point=(150.0, 90.0))}
    with pytest.raises(InvalidInputError, match="unknown photo 'c.jpg': not among the 3 photos"):
        load({"c.jpg": {"hand_point": [1, 1]}})
    with pytest.raises(InvalidInputError, match="'b.png' is ambiguous: x/b.png, y/b.png"):
        load({"b.png": {"hand_point": [1, 1]}})
    photos["z/d.png"] = _photo(tmp_path / "z" / "d.png")
    with pytest.raises(InvalidInputError, match="photo 'z/d.png' is named twice"):
        load({"z/d.png": {"hand_point": [1, 1]}, "d.png": {"hand_point": [2, 2]}})
    # x/b.png is 64x48: 150,90 lies outside it (but inside y/b.png, 200x100)
    with pytest.raises(InvalidInputError, match=r"photo 'x/b.png': --hand-point 150,90 lies outs"):
        load({"x/b.png": {"hand_point": [150, 90]}})
    for name, text, message in (
        ("p.txt", "{}", "must be .json or .csv, got '.txt'"),
        ("missing.json", None, "cannot read the prompts file"),
    ):
        if text is not None:
            (tmp_path / name).write_text(text)
        with pytest.raises(InvalidInputError, match=message):
            load_prompts_file(tmp_path / name, photos)


def test_photo_size_follows_the_exif_orientation(tmp_path):
    path = tmp_path / "rot.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6  # stored landscape, shown portrait
    Image.fromarray(np.zeros((40, 90, 3), np.uint8)).save(path, exif=exif.tobytes())
    assert photo_size(path) == (40, 90)
    from easyhoi.io.image import load_image

    assert load_image(path).original_size == (40, 90)
    with pytest.raises(InvalidInputError, match="cannot read photo"):
        photo_size(tmp_path / "nope.jpg")


def test_cli_batch_prompts_reach_their_photos_and_warnings_are_printed(
    tmp_path, capsys, monkeypatch
):
    perception = {
        "confidence": {"object": {"score": 0.25, "low": True, "reasons": ["no contrast"]}},
        "hand_index": 1, "side": "left", "hands_found": 2, "hand_choice": "first holding an object",
        "notes": ["hand 0 (right) holds no object"],
    }  # fmt: skip
    seen = {}
    _fake_pipeline(monkeypatch, perception, seen)
    d = tmp_path / "in"
    _photo(d / "a.jpg")
    _photo(d / "b.png")
    side = tmp_path / "prompts.csv"
    side.write_text("photo,kind,x,y,x1,y1\na.jpg,object_point,10,12,,\n")
    out = tmp_path / "o"
    rc = main(["batch", str(d), "--out", str(out), "--engine", "inline", "--prompts", str(side),
               "--strict"])  # fmt: skip
    assert rc == 0
    assert seen == {"a.jpg": (Prompts(((10.0, 12.0),)), True), "b.png": (None, True)}
    err = capsys.readouterr().err
    assert ("a.jpg: warning: low confidence in the object mask (score 0.25; weak: no contrast): "
            "add object_point rows") in err  # fmt: skip
    assert (
        "b.png: warning: low confidence in the object mask (score 0.25; weak: no contrast): "
        "give the photo an object_point on the held object in the --prompts file"
    ) in err
    assert "b.png: note: hand 0 (right) holds no object: the result uses hand 1 (left)" in err
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert [len(x["info"]["warnings"]) for x in lines] == [1, 1]


@pytest.mark.parametrize(
    "text, message",
    [
        ("photo,kind,x,y\nzz.jpg,object_point,1,2\n", "unknown photo 'zz.jpg'"),
        ("photo,kind,x,y\na.jpg,object_point,1000,2\n", "--object-point 1000,2 lies outside"),
        ("photo,kind,x,y\na.jpg,point,1,2\n", "line 2: kind must be one of"),
    ],
)
def test_cli_batch_bad_sidecar_exits_2_before_any_work(tmp_path, capsys, monkeypatch, text,
                                                       message):  # fmt: skip
    seen = _fake_pipeline(monkeypatch)
    _photo(tmp_path / "in" / "a.jpg")
    side = tmp_path / "prompts.csv"
    side.write_text(text)
    out = tmp_path / "o"
    rc = main(["batch", str(tmp_path / "in"), "--out", str(out), "--engine", "inline",
               "--prompts", str(side)])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("error: InvalidInputError: prompts file prompts.csv") and message in err
    assert "Traceback" not in err and seen == {} and not out.exists()


def test_the_worker_with_prompts_travels_to_other_processes():
    import pickle

    from easyhoi.batch import ReconstructWorker

    worker = ReconstructWorker(None, prompts={"a.jpg": Prompts(((1.0, 2.0),))}, strict=True)
    back = pickle.loads(pickle.dumps(worker))
    assert back.prompts == {"a.jpg": Prompts(((1.0, 2.0),))} and back.strict is True
