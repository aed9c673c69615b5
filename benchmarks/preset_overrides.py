"""``--set KEY=VALUE`` for the benchmark scripts: configuration overrides of the fast preset,
so that a script measures a variant, with a bad key or value an argument error."""

from __future__ import annotations

import argparse


def add_set_option(ap: argparse.ArgumentParser) -> None:
    """Add the repeatable ``--set KEY=VALUE`` option to ``ap``."""
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="configuration override of the fast preset (repeatable), to measure a variant",
    )


def fast_overrides(ap: argparse.ArgumentParser, items: list[str]) -> dict:
    """The overrides of ``items`` checked against the fast preset; ``ap.error`` when one is
    bad (an unknown field, a value of the wrong type)."""
    from easyhoi.config import get_preset, parse_overrides
    from easyhoi.errors import InvalidInputError

    try:
        return parse_overrides(items, get_preset("fast"))
    except InvalidInputError as exc:
        ap.error(str(exc))
