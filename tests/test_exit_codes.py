"""Exit codes: one table in easyhoi.errors, used by the CLI and the batch runner, and documented."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from easyhoi import errors
from easyhoi.cli import build_parser, main
from easyhoi.errors import EXIT_CODE_MEANINGS, ExitCode, exit_code_of

DOC = Path(__file__).resolve().parents[1] / "docs" / "bad_input.md"


def _doc_table() -> dict[int, tuple[str, str]]:
    """``{exit code: (meaning, raised as)}`` of the "Exit codes" table of docs/bad_input.md."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Exit codes", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        m = re.match(r"\| (\d+) \| (.+?) \| (.+?) \|$", line)
        if m:
            rows[int(m.group(1))] = (m.group(2), m.group(3))
    return rows


def test_every_code_has_one_meaning_and_codes_are_distinct():
    assert set(EXIT_CODE_MEANINGS) == set(ExitCode)
    assert len({int(c) for c in ExitCode}) == len(ExitCode)
    assert all(0 <= c <= 255 for c in ExitCode)


def test_docs_table_matches_the_code():
    rows = _doc_table()
    assert set(rows) == {int(c) for c in ExitCode}
    for code, text in EXIT_CODE_MEANINGS.items():
        assert rows[int(code)][0] == text, code
    # every error class is listed next to its own code
    for name in errors.__all__:
        cls = getattr(errors, name)
        if isinstance(cls, type) and issubclass(cls, errors.EasyHOIError):
            assert f"`{name}`" in rows[int(cls.exit_code)][1], name


@pytest.mark.parametrize(
    "exc, code",
    [
        (errors.InvalidInputError("x"), 2),
        (errors.UnsafeFileError("x"), 2),
        (errors.MissingDependencyError("pkg"), 3),
        (errors.BackendError("x"), 4),
        (errors.NoHandError("x"), 5),
        (errors.NoObjectError("x"), 6),
        (errors.OptimizationError("x"), 7),
        (errors.EasyHOIError("x"), 1),
        (RuntimeError("x"), 70),
        (KeyboardInterrupt(), 130),
    ],
)
def test_exit_code_of(exc, code):
    assert exit_code_of(exc) == code


def test_help_lists_the_table(capsys):
    text = build_parser().format_help()
    for code, meaning in EXIT_CODE_MEANINGS.items():
        assert re.search(rf"^\s+{int(code)}\s+{re.escape(meaning)}$", text, re.M), code


def test_cli_returns_the_tables_codes(tmp_path, capsys, monkeypatch):
    assert main(["reconstruct", str(tmp_path / "missing.jpg"), "--out", str(tmp_path)]) == 2
    import easyhoi.cli as cli

    def boom(args):
        raise RuntimeError("a bug")

    def interrupt(args):
        raise KeyboardInterrupt

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    for fn, code in ((boom, ExitCode.INTERNAL), (interrupt, ExitCode.INTERRUPTED)):
        parser._subparsers._group_actions[0].choices["doctor"].set_defaults(func=fn)
        rc = main(["doctor"])
        assert rc == code and type(rc) is int
    err = capsys.readouterr().err
    assert "internal error: RuntimeError: a bug" in err and "interrupted" in err
