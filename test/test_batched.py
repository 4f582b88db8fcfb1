# SPDX-License-Identifier: Apache-2.0
"""Stacks of small matrices, bins-last: against numpy's per-matrix LAPACK results."""

import importlib

import numpy as np
import pytest

batched = importlib.import_module("mr_ident.numerics.batched")


def _stack(rng, m, K):
    return rng.standard_normal((m, m, K)) + 1j * rng.standard_normal((m, m, K))


def _first(A):
    return A.transpose(2, 0, 1)


@pytest.mark.parametrize("m", [1, 2, 3, 6])
def test_inv_equals_lapack_including_bins_that_need_row_exchanges(m):
    rng = np.random.default_rng(m)
    A = _stack(rng, m, 500)
    A[0, 0, :100] *= 1e-9  # tiny leading pivot: these bins need a row exchange
    got = batched.inv(A)
    ref = np.linalg.inv(_first(A))
    # tolerance: a few eps times cond(A) (random complex matrices: cond up to ~1e4)
    cond = np.linalg.cond(_first(A))
    err = np.abs(_first(got) - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    assert np.all(err <= 1e-13 * cond)


def test_inv_gives_nan_not_an_exception_for_singular_and_nan_matrices():
    rng = np.random.default_rng(0)
    A = _stack(rng, 3, 4)
    A[:, :, 1] = 0.0  # singular
    A[0, 1, 2] = np.nan
    got = batched.inv(A)
    assert np.allclose(_first(got)[[0, 3]], np.linalg.inv(_first(A)[[0, 3]]), rtol=1e-12, atol=0)
    assert not np.isfinite(got[:, :, 1]).all()
    assert not np.isfinite(got[:, :, 2]).all()


def test_matmul_and_real_dot_equal_their_definitions():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((2, 3, 7)) + 1j * rng.standard_normal((2, 3, 7))
    B = rng.standard_normal((3, 4, 7)) + 1j * rng.standard_normal((3, 4, 7))
    np.testing.assert_allclose(
        _first(batched.matmul(A, B)), _first(A) @ _first(B), rtol=1e-14, atol=1e-14
    )
    C = rng.standard_normal((2, 3, 7)) + 1j * rng.standard_normal((2, 3, 7))
    np.testing.assert_allclose(
        batched.real_dot(A, C, axis=1),
        np.real(np.sum(A * np.conj(C), axis=1)),
        rtol=1e-14,
        atol=1e-14,
    )
