"""Render a hand model's region labels (palmar faces, contact zones, fingertips) to a PNG.

Usage: python scripts/show_hand_regions.py --out hand_regions.png
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")

from easyhoi.hand.openhand import OpenHand  # noqa: E402
from easyhoi.hand.regions import plot_regions  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="output PNG path")
    args = parser.parse_args(argv)
    path = plot_regions(OpenHand(), args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
