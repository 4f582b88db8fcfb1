# SPDX-License-Identifier: Apache-2.0
"""Sums over sliding windows of frequency bins: the LPM's moment sums, batched.

Every entry of the LPM's normal equations (``K^H K``, ``K^H Y``, ``Y^H Y``) is a sum over
the window ``r = -n..n`` of a product signal times a kernel ``(r/n)^q`` (or the window's
orthonormal polynomials): :func:`window_sums` computes them for all bins at once, one
real BLAS product per block of bins against a banded Toeplitz matrix (:class:`Kernel`);
:func:`kernels` builds the kernels of :func:`~mr_ident.numerics.local.lpm.lpm_bins_last`;
:func:`moving_sum` is the unweighted sum by doubling.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: Bins per block of :func:`window_sums`: a fixed block about as fast as any near it and
#: faster than one of 2n bins at wide windows (measured: docs/benchmarks.md).
BLOCK = 16


@dataclass(frozen=True)
class Kernel:
    """Weights ``w[q, r]`` (r = -n..n) of :func:`window_sums` as a banded Toeplitz matrix.

    Output i of a block of B bins draws on inputs t = 0..B+2n-1 counted from the
    block's first bin (the block and the 2n bins after it):
    ``taps[t, (q, i)] = w[q, t - i]``, shape (B + 2n, n_q * B). The work per bin is
    ``(B + 2n) n_q`` multiply-adds, so B is small and fixed (:data:`BLOCK`): a B that grew
    with n (it was 2n) made a window of n = 27 cost 1.8x one of n = 8 in the sums.
    """

    taps: NDArray[np.float64]
    n_out: int
    B: int
    stride: int = 1

    @classmethod
    def of(cls, w: NDArray[np.float64], stride: int = 1) -> Kernel:
        """The kernel of weights ``w`` (n_q, 2n+1); outputs every ``stride`` bins.

        With a stride s, output i of a block is the window centred ``s i`` bins after the
        block's first centre: ``taps[t, (q, i)] = w[q, t - s i]``, shape
        (s (B - 1) + 2n + 1, n_q * B).
        """
        nq, L = w.shape
        B = BLOCK
        T = np.zeros((stride * (B - 1) + L, nq, B))
        for i in range(B):
            T[stride * i : stride * i + L, :, i] = w.T
        T = T.reshape(T.shape[0], nq * B)
        T.flags.writeable = False
        return cls(T, nq, B, stride)


@functools.lru_cache(maxsize=32)
def kernels(
    n: int, degree: int, stride: int = 1
) -> tuple[NDArray[np.float64], Kernel, Kernel, Kernel, Kernel]:
    """The constant transient factor ``L_TT`` and the window kernels of :func:`lpm_bins_last`.

    For half-width n and degree R; the sums every ``stride`` centres.

    With ``x = r/n`` and ``phi_u`` the polynomials orthonormal on the window
    (``phi = V L_TT^-T``, ``V[r, t] = x^t``, ``L_TT L_TT^T = V^T V``):

    * ``x^q``, q = 0..2R, for the products ``conj(U_i) U_j`` (the G-G block);
    * ``phi_u(r) x^s``, u = 0..R, s = R..0, for ``conj(U_i)``: the G-transient block of
      the Cholesky factor, ``L_GT = A_GT L_TT^-T``, directly;
    * ``x^s``, s = 0..R, for ``conj(U_i) Y_o`` (the right-hand side of G);
    * ``phi_u``, u = 0..R, for ``Y_o``: the transient rows of the forward solve directly.
    """
    x = np.arange(-n, n + 1) / n
    T = degree + 1
    V = x[:, None] ** np.arange(T)[None, :]
    L_TT = np.linalg.cholesky(V.T @ V)
    L_TT.flags.writeable = False
    phi = V @ np.linalg.inv(L_TT).T  # (2n+1, T)
    powers = x[None, :] ** np.arange(2 * degree + 1)[:, None]  # (2R+1, 2n+1)
    s_desc = np.arange(degree, -1, -1)
    phi_x = (phi.T[:, None, :] * powers[s_desc][None, :, :]).reshape(T * T, -1)
    return (
        L_TT,
        Kernel.of(powers, stride),
        Kernel.of(phi_x, stride),
        Kernel.of(powers[:T], stride),
        Kernel.of(phi.T.copy(), stride),
    )


@functools.lru_cache(maxsize=16)
def plain(n: int, stride: int = 1) -> Kernel:
    """The kernel of the plain sum over the window (all weights 1)."""
    return Kernel.of(np.ones((1, 2 * n + 1)), stride)


def window_sums(Z: NDArray[np.complex128], kernel: Kernel, K: int) -> NDArray[np.complex128]:
    """Windowed sums ``S[q, c, k] = sum_{r=-n}^{n} w[q, r] Z[c, s k + n + r]``, k = 0..K-1.

    Z has shape (C, s (K-1) + 2n + 1) (s the kernel's stride, usually 1); the result
    (n_q, C, K). The sums are a correlation with 2n+1 taps, done as one real matrix
    product (BLAS) per block of B outputs against a banded Toeplitz matrix
    (:class:`Kernel`): the real and imaginary parts of every signal over the block's
    windows are rows.
    """
    C = Z.shape[0]
    B, nq, st = kernel.B, kernel.n_out, kernel.stride
    span = kernel.taps.shape[0]  # s (B - 1) + 2n + 1
    nb = -(-K // B)
    need = (nb - 1) * B * st + span
    if Z.shape[1] < need:
        Zp = np.zeros((C, need), dtype=np.complex128)
        Zp[:, : Z.shape[1]] = Z
        Z = Zp
    c_st, k_st = Z.strides
    blocks = np.lib.stride_tricks.as_strided(
        Z, (C, nb, span), (c_st, B * st * k_st, k_st), writeable=False
    )  # overlapping: block b = Z[:, b B s : b B s + span]
    X = np.empty((2, C, nb, span))
    X[0] = blocks.real
    X[1] = blocks.imag
    o = (X.reshape(2 * C, nb, span) @ kernel.taps).reshape(2, C, nb, nq, B)
    out = np.empty((nq, C, nb, B), dtype=np.complex128)
    out.real = o[0].transpose(2, 0, 1, 3)
    out.imag = o[1].transpose(2, 0, 1, 3)
    return out.reshape(nq, C, nb * B)[:, :, :K]


def moment_index(n_in: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The upper-triangle pairs (i, j) of n_in inputs and each pair's index, symmetric."""
    iu, ju = np.triu_indices(n_in)
    pair = np.empty((n_in, n_in), dtype=np.intp)
    pair[iu, ju] = np.arange(iu.size)
    pair[ju, iu] = np.arange(iu.size)
    return iu, ju, pair


def moving_sum(Z: NDArray[np.complex128], n: int, K: int) -> NDArray[np.complex128]:
    """``S[c, k] = sum_{r=-n}^{n} Z[c, k+n+r]`` by doubling: O(log n) adds, no cumsum drift."""
    L = 2 * n + 1
    out: NDArray[np.complex128] | None = None
    offset = 0
    block = Z  # block[c, j] = sum of `width` samples starting at j
    width = 1
    while True:
        if L & width:
            part = block[:, offset : offset + K]
            out = part.copy() if out is None else out + part
            offset += width
        if 2 * width > L:
            break
        block = block[:, :-width] + block[:, width:]
        width *= 2
    assert out is not None
    return out
