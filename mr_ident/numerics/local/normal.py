# SPDX-License-Identifier: Apache-2.0
"""The LPM's normal equations for a chunk of windows: sums, Cholesky factor, residual.

The steps :func:`~mr_ident.numerics.local.lpm.lpm_bins_last` (every window solved at its
centre) and :func:`~mr_ident.numerics.local.strided.lpm_strided` (every few windows solved,
each evaluated at the bins around its centre) share, bins last (arrays ``(..., Kc)``):

* :func:`chunk_sums`: the windowed sums of the product signals (``K^H K``, ``K^H Y``,
  ``Y^H Y`` and the transient's part of the factor) at the centres of a stretch;
* :func:`factor`: the Cholesky factor ``L`` of ``K^H K`` and the forward solve
  ``L W = K^H Y``, left-looking, vectorised over windows;
* :func:`noise_cov`: ``C_v = (Y^H Y - W^H W)^T / q``.

The unknowns are ordered transient first (T = R + 1 of them, whose factor is constant),
then ``G_s`` for s = R..0, each n_in of them, so that ``G_0`` trails (:class:`Layout`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .window_sums import Kernel, kernels, moment_index, moving_sum, plain, window_sums

Sums = tuple[
    NDArray[np.complex128],
    NDArray[np.complex128],
    NDArray[np.complex128],
    NDArray[np.complex128],
    NDArray[np.complex128],
]


@dataclass(frozen=True)
class Layout:
    """Index arrays of one (n, degree, n_in, n_out): which sum fills which entry."""

    n: int
    degree: int
    n_in: int
    n_out: int
    L_TT: NDArray[np.float64]
    k_uu: Kernel
    k_u: Kernel
    k_uy: Kernel
    k_y: Kernel
    iu: NDArray[np.intp]
    ju: NDArray[np.intp]
    s_of: NDArray[np.intp]  # (P,) power s of unknown j (G_s, s = R..0)
    i_of: NDArray[np.intp]  # (P,) input of unknown j
    mom_ab: NDArray[np.intp]
    pair_ab: NDArray[np.intp]
    conj_ab: NDArray[np.bool_]
    ou: NDArray[np.intp]
    ov: NDArray[np.intp]

    @classmethod
    @functools.lru_cache(maxsize=32)
    def of(cls, n: int, degree: int, n_in: int, n_out: int) -> Layout:
        """The layout of half-width n, degree R, n_in inputs and n_out outputs (cached)."""
        L_TT, k_uu, k_u, k_uy, k_y = kernels(n, degree)
        iu, ju, pair = moment_index(n_in)
        s_of = np.repeat(np.arange(degree, -1, -1), n_in)
        i_of = np.tile(np.arange(n_in), degree + 1)
        ou, ov = np.triu_indices(n_out)
        return cls(
            n, degree, n_in, n_out, L_TT, k_uu, k_u, k_uy, k_y, iu, ju, s_of, i_of,
            s_of[:, None] + s_of[None, :],
            pair[i_of[:, None], i_of[None, :]],
            i_of[:, None] > i_of[None, :],
            ou, ov,
        )  # fmt: skip

    @property
    def T(self) -> int:
        """Transient unknowns, R + 1."""
        return self.degree + 1

    @property
    def P(self) -> int:
        """G unknowns, (R + 1) n_in."""
        return (self.degree + 1) * self.n_in

    @property
    def Q(self) -> int:
        """All unknowns."""
        return self.T + self.P


def chunk_sums(
    Ua: NDArray[np.complex128],
    Ya: NDArray[np.complex128],
    first: int,
    span: int,
    pick: NDArray[np.intp] | None,
    lay: Layout,
    *,
    stride: int = 1,
) -> Sums:
    """The windowed sums of the windows centred at ``first, first + stride, ...`` (span of them).

    Of padded spectra Ua (.., n_in), Ya (.., n_out) (the window of centre c is the bins
    ``c .. c + 2n``); with ``pick`` (stride 1), those positions counted from ``first`` only.
    Returns mUU, mUY, L_GT, W_T, mYY, bins last.
    """
    n, R, T, P = lay.n, lay.degree, lay.T, lay.P
    n_in, n_out = lay.n_in, lay.n_out
    width = stride * (span - 1) + 2 * n + 1
    k_uu, k_u, k_uy, k_y = (
        (lay.k_uu, lay.k_u, lay.k_uy, lay.k_y) if stride == 1 else kernels(n, R, stride)[1:]
    )
    Uc = Ua[first : first + width].T  # (n_in, width)
    Yc = Ya[first : first + width].T  # (n_out, width)
    Ucj = np.conj(Uc)
    UU = np.multiply(Ucj[lay.iu], Uc[lay.ju])  # conj(U_i) U_j, i <= j
    UY = np.multiply(Ucj[:, None, :], Yc[None, :, :]).reshape(n_in * n_out, width)
    mUU = window_sums(UU, k_uu, span)  # (2R+1, npair, span)
    mUY = window_sums(UY, k_uy, span).reshape(R + 1, n_in, n_out, span)
    L_GT = window_sums(Ucj, k_u, span).reshape(T, P, span)  # L_GT[u, (s, i)]
    W_T = window_sums(Yc, k_y, span)  # (T, n_out, span)
    YY = np.conj(Yc[lay.ou]) * Yc[lay.ov]
    if stride == 1:
        mYY = moving_sum(YY, n, span)  # (npair_o, span)
    else:  # the plain sum: the kernel x^0 of the G-G block
        mYY = window_sums(YY, plain(n, stride), span)[0]
    if pick is not None:
        return tuple(x[..., pick] for x in (mUU, mUY, L_GT, W_T, mYY))  # type: ignore[return-value]
    return mUU, mUY, L_GT, W_T, mYY


def factor(
    sums: Sums, lay: Layout
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.bool_]]:
    """Cholesky ``L L^H`` of the normal matrix and the forward solve ``L W = K^H Y``.

    Left-looking, vectorised over the Kc windows. The transient columns are known:
    ``L_TT`` is constant and ``L_GT``, ``W_T`` came out of the window sums, so eliminating
    the transient costs only a longer inner product per G column. Returns L (Q, Q, Kc),
    lower triangle used; W (Q, n_out, Kc); and the windows whose regressor is rank
    deficient (a pivot below 1e-13 of its diagonal entry; their values are finite garbage).
    """
    mUU, mUY, L_GT, W_T, _ = sums
    T, P, Q, n_out = lay.T, lay.P, lay.Q, lay.n_out
    s_of, i_of = lay.s_of, lay.i_of
    Kc = mUU.shape[-1]
    L = np.empty((Q, Q, Kc), dtype=np.complex128)
    W = np.empty((Q, n_out, Kc), dtype=np.complex128)
    L[:T, :T] = lay.L_TT[:, :, None]
    L[T:, :T] = L_GT.transpose(1, 0, 2)
    W[:T] = W_T
    bad = np.zeros(Kc, dtype=bool)
    buf = np.empty((max(Q, n_out), Kc), dtype=np.complex128)  # products, reused
    for j in range(P):
        J = T + j
        col = mUU[lay.mom_ab[j:, j], lay.pair_ab[j:, j]]  # A_GG[j:, j]
        flip = lay.conj_ab[j:, j]
        col[flip] = np.conj(col[flip])
        Lj = L[J, :J]
        d = (
            col[0].real
            - np.einsum("mk,mk->k", Lj.real, Lj.real)
            - np.einsum("mk,mk->k", Lj.imag, Lj.imag)
        )
        tiny = d <= 1e-13 * np.abs(col[0].real)
        bad |= tiny
        ljj = np.sqrt(np.where(tiny, 1.0, d))
        L[J, J] = ljj
        if J + 1 < Q:
            Ljc = np.conj(Lj)
            acc, tmp = L[J + 1 :, J], buf[: Q - J - 1]
            np.subtract(col[1:], np.multiply(L[J + 1 :, 0], Ljc[0], out=tmp), out=acc)
            for m in range(1, J):
                acc -= np.multiply(L[J + 1 :, m], Ljc[m], out=tmp)
            acc *= 1.0 / ljj
        acc, tmp = W[J], buf[:n_out]
        np.subtract(mUY[s_of[j], i_of[j]], np.multiply(Lj[0], W[0], out=tmp), out=acc)
        for m in range(1, J):
            acc -= np.multiply(Lj[m], W[m], out=tmp)
        acc *= 1.0 / ljj
    return L, W, bad


def noise_cov(
    mYY: NDArray[np.complex128], W: NDArray[np.complex128], q: int, out: NDArray[np.complex128]
) -> None:
    """``C_v = (Y^H Y - W^H W)^T / q`` into ``out`` (n_out, n_out, Kc); overwrites mYY.

    ``mYY`` holds the upper-triangle pairs of ``Y^H Y`` (row by row), W (Q, n_out, Kc).
    """
    n_out, Q = out.shape[0], W.shape[0]
    ou, ov = np.triu_indices(n_out)
    Wc = np.conj(W)
    buf = np.empty((n_out, mYY.shape[-1]), dtype=np.complex128)
    p0 = 0
    for a in range(n_out):  # the pairs (a, a..n_out-1) are consecutive in ou, ov
        v, tmp = mYY[p0 : p0 + n_out - a], buf[: n_out - a]
        for j in range(Q):
            v -= np.multiply(W[j, a:], Wc[j, a], out=tmp)
        p0 += n_out - a
    out[ov, ou] = mYY / q
    out[ou, ov] = np.conj(out[ov, ou])
