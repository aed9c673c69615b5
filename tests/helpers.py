"""Shared test helpers: one assert_close, the tolerances used across the suite, and a loader
for the repository's scripts."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]

ATOL32 = 1e-5
ATOL64 = 1e-10


def assert_close(actual, expected, atol: float = ATOL32, rtol: float = 0.0, msg: str = ""):
    a = actual.detach().cpu().numpy() if isinstance(actual, torch.Tensor) else np.asarray(actual)
    e = (
        expected.detach().cpu().numpy()
        if isinstance(expected, torch.Tensor)
        else np.asarray(expected)
    )
    np.testing.assert_allclose(a, e, atol=atol, rtol=rtol, err_msg=msg)


def load_script(relpath: str):
    """A script of the repository (``benchmarks/...``, ``scripts/...``) imported as a module
    named after its file."""
    path = ROOT / relpath
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
