# SPDX-License-Identifier: Apache-2.0
"""Stacks of small matrices laid out bins-last, shape (rows, cols, K).

With K (frequency bins) in the last, contiguous axis every operation is a few
whole-array passes over K, instead of one small LAPACK/BLAS call per bin: for
the 3x3 to 6x6 matrices of a lifted loop that is several times faster.
"""

from __future__ import annotations

import numpy as np

from .arrays import ComplexArray, FloatArray

#: A pivot smaller than this fraction of the largest candidate in its column sends the
#: bin to LAPACK (partial pivoting) instead.
WEAK_PIVOT = 0.1


def matmul(A: ComplexArray, B: ComplexArray) -> ComplexArray:
    """``C[:, :, k] = A[:, :, k] @ B[:, :, k]`` for A (a, i, K) and B (i, b, K)."""
    out: ComplexArray = A[:, 0, None, :] * B[None, 0]
    for i in range(1, A.shape[1]):
        out += A[:, i, None, :] * B[None, i]
    return out


def real_dot(A: ComplexArray, B: ComplexArray, axis: int) -> FloatArray:
    """``Re(sum(A * conj(B), axis))`` without forming the complex product."""
    out: FloatArray = np.sum(A.real * B.real + A.imag * B.imag, axis=axis)
    return out


def inv(A: ComplexArray) -> ComplexArray:
    """Inverse of every matrix in a stack (m, m, K).

    Gauss-Jordan elimination vectorised over K without row exchanges; a bin whose
    pivot is weak (below :data:`WEAK_PIVOT` times the largest entry left in its
    column, where partial pivoting would exchange rows) is inverted by LAPACK
    instead, so the result is as accurate as ``np.linalg.inv``. Singular or NaN
    matrices give NaN or inf entries, not an exception.
    """
    m, _, K = A.shape
    M = np.zeros((m, 2 * m, K), dtype=np.complex128)
    M[:, :m] = A
    M[np.arange(m), m + np.arange(m)] = 1.0
    weak = np.zeros(K, dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(m):
            col = M[j:, j]
            mag = col.real**2 + col.imag**2
            weak |= mag[0] < WEAK_PIVOT**2 * mag.max(axis=0)
            M[j, j + 1 :] /= M[j, j]
            M[j, j] = 1.0
            for i in range(m):
                if i != j:
                    M[i, j + 1 :] -= M[i, j] * M[j, j + 1 :]
    out = M[:, m:]
    weak &= np.isfinite(A).all(axis=(0, 1))
    if weak.any():
        idx = np.nonzero(weak)[0]
        try:
            out[:, :, idx] = np.linalg.inv(A[:, :, idx].transpose(2, 0, 1)).transpose(1, 2, 0)
        except np.linalg.LinAlgError:
            for k in idx:  # only when some matrix is exactly singular
                try:
                    out[:, :, k] = np.linalg.inv(A[:, :, k])
                except np.linalg.LinAlgError:
                    out[:, :, k] = np.nan
    return out
