import pytest

from easyhoi.config import PerceptionConfig
from easyhoi.errors import InvalidInputError
from easyhoi.perception import chain


def test_adapter_without_model_folder_names_the_flag():
    pc = PerceptionConfig(amodal="sam")
    with pytest.raises(InvalidInputError, match="--sam-dir"):
        chain._backend(pc, "amodal", "sam")


def test_adapter_gets_its_model_folder(monkeypatch, tmp_path):
    seen = {}

    def fake_create(role, name, **kw):
        seen.update(role=role, name=name, **kw)
        return object()

    monkeypatch.setattr(chain, "create", fake_create)
    pc = PerceptionConfig(object="depth", depth_dir=str(tmp_path))
    chain._backend(pc, "object", "depth", device="cuda:1")
    assert seen == {"role": "object", "name": "depth", "model_dir": str(tmp_path),
                    "device": "cuda:1"}  # fmt: skip
    seen.clear()
    chain._backend(pc, "segmenter", "classical", 7)
    assert seen == {"role": "segmenter", "name": "classical", "seed": 7}  # it takes a seed


def test_cli_model_dir_flags_select_the_adapters(tmp_path):
    from easyhoi.cli import _config_from_args, build_parser

    args = build_parser().parse_args(
        [
            "reconstruct",
            "x.jpg",
            "--out",
            str(tmp_path),
            "--sam-dir",
            "/models/sam",
            "--diffusion-dir",
            "/models/inpaint",
        ]  # fmt: skip
    )
    pc = _config_from_args(args).perception
    assert (pc.amodal, pc.sam_dir) == ("sam", "/models/sam")
    assert (pc.inpainter, pc.diffusion_dir) == ("diffusion", "/models/inpaint")
    assert pc.object == "silhouette" and pc.depth_dir is None
