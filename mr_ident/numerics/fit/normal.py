# SPDX-License-Identifier: Apache-2.0
"""The fit's linear steps over many bins: Gram matrices in blocks of bins, entries on threads.

Every linear step of the fit is, per entry ``e``, a weighted least-squares problem in
real coefficients with complex columns, ``min ‖w_e ⊙ (y_e - X_e c)‖``; its real form
stacks the real and imaginary parts. Its Gram ``Re(X_eᴴ X_e)`` is summed over blocks of
bins (one BLAS ``syrk`` per block: the block's real stack stays in the cache, and no
array of all bins times all columns per entry is ever formed), one entry per thread.
The small systems are solved with the columns scaled to unit norm, by a symmetric
eigendecomposition (as accurate as a Cholesky factor and never failing on a singular
Gram); the condition number it reports is that of the scaled columns (the square root
of the Gram's). The residual is always formed from the data, never from the Gram, and
one step of refinement on it recovers what the normal equations lose (semi-normal
equations with one correction: Björck 1996, §2.5).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..arrays import ComplexArray, FloatArray
from ..threads import resolve_workers, thread_map

#: Bins per block: the real stack of a block, 2 x 4096 x ~80 doubles, fits the cache.
BLOCK = 4096


def gram(
    build: Callable[[slice, int], ComplexArray],
    n_bins: int,
    n_entries: int,
    n_cols: int,
    workers: int | None = None,
) -> FloatArray:
    """``Re(Xᴴ X)`` per entry, shape (n_entries, n_cols, n_cols).

    ``build(rows, e)``: the complex columns ``X`` of entry ``e`` on bins ``rows``, shape
    (len(rows), n_cols); called once per block of :data:`BLOCK` bins.
    """

    def one(e: int) -> FloatArray:
        G = np.zeros((n_cols, n_cols))
        buf = np.empty((2 * min(BLOCK, n_bins), n_cols))
        for start in range(0, n_bins, BLOCK):
            X = build(slice(start, min(start + BLOCK, n_bins)), e)
            b = X.shape[0]
            S = buf[: 2 * b]
            S[:b] = X.real
            S[b:] = X.imag
            G += S.T @ S  # syrk: numpy recognises the transposed operand
        return G

    # threads only where each has blocks to do (starting them costs more than a small Gram)
    n = resolve_workers(workers) if n_bins * n_cols >= 4 * BLOCK * 64 else 1
    return np.stack(thread_map(one, range(n_entries), n))


def weighted_gram(
    Y: ComplexArray,
    W: FloatArray,
    extra: Callable[[slice, int], ComplexArray] | None = None,
    n_extra: int = 0,
    workers: int | None = None,
) -> FloatArray:
    """``Re(Xₑᴴ Xₑ)`` of ``Xₑ = wₑ ⊙ [Y, extra(e)]`` per entry, (E, m + n_extra, m + n_extra).

    ``Y`` (K, m): columns common to every entry; ``W`` (K, E): each entry's weights;
    ``extra(rows, e)`` (len(rows), n_extra): an entry's own columns. Only the weighting is
    done per entry and block: no complex array is formed there.
    """
    K, m = Y.shape
    E = W.shape[1]
    n = m + n_extra
    Yr, Yi = Y.real, Y.imag

    def one(e: int) -> FloatArray:
        G = np.zeros((n, n))
        buf = np.empty((2 * min(BLOCK, K), n))
        for start in range(0, K, BLOCK):
            r = slice(start, min(start + BLOCK, K))
            b = r.stop - r.start
            w = W[r, e, None]
            S = buf[: 2 * b]
            np.multiply(w, Yr[r], out=S[:b, :m])
            np.multiply(w, Yi[r], out=S[b:, :m])
            if extra is not None:
                X = w * extra(r, e)
                S[:b, m:] = X.real
                S[b:, m:] = X.imag
            G += S.T @ S
        return G

    nw = resolve_workers(workers) if K * n >= 4 * BLOCK * 64 else 1
    return np.stack(thread_map(one, range(E), nw))


def real_product(Y: ComplexArray, R: ComplexArray) -> FloatArray:
    """``Re(Yᴴ R)`` by two real products: (m, E) of ``Y`` (K, m) and ``R`` (K, E)."""
    out: FloatArray = Y.real.T @ R.real + Y.imag.T @ R.imag
    return out


def times_real(Y: ComplexArray, C: FloatArray) -> ComplexArray:
    """``Y C`` for real ``C`` by two real products (half the flops of a complex one)."""
    out = np.empty((Y.shape[0], C.shape[1]), dtype=complex)
    out.real = Y.real @ C
    out.imag = Y.imag @ C
    return out


def solve(G: FloatArray, b: FloatArray, rcond: float = 1e-14) -> tuple[FloatArray, float]:
    """``G⁻¹ b`` per leading index, and the largest condition number of the scaled columns.

    ``G``: (..., m, m) symmetric positive semi-definite, ``b``: (..., m) or (..., m, k).
    Columns scaled to unit norm; eigenvalues below ``rcond`` times the largest are
    dropped (the least-norm solution of a rank-deficient problem).
    """
    d = np.sqrt(np.maximum(np.diagonal(G, axis1=-2, axis2=-1), 0.0))
    big = np.max(d, axis=-1, keepdims=True) if d.size else d
    big = np.where(big > 0, big, 1.0)
    # a column of zeros to rounding is scaled like the largest: it stays negligible (its
    # eigenvalue falls under rcond) instead of being blown up to unit norm
    d = np.where(d > 1e-12 * big, d, big)
    Gs = G / d[..., :, None] / d[..., None, :]
    lam, V = np.linalg.eigh(Gs)
    top = lam[..., -1:]
    keep = lam > rcond * top
    inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    vec = b.ndim == G.ndim - 1
    bs = (b / d)[..., None] if vec else b / d[..., :, None]
    x = V @ (inv[..., :, None] * (np.swapaxes(V, -1, -2) @ bs))
    x = x / d[..., :, None]
    low = np.where(keep, lam, np.inf).min(axis=-1)
    cond = float(np.sqrt(np.max(top[..., 0] / low))) if lam.size else 1.0
    return (x[..., 0] if vec else x), cond
