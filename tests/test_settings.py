"""A run's settings are resolved once (config, hand model, seed, device) and reach every step."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from easyhoi.cli import build_parser, main, run_from_args
from easyhoi.config import MAX_SEED, get_preset, with_overrides
from easyhoi.errors import InvalidInputError
from easyhoi.settings import RunSettings, resolve_run
from easyhoi.testing.mano_synth import write_synthetic_mano

SRC = Path(__file__).resolve().parents[1] / "src" / "easyhoi"
SHORT = ["--set", "optim.camera.max_iters=10", "--set", "optim.contact.max_iters=10",
         "--set", "optim.refine.max_iters=5", "-q"]  # fmt: skip


@pytest.fixture(scope="module")
def photo(tmp_path_factory) -> Path:
    """A synthetic photo (256 px) whose hand and held object the offline perception finds."""
    from easyhoi.synth.scene import make_scene

    path = tmp_path_factory.mktemp("photo") / "held.png"
    Image.fromarray(make_scene(7, image_size=256).image).save(path)
    return path


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_file_io_does_not_depend_on_pictures():
    for path in sorted((SRC / "io").glob("*.py")):
        assert not [m for m in _imports(path) if m.startswith("easyhoi.viz")], path.name


def test_only_the_settings_load_the_hand_model():
    """Perception, the optimizer and the pictures take the run's model; none loads one."""
    for rel in ("perception/chain.py", "optim/run.py", "viz/overlay.py", "viz/stages.py",
                "viz/report.py", "pipeline.py", "result_folder.py"):  # fmt: skip
        assert "load_hand_model" not in (SRC / rel).read_text(encoding="utf-8"), rel


def test_resolve_run(monkeypatch):
    # a machine without a GPU: "auto" is the CPU and asking for cuda is an error
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    run = resolve_run()
    assert run.config is get_preset() and run.seed == 0 and run.device == "cpu"
    assert run.hand_model.name == "openhand" and run.hand_model.v_template.dtype == torch.float32
    cfg = with_overrides(get_preset("paper"), {"optim.seed": 9, "optim.dtype": "float64"})
    run = resolve_run(cfg)
    assert run.seed == 9 and run.hand_model.v_template.dtype == torch.float64
    assert resolve_run(cfg, seed=4).seed == 4 and resolve_run(cfg, seed=4).config.name == "paper"
    again = run.with_seed(11)
    assert again.seed == 11 and again.hand_model is run.hand_model and run.seed == 9
    with pytest.raises(InvalidInputError, match="device"):
        resolve_run(device="cuda")
    for bad in (-1, MAX_SEED + 1, 10**30):
        with pytest.raises(InvalidInputError, match="seed"):
            resolve_run(seed=bad)
    with pytest.raises(InvalidInputError, match="EasyHOIConfig"):
        resolve_run(get_preset().optim)  # type: ignore[arg-type]


def _args(*argv: str):
    return build_parser().parse_args(["reconstruct", "x.png", "--out", "o", *argv])


def test_seed_flag_is_an_alias_of_the_config_seed():
    assert run_from_args(_args()).seed == 0
    assert run_from_args(_args("--seed", "3")).seed == 3
    assert run_from_args(_args("--set", "optim.seed=5")).seed == 5
    assert run_from_args(_args("--set", "optim.seed=5", "--seed", "5")).seed == 5
    with pytest.raises(InvalidInputError, match="--seed 4 and --set optim.seed=5 disagree"):
        run_from_args(_args("--set", "optim.seed=5", "--seed", "4"))
    with pytest.raises(InvalidInputError, match="disagree"):
        run_from_args(_args("--set", 'optim={"seed": 5}', "--seed", "4"))


def test_conflicting_seeds_and_bad_seeds_exit_2_before_any_work(tmp_path, capsys, photo):
    out = tmp_path / "out"
    for extra in (["--seed", "4", "--set", "optim.seed=5"], ["--seed", str(2**40)]):
        assert main(["reconstruct", str(photo), "--out", str(out), *extra]) == 2
        assert "InvalidInputError" in capsys.readouterr().err
    assert not out.exists()


def test_the_seed_reaches_the_perception_backends(photo, monkeypatch):
    from easyhoi.perception import chain
    from easyhoi.perception.chain import backend_seed, perceive

    image = np.asarray(Image.open(photo).convert("RGB"))
    seeds, built = [], {}
    create = chain.create

    def spy(role, name, **kw):
        seeds.append((role, kw.get("seed")))
        built[role] = create(role, name, **kw)
        return built[role]

    monkeypatch.setattr(chain, "create", spy)
    perceive(image, resolve_run(seed=5))
    monkeypatch.undo()
    assert ("segmenter", 5) in seeds and ("amodal", 5) in seeds
    # the backends that were used hold the run's seed (GrabCut's initial clustering uses it)
    assert built["segmenter"].seed == 5 and built["amodal"].seed == 5
    assert backend_seed(MAX_SEED) == 2**31 - 1 and backend_seed(7) == 7


def test_mano_is_not_loaded_by_name_below_the_settings():
    from easyhoi.hand import builtin_hand_model

    assert builtin_hand_model("open").name == "openhand"
    with pytest.raises(InvalidInputError, match="resolve_run"):
        builtin_hand_model("mano")


@pytest.mark.slow
def test_mano_folder_given_once_works_end_to_end(tmp_path, capsys, monkeypatch, photo):
    """``reconstruct --hand-model mano --mano-dir D`` (no EASYHOI_MANO_DIR) with a synthetic
    MANO file: perception fits it, the optimizer poses it, the pictures draw it; ``--seed`` and
    ``--set optim.seed`` give the same result."""
    monkeypatch.delenv("EASYHOI_MANO_DIR", raising=False)
    mano = tmp_path / "mano"
    mano.mkdir()
    write_synthetic_mano(mano)
    docs = []
    for i, seed_args in enumerate((["--seed", "5"], ["--set", "optim.seed=5"])):
        out = tmp_path / f"out{i}"
        rc = main(["reconstruct", str(photo), "--out", str(out), "--hand-model", "mano",
                   "--mano-dir", str(mano), *seed_args, *SHORT])  # fmt: skip
        assert rc == 0, capsys.readouterr().err
        folder = out / "held"
        doc = json.loads((folder / "result.json").read_text())
        assert doc["hand_model"] == "mano" and doc["hand"]["num_vertices"] == 778
        assert doc["seed"] == 5
        hand = trimesh.load(folder / "hand.ply", process=False)
        assert len(hand.vertices) == 778
        docs.append(doc)
    assert docs[0]["hand"] == docs[1]["hand"] and docs[0]["camera"] == docs[1]["camera"]


def test_run_settings_pickle_for_worker_processes():
    import pickle

    run = resolve_run(seed=3)
    back = pickle.loads(pickle.dumps(run))
    assert isinstance(back, RunSettings) and back.seed == 3 and back.config == run.config
    assert torch.equal(back.hand_model.v_template, run.hand_model.v_template)
