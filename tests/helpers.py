"""Shared test helpers: one assert_close and the tolerances used across the suite."""

from __future__ import annotations

import numpy as np
import torch

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
