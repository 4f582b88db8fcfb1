# SPDX-License-Identifier: Apache-2.0
"""objective.project_out (normal equations where well conditioned, else the SVD) against
numpy's least squares: the same residual to 1e-12 relative (1e-8 for nearly equal
columns, where the problem itself holds no more), for columns of norms 1e-3 to
1e3, nearly equal ones (the normal equations refused), a zero column, and one 1e-9 the
size of the others (kept: a direction, not rounding)."""

from __future__ import annotations

import numpy as np
import pytest

from mr_ident.diagnosis.criterion.objective import project_out


def _reference(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    keep = np.linalg.norm(A, axis=0) > 0
    return b - A[:, keep] @ np.linalg.lstsq(A[:, keep], b, rcond=None)[0]


@pytest.mark.parametrize("case", ["scaled", "nearly equal", "zero column", "tiny column"])
def test_project_out_is_least_squares(case):
    rng = np.random.default_rng(11)
    A = rng.standard_normal((5000, 6)) * np.array([1e-3, 1.0, 10.0, 1e3, 1.0, 1.0])
    if case == "nearly equal":
        A[:, 5] = A[:, 4] + 1e-6 * rng.standard_normal(5000)
    if case == "zero column":
        A[:, 2] = 0.0
    if case == "tiny column":
        A[:, 0] *= 1e-6
    b = rng.standard_normal(5000) + A @ rng.standard_normal(6)
    ref = _reference(A, b)
    got = project_out(A, b)
    tol = 1e-8 if case == "nearly equal" else 1e-12  # there eps / sigma_min ~ 1e-10
    assert np.linalg.norm(got - ref) <= tol * np.linalg.norm(b)
    assert abs(np.linalg.norm(ref) / np.sqrt(5000 - 6) - 1) < 0.05  # b's noise is left
