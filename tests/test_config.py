"""Configuration tree: presets, overrides, JSON round trip, field docs."""

from __future__ import annotations

import json
from dataclasses import FrozenInstanceError, fields, is_dataclass

import pytest

from easyhoi.config import (
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


def test_paper_preset_is_the_papers_schedule():
    p = get_preset("paper").optim
    assert (p.camera.lr, p.camera.max_iters, p.camera.stop_loss) == (1e-2, 1000, 0.1)
    assert (p.camera.init_fov_deg, p.camera.init_distance) == (30.0, 4.5)
    assert p.camera.use_sinkhorn and p.camera.optimise_focal
    assert (p.contact.lr, p.contact.max_iters, p.contact.stop_loss) == (1e-2, 1000, 0.1)
    assert p.contact.register_at == (100, 200) and p.contact.peel_layers == 4
    r = p.refine
    assert (r.lr_global, r.lr_pose) == (1e-4, 1e-2)
    weights = (r.hand_mask_weight, r.penetration_weight, r.contact_weight, r.reg_weight)
    assert weights == (5.0, 10.0, 5.0, 0.1)
    assert (r.sdf_resolution, r.penetration_threshold) == (64, -5e-3)
    assert r.contact_max_distance is None
    assert p.render_size == 256 and p.run_camera and p.run_contact and p.run_refine
    for stage in (p.camera, p.contact, p.refine):
        assert stage.patience == 0 and stage.resolution_schedule == (1.0,)


def test_fast_preset_is_default_and_cheaper():
    f, p = get_preset(), get_preset("paper")
    assert f is PRESETS["fast"] and f.name == "fast"
    assert f.optim.render_size * min(f.optim.camera.resolution_schedule) == 64
    assert f.optim.render_size == 128
    assert (f.optim.camera.max_iters, f.optim.contact.max_iters, f.optim.refine.max_iters) == (
        150,
        150,
        100,
    )
    assert f.optim.contact.register_at == (20, 60)
    assert all(s.patience > 0 for s in (f.optim.camera, f.optim.contact, f.optim.refine))
    # the paper preset keeps the paper's loss weights and learning rates
    r = p.optim.refine
    assert (r.hand_mask_weight, r.penetration_weight, r.contact_weight, r.reg_weight) == (
        5.0,
        10.0,
        5.0,
        0.1,
    )
    assert (r.lr_global, r.lr_pose) == (1e-4, 1e-2)
    # fast keeps the global learning rate, takes smaller articulation steps (the depth scan's
    # contact band puts the hand where noisy fingers collide); weights rebalanced for a dense mesh
    assert (f.optim.refine.lr_global, f.optim.refine.lr_pose) == (1e-4, 3e-3)
    assert (p.optim.contact.scan_band, f.optim.contact.scan_band) == (0.0, 0.02)
    assert (r.penetration_weight, f.optim.refine.penetration_weight) == (10.0, 2000.0)
    assert f.optim.refine.penetration_weight > r.penetration_weight
    assert f.perception == PerceptionConfig() and f.hand_model == "open"
    assert f.perception.hand == "mediapipe" and f.perception.object == "silhouette"


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
