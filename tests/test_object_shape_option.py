"""``--object-shape`` / ``perception.object_shape``: the silhouette backend fits one family."""

import cv2
import numpy as np
import pytest

from easyhoi.config import PerceptionConfig
from easyhoi.errors import InvalidInputError
from easyhoi.perception import chain
from easyhoi.shape_families import OBJECT_SHAPES


def test_names_are_the_shape_code_families():
    from easyhoi.perception.shapes import FAMILIES

    assert OBJECT_SHAPES == FAMILIES


def test_config_accepts_auto_and_each_family_only():
    for name in ("auto", *OBJECT_SHAPES):
        assert PerceptionConfig(object_shape=name).object_shape == name
    with pytest.raises(InvalidInputError, match="object_shape"):
        PerceptionConfig(object_shape="cup")


@pytest.mark.parametrize("command", ["reconstruct", "batch"])
def test_cli_flag_sets_the_family(command, tmp_path):
    from easyhoi.cli import _config_from_args, build_parser

    args = build_parser().parse_args(
        [command, "x", "--out", str(tmp_path), "--object-shape", "revolution"]
    )
    assert _config_from_args(args).perception.object_shape == "revolution"
    args = build_parser().parse_args([command, "x", "--out", str(tmp_path)])
    assert _config_from_args(args).perception.object_shape == "auto"
    with pytest.raises(SystemExit) as e:  # argparse names the choices, exit 2
        build_parser().parse_args([command, "x", "--out", str(tmp_path), "--object-shape", "cup"])
    assert e.value.code == 2


def test_backend_fits_the_chosen_family_alone():
    """A disk is fitted as a round family by default; told "cuboid", the backend fits the
    box and nothing else, and the box's outline still covers the disk."""
    disk = np.zeros((160, 160), np.uint8)
    cv2.circle(disk, (80, 80), 50, 1, -1)
    disk = disk.astype(bool)
    auto = chain._backend(PerceptionConfig(), "object", "silhouette").reconstruct(None, disk)
    assert auto.metadata["easyhoi"]["method"] != "cuboid"
    rec = chain._backend(PerceptionConfig(object_shape="cuboid"), "object", "silhouette")
    assert rec.families == ("cuboid",)
    mesh = rec.reconstruct(None, disk)
    md = mesh.metadata["easyhoi"]
    assert md["method"] == "cuboid"
    assert set(md["shape"]["scores"]) == {"cuboid"}  # no other family was fitted
    # a box whose outline covers a disk of diameter 100 px: its sides 80-120 px long
    sides = np.sort(mesh.extents * md["pixels_per_unit"])[1:]
    assert np.all((sides >= 80) & (sides <= 120))


def test_a_backend_without_families_refuses_the_option(tmp_path):
    pc = PerceptionConfig(object="depth", depth_dir=str(tmp_path), object_shape="tube")
    with pytest.raises(InvalidInputError, match="--object-shape tube"):
        chain._backend(pc, "object", "depth")
