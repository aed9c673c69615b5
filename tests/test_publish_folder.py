"""io.atomic.publish_folder: a folder appears complete under its final name, or not at all."""

from __future__ import annotations

import pytest

from easyhoi.errors import InvalidInputError
from easyhoi.io.atomic import publish_folder


def _fill(names):
    def fill(tmp):
        for n in names:
            (tmp / n).write_text(n)

    return fill


def test_new_folder_and_replacement(tmp_path):
    final = tmp_path / "deep" / "r"
    assert publish_folder(final, _fill(["a", "b"]), ["a", "b"]) == final
    assert sorted(p.name for p in final.iterdir()) == ["a", "b"]
    (final / "stale").write_text("old")
    publish_folder(final, _fill(["c"]), ["c"])
    assert sorted(p.name for p in final.iterdir()) == ["c"]  # replaced whole
    assert sorted(p.name for p in final.parent.iterdir()) == ["r"]  # no temporary left


def test_failure_and_missing_files_leave_the_old_folder(tmp_path):
    final = tmp_path / "r"
    publish_folder(final, _fill(["a"]))

    def boom(tmp):
        (tmp / "half").write_text("x")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        publish_folder(final, boom)
    with pytest.raises(InvalidInputError, match=r"missing \['b'\]"):
        publish_folder(final, _fill(["a"]), ["a", "b"])
    assert [p.name for p in tmp_path.iterdir()] == ["r"]
    assert [p.name for p in final.iterdir()] == ["a"]


@pytest.mark.parametrize("name", ["..", ".hidden"])
def test_names_that_are_not_plain_are_refused(tmp_path, name):
    with pytest.raises(InvalidInputError, match="plain name"):
        publish_folder(tmp_path / "x" / name, _fill(["a"]))
    (tmp_path / "file").write_text("f")
    with pytest.raises(InvalidInputError, match="not a folder"):
        publish_folder(tmp_path / "file", _fill(["a"]))
