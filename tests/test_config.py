"""Configuration tree: presets, overrides, JSON round trip, field docs."""

from __future__ import annotations

import json
import math
import re
from dataclasses import FrozenInstanceError, fields, is_dataclass
from pathlib import Path

import pytest

from easyhoi.config import (
    MAX_SEED,
    PRESETS,
    CameraStageConfig,
    ContactStageConfig,
    EasyHOIConfig,
    OptimConfig,
    PerceptionConfig,
    RefineStageConfig,
    field_docs,
    from_dict,
    get_preset,
    parse_overrides,
    to_dict,
    with_overrides,
)
from easyhoi.errors import InvalidInputError

ALL_CLASSES = (
    CameraStageConfig,
    ContactStageConfig,
    RefineStageConfig,
    OptimConfig,
    PerceptionConfig,
    EasyHOIConfig,
)


DOC = Path(__file__).resolve().parents[1] / "docs" / "method.md"


def _paper_table() -> dict[str, object]:
    """``{dotted field: value}`` of the paper's settings table in docs/method.md (section 2.3)."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("### 2.3", 1)[1].split("\n#", 1)[0]
    rows = {}
    for line in section.splitlines():
        m = re.match(r"\| `([\w.]+)` \| (.+?) \|$", line)
        if m:
            rows[m.group(1)] = json.loads(m.group(2))
    return rows


def _get(cfg, path: str):
    for part in path.split("."):
        cfg = getattr(cfg, part)
    return cfg


def _leaves(d: dict, prefix: str = ""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _leaves(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def test_paper_preset_matches_the_papers_settings_in_the_docs():
    rows = _paper_table()
    assert len(rows) >= 20  # the table was found and read
    paper = get_preset("paper")
    for path, value in rows.items():
        expected = tuple(value) if isinstance(value, list) else value
        assert _get(paper, path) == expected, path


def test_paper_preset_runs_the_full_schedule():
    p = get_preset("paper").optim
    assert p.run_camera and p.run_contact and p.run_refine
    for stage in (p.camera, p.contact, p.refine):
        assert stage.patience == 0 and stage.resolution_schedule == (1.0,)
    # no stage-3 cap in the paper: the other stages' cap
    assert p.refine.max_iters == p.camera.max_iters == p.contact.max_iters


def test_fast_is_the_default_and_cheaper_than_paper():
    f, p = get_preset().optim, get_preset("paper").optim
    assert get_preset() is PRESETS["fast"] and PRESETS["fast"].name == "fast"
    stages = ("camera", "contact", "refine")
    for name in stages:
        fs, ps = getattr(f, name), getattr(p, name)
        assert fs.max_iters <= ps.max_iters, name
        assert fs.patience > 0, name  # early stopping
        assert min(fs.resolution_schedule) <= min(ps.resolution_schedule), name

    def total(o):
        return sum(getattr(o, n).max_iters for n in stages)

    assert total(f) < total(p)
    assert f.render_size <= p.render_size
    assert f.camera.sinkhorn_grid <= p.camera.sinkhorn_grid
    assert f.refine.sdf_resolution <= p.refine.sdf_resolution
    assert f.contact.peel_layers <= p.contact.peel_layers
    assert f.contact.icp_iters <= p.contact.icp_iters
    assert f.dtype == p.dtype and f.seed == p.seed


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_value_is_finite_and_in_range(name):
    from easyhoi.perception.base import available

    cfg = get_preset(name)
    assert from_dict(to_dict(cfg)) == cfg  # every dataclass check passes again
    for path, value in _leaves(to_dict(cfg)):
        values = value if isinstance(value, list) else [value]
        for v in values:
            if isinstance(v, float):
                assert math.isfinite(v), path
        leaf = path.rsplit(".", 1)[-1]
        if leaf.startswith("lr") and value is not None:
            assert 0 < value <= 1, path
        if leaf.endswith("_weight"):
            assert value >= 0, path
        if leaf == "max_iters":
            assert isinstance(value, int) and value >= 1, path
        if leaf == "resolution_schedule":
            assert value[-1] == 1.0, path  # the last phase renders at full size
    o = cfg.optim
    # registrations happen within the stage's iteration cap
    assert all(0 <= it < o.contact.max_iters for it in o.contact.register_at)
    assert 32 <= o.render_size <= 1024 and o.refine.penetration_threshold <= 0
    assert 0 < o.camera.init_fov_deg < 180 and o.camera.init_distance > 0
    for role in ("hand", "segmenter", "inpainter", "amodal", "object"):
        assert getattr(cfg.perception, role) in available(role), role
    assert cfg.hand_model in ("open", "mano")


def test_unknown_preset_lists_names():
    with pytest.raises(InvalidInputError, match="available: fast, paper"):
        get_preset("slow")


def test_frozen():
    with pytest.raises(FrozenInstanceError):
        get_preset().optim.refine.max_iters = 3  # type: ignore[misc]


def test_with_overrides_changes_only_the_named_fields():
    base = get_preset("paper")
    cfg = with_overrides(
        base,
        {
            "optim.refine.max_iters": 50,
            "optim.camera.use_sinkhorn": False,
            "optim.refine.reg_weight": 1,  # int accepted for float
            "optim.contact.register_at": [5, 7],  # list -> tuple
            "optim.refine.contact_max_distance": 0.01,
            "mano_dir": "/tmp/mano",
        },
    )
    assert cfg.optim.refine.max_iters == 50 and not cfg.optim.camera.use_sinkhorn
    assert cfg.optim.refine.reg_weight == 1.0 and isinstance(cfg.optim.refine.reg_weight, float)
    assert cfg.optim.contact.register_at == (5, 7) and cfg.mano_dir == "/tmp/mano"
    assert cfg.optim.refine.contact_max_distance == 0.01
    assert base.optim.refine.max_iters == 1000  # original untouched
    d0, d1 = to_dict(base), to_dict(cfg)
    changed = {
        f"{s}.{k}"
        for s in ("camera", "contact", "refine")
        for k in d0["optim"][s]
        if d0["optim"][s][k] != d1["optim"][s][k]
    }
    assert changed == {
        "camera.use_sinkhorn",
        "contact.register_at",
        "refine.max_iters",
        "refine.reg_weight",
        "refine.contact_max_distance",
    }
    # a whole section can be replaced by a dict
    cfg2 = with_overrides(base, {"optim.refine": {"max_iters": 7}})
    assert cfg2.optim.refine.max_iters == 7 and cfg2.optim.refine.lr_pose == 1e-2


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"optim.refine.max_iter": 5}, "unknown config field 'optim.refine.max_iter'"),
        ({"optimx.refine.max_iters": 5}, "unknown config field"),
        ({"optim.refine.max_iters": 5.5}, "expects int"),
        ({"optim.refine.max_iters": True}, "expects int"),
        ({"optim.camera.use_sinkhorn": 1}, "expects bool"),
        ({"optim.refine.reg_weight": "0.1"}, "expects float"),
        ({"optim.refine.max_iters": None}, "may not be None"),
        ({"optim.contact.register_at": [200, 100]}, "strictly increasing"),
        ({"optim.refine.lr_pose": -1.0}, "must be > 0"),
        ({"optim.dtype": "float16"}, "dtype must be one of"),
        ({"hand_model": "smplx"}, "hand_model must be one of"),
        ({"optim.camera.resolution_schedule": [1.0, 0.5]}, "increasing fractions"),
        ({"optim.refine.penetration_threshold": 0.1}, "must be <= 0"),
        ({"optim.refine": {"bogus": 1}}, "unknown config field"),
        ({"optim.refine.lr_pose": float("inf")}, "must be a finite number"),
        ({"optim.refine.reg_weight": float("nan")}, "must be a finite number"),
        ({"optim.camera.resolution_schedule": [0.5, float("nan")]}, "finite"),
        ({"optim.seed": MAX_SEED + 1}, "seed must be in"),
        ({"optim.seed": -1}, "seed must be in"),
    ],
)
def test_with_overrides_rejects_bad_values(overrides, message):
    with pytest.raises(InvalidInputError, match=message):
        with_overrides(get_preset(), overrides)


def test_parse_overrides():
    d = parse_overrides(
        [
            "optim.refine.max_iters=50",
            "optim.dtype=float64",
            "optim.contact.register_at=[1, 2]",
            "optim.camera.use_sinkhorn=false",
            "mano_dir=null",
        ],
        cfg=get_preset(),
    )
    assert d == {
        "optim.refine.max_iters": 50,
        "optim.dtype": "float64",
        "optim.contact.register_at": [1, 2],
        "optim.camera.use_sinkhorn": False,
        "mano_dir": None,
    }
    cfg = with_overrides(get_preset(), d)
    assert cfg.optim.dtype == "float64" and str(cfg.optim.torch_dtype) == "torch.float64"
    with pytest.raises(InvalidInputError, match="path=value"):
        parse_overrides(["optim.seed"])
    with pytest.raises(InvalidInputError, match="expects int"):
        parse_overrides(["optim.seed=abc"], cfg=get_preset())


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_json_round_trip(name):
    cfg = with_overrides(get_preset(name), {"optim.refine.contact_max_distance": 0.02})
    text = json.dumps(to_dict(cfg))
    back = from_dict(json.loads(text))
    assert back == cfg
    assert from_dict(json.loads(json.dumps(to_dict(get_preset(name))))) == get_preset(name)


def test_from_dict_defaults_and_errors():
    assert from_dict({}) == EasyHOIConfig()
    assert from_dict({"optim": {"seed": 3}}).optim.seed == 3
    with pytest.raises(InvalidInputError, match="unknown config field"):
        from_dict({"optim": {"sed": 3}})
    with pytest.raises(InvalidInputError, match="must be a mapping"):
        from_dict([1, 2])  # type: ignore[arg-type]


def test_every_field_is_documented():
    for cls in ALL_CLASSES:
        docs = field_docs(cls)
        missing = [f.name for f in fields(cls) if not docs.get(f.name)]
        assert not missing, f"{cls.__name__} lacks docstrings for {missing}"
        assert cls.__doc__
    assert "Adam" in field_docs(CameraStageConfig)["lr"]
    assert "\n" not in field_docs(CameraStageConfig)["patience"]
    with pytest.raises(InvalidInputError):
        field_docs(int)


def test_tree_shape():
    cfg = get_preset()
    assert is_dataclass(cfg.optim.camera) and isinstance(cfg.optim.contact, ContactStageConfig)
