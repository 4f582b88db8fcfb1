"""objective.project_out (normal equations where well conditioned, else the SVD) against
numpy's least squares: the same residual to 1e-12 relative, well-conditioned columns,
nearly equal ones (the Gram route refused), and a zero column."""

from __future__ import annotations

import numpy as np
import pytest

from mr_ident.diagnosis.objective import project_out


def _reference(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    return b - A @ np.linalg.lstsq(A, b, rcond=1e-10)[0]


@pytest.mark.parametrize("case", ["scaled", "nearly equal", "zero column"])
def test_project_out_is_least_squares(case):
    rng = np.random.default_rng(11)
    A = rng.standard_normal((5000, 6)) * np.array([1e-3, 1.0, 10.0, 1e3, 1.0, 1.0])
    if case == "nearly equal":
        A[:, 5] = A[:, 4] + 1e-7 * rng.standard_normal(5000)
    if case == "zero column":
        A[:, 2] = 0.0
    b = rng.standard_normal(5000) + A @ rng.standard_normal(6)
    ref = _reference(A, b)
    got = project_out(A, b)
    assert np.linalg.norm(got - ref) <= 1e-12 * np.linalg.norm(b)
    assert abs(np.linalg.norm(ref) / np.sqrt(5000 - 6) - 1) < 0.05  # b's noise is left
