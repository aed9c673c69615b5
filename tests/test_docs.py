"""Every document the code cites is in the repository, and cited sections exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREES = ("src", "tests", "docs", "benchmarks", "scripts")


def _texts():
    for tree in TREES:
        for path in sorted((ROOT / tree).rglob("*")):
            if path.suffix in (".py", ".md") and path.is_file():
                yield path, path.read_text(encoding="utf-8", errors="replace")
    yield ROOT / "README.md", (ROOT / "README.md").read_text(encoding="utf-8")


def test_cited_documents_exist():
    missing = []
    for path, text in _texts():
        for ref in set(re.findall(r"\bdocs/[\w-]+\.md\b", text)):
            if not (ROOT / ref).is_file():
                missing.append(f"{path.relative_to(ROOT)} cites {ref}")
        if re.search(r"\b[A-Z]+\.md\b", text.replace("README.md", "")):
            names = set(re.findall(r"\b[A-Z]+\.md\b", text.replace("README.md", "")))
            missing += [f"{path.relative_to(ROOT)} cites {n}" for n in names]
    assert not missing, missing


def test_cited_method_sections_exist():
    method = (ROOT / "docs" / "method.md").read_text(encoding="utf-8")
    headings = set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", method, re.M))
    assert {"1", "2", "2.1", "2.2", "2.3", "3", "4", "5"} <= headings
    for path, text in _texts():
        for section in re.findall(r"docs/method\.md section (\d+(?:\.\d+)?)", text):
            assert section in headings, f"{path.relative_to(ROOT)} cites section {section}"
