# SPDX-License-Identifier: Apache-2.0
"""Local rational method (LRM), MIMO, batched over all frequency bins.

Model in the window ``r = -n..n`` around every centre bin k, ``x = r/n``
(McKelvey & Guérin, SYSID 2012; Pintelon & Schoukens 2012, sec. 7.2.6)::

    D(x) Y(k+r) = N(x) U(k+r) + M(x) + D(x) V(k+r)
    N(x) = sum_{s=0}^{R} N_s x^s   (n_out x n_in),   M(x) = sum_{s=0}^{R} M_s x^s,
    D(x) = 1 + sum_{t=1}^{R_d} d_t x^t                (one scalar denominator, monic at x=0)

so that ``G(k) = N(0) / D(0) = N_0``. One denominator is common to every output and
input of the window: the poles of a MIMO (or lifted) system are shared by all its
entries, and a lightly damped mode is one pole pair near the window, which a polynomial
cannot follow but a denominator of order 2 can. The coefficients are complex (a local
model in the complex frequency domain).

Estimation
----------
1. Levy's linearisation: ``Y = N U + M - (D - 1) Y + e`` is linear in all unknowns,
   ``e = D V``. With the regressor ``K = [x^s U, x^s]`` (common to every output) and the
   denominator columns ``Phi_o = -Y_o x^t``, the numerator and transient ``theta_o`` of
   each output are projected out (variable projection):
   ``d = (sum_o Phi~_o^H Phi~_o)^-1 sum_o Phi~_o^H Y~_o`` with ``X~ = X - K A^-1 K^H X``,
   ``A = K^H K``; then ``theta_o = A^-1 K^H (Y_o - Phi_o d)``.
2. :data:`SK_ITERATIONS` Sanathanan-Koerner steps: the same with every row weighted by
   ``1 / D_prev(x)`` (the previous denominator), so that the equation error
   ``D/D_prev V`` is close to V: white, and the fit close to the output-error one.

Covariance (first order, the last step's equation error taken as V): the residuals of
the last weighted fit give ``C_v`` with ``q = 2n+1 - (R+1)(n_in+1) - ceil(R_d / n_out)``
degrees of freedom (the denominator's R_d unknowns shared among the n_out outputs), and
with ``C_o = A^-1 K^H Phi_o`` (its G_0 rows ``C0_o``, n_in x R_d)::

    Cov(G[o, :], G[o2, :]) = C_v[o, o2] (A^-1)_00 + C0_o S_d C0_o2^H
    S_d = B^-1 (sum_{o,o2} C_v[o, o2] Phi~_o^H Phi~_o2) B^-1,   B = sum_o Phi~_o^H Phi~_o

The first term is the LPM's Kronecker form (``inv_gram`` = (A^-1)_00); the second is
the denominator's uncertainty, carried by ``den_gain`` (C0) and ``den_cov`` (S_d). The
approximation: the denominator's regressors hold the noisy Y (errors in variables; a
bias of order the noise variance, neglected) and the weight is taken as known.

Shapes: bins last, as :func:`~mr_ident.numerics.local.lpm.lpm_bins_last`: the windows of a
chunk of bins are formed explicitly (``(B, 2n+1, ...)`` stacks) and every solve runs on
``(B, p, p)`` stacks; no Python loop per bin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...errors import ConfigError
from ..arrays import BoolArray, ComplexArray
from ..budget import lrm_chunk_bins
from ..threads import thread_map
from .lpm import check_window
from .lpm import dof as lpm_dof

#: Sanathanan-Koerner re-weighted steps after Levy's.
SK_ITERATIONS = 1


def den_degree(degree: int) -> int:
    """The denominator order R_d of the LRM: the numerator's R (McKelvey & Guérin's choice)."""
    return degree


def dof(n: int, degree: int, n_in: int, n_out: int) -> int:
    """Residual degrees of freedom per output: ``2n+1 - (R+1)(n_in+1) - ceil(R_d/n_out)``.

    ``n_out`` is the number of outputs fitted together (sharing the denominator).
    """
    return lpm_dof(n, degree, n_in) - -(-den_degree(degree) // n_out)


def smallest_n(degree: int, n_in: int, n_out: int, n_fit: int, margin: int = 0) -> int:
    """The smallest n with ``dof(n, degree, n_in, n_fit) > n_out + margin``.

    >>> smallest_n(2, 1, 1, 2)          # 2n + 1 - 6 - 1 > 1 first holds at n = 4
    4
    """
    need = n_out + margin + (degree + 1) * (n_in + 1) + -(-den_degree(degree) // n_fit)
    return (need - 1) // 2 + 1


def check_lrm_options(n: int, degree: int, n_in: int, n_out: int, n_fit: int) -> int:
    """Validate the window and orders of the LRM; return its dof q.

    ``n_out`` outputs per map must stay below q (as for the LPM); ``n_fit`` outputs are
    fitted together.

    Raises
    ------
    ConfigError
        If ``degree < 1`` (no denominator) or the window cannot support the orders.
    """
    check_window(n, degree)
    if degree < 1:
        raise ConfigError(
            f"local rational needs degree R >= 1 (numerator, transient and denominator "
            f"order R), got {degree!r}"
        )
    q = dof(n, degree, n_in, n_fit)
    if q <= n_out:
        need = smallest_n(degree, n_in, n_out, n_fit)
        raise ConfigError(
            f"local rational degrees of freedom: 2n+1 - (R+1)(n_in+1) - ceil(R_d/{n_fit}) = "
            f"{2 * n + 1} - {degree + 1}*{n_in + 1} - {-(-den_degree(degree) // n_fit)} = {q} "
            f"must exceed n_out = {n_out} (n={n}, numerator and transient order R={degree}, "
            f"denominator order R_d={den_degree(degree)}, n_in={n_in}); use n >= {need} or a "
            "lower degree"
        )
    return q


@dataclass(frozen=True)
class DenominatorTerm:
    """The denominator's share of the covariance of G, bins last.

    ``Cov(G[o, b], G[o2, b2]) += sum_{t,t2} gain[o, b, t] cov[t, t2, k] conj(gain[o2, b2, t2])``

    Attributes
    ----------
    gain : ndarray, shape (n_out, n_in, R_d, K), complex128
        C0: how the denominator's error moves G_0.
    cov : ndarray, shape (R_d, R_d, K), complex128
        S_d: the covariance of the denominator's coefficients.
    """

    gain: ComplexArray
    cov: ComplexArray


def _windows(X: ComplexArray, k0: int, B: int, L: int) -> ComplexArray:
    """The windows ``X[k0+j : k0+j+L]`` of B bins as a (B, L, c) view."""
    v: ComplexArray = np.lib.stride_tricks.sliding_window_view(X[k0 : k0 + B + L - 1], L, axis=0)
    return v.transpose(0, 2, 1)


def _inv_hermitian(A: ComplexArray) -> tuple[ComplexArray, BoolArray]:
    """Inverses of Hermitian positive (semi)definite (B, p, p) stacks, Jacobi scaled.

    Returns the inverses and the bins whose matrix is numerically singular (identity
    there, to be flagged by the caller).
    """
    p = A.shape[-1]
    dg = np.real(np.diagonal(A, axis1=1, axis2=2))
    scale = np.where(dg > 0, dg, 1.0) ** -0.5
    As = A * scale[:, :, None] * scale[:, None, :]
    bad: BoolArray = np.asarray(~(dg > 0).all(axis=1))
    eye = np.eye(p)
    As[bad] = eye
    try:
        Lc = np.linalg.cholesky(As)
        # the LPM's criterion: a pivot below 1e-13 of its (unit) diagonal
        bad |= (np.real(np.diagonal(Lc, axis1=1, axis2=2)) ** 2 <= 1e-13).any(axis=1)
    except np.linalg.LinAlgError:
        w = np.linalg.eigvalsh(As)
        bad |= w[:, 0] <= 1e-13 * w[:, -1]
    As[bad] = eye
    Ai = np.asarray(np.linalg.solve(As, np.broadcast_to(eye, As.shape)), dtype=np.complex128)
    out: ComplexArray = Ai * scale[:, :, None] * scale[:, None, :]
    return out, bad


def _fit_chunk(
    Uw: ComplexArray, Yw: ComplexArray, n: int, degree: int, q: int
) -> tuple[ComplexArray, ComplexArray, ComplexArray, ComplexArray, ComplexArray, BoolArray]:
    """The LRM on B windows: Uw (B, L, n_in), Yw (B, L, n_out).

    Returns G (B, n_out, n_in), C_v (B, n_out, n_out), (A^-1)_00 (B, n_in, n_in),
    C0 (B, n_out, n_in, R_d), S_d (B, R_d, R_d) and the rank-deficient bins.
    """
    B, L, n_in = Uw.shape
    n_out = Yw.shape[2]
    T, Rd = degree + 1, den_degree(degree)
    x = np.arange(-n, n + 1) / n
    xs = x[:, None] ** np.arange(T)  # (L, T)
    xd = x[:, None] ** np.arange(1, Rd + 1)  # (L, Rd)
    # Regressor: x^s U_i (s-major, so that G_0 = theta[:n_in]) and the transient x^s.
    K = np.concatenate(
        [(xs[None, :, :, None] * Uw[:, :, None, :]).reshape(B, L, T * n_in)]
        + [np.broadcast_to(xs.astype(complex), (B, L, T))],
        axis=2,
    )
    # Right-hand sides: Y_o and the denominator columns Phi_o[t] = -Y_o x^t.
    rhs0 = np.concatenate(
        [Yw, (-Yw[:, :, :, None] * xd[None, :, None, :]).reshape(B, L, n_out * Rd)], axis=2
    )
    w = np.ones((B, L), dtype=complex)
    bad = np.zeros(B, dtype=bool)
    for _ in range(1 + SK_ITERATIONS):
        Kw = K * w[:, :, None]
        rhs = rhs0 * w[:, :, None]
        KwH = np.conj(Kw.transpose(0, 2, 1))
        Ainv, bad = _inv_hermitian(KwH @ Kw)
        Z = Ainv @ (KwH @ rhs)  # (B, P, n_out (1 + Rd)): theta of Y_o and C_o
        res = rhs - Kw @ Z  # projected: Y~_o, Phi~_o
        Yt = res[:, :, :n_out]
        Pt = res[:, :, n_out:].reshape(B, L, n_out, Rd)
        Bm = np.einsum("blot,blos->bts", np.conj(Pt), Pt)
        c = np.einsum("blot,blo->bt", np.conj(Pt), Yt)
        # A denominator the data cannot tell (exactly polynomial data: Phi~ = 0) is 1.
        reg = 1e-12 * np.real(np.trace(Bm, axis1=1, axis2=2)) + 1e-300
        Binv = np.linalg.inv(Bm + reg[:, None, None] * np.eye(Rd))
        d = np.einsum("bts,bs->bt", Binv, c)
        Dx = 1.0 + d @ xd.T  # (B, L)
        w = np.where(Dx != 0, 1.0 / np.where(Dx != 0, Dx, 1.0), 0.0)
    C = Z[:, :n_in, n_out:].reshape(B, n_in, n_out, Rd).transpose(0, 2, 1, 3)
    G = Z[:, :n_in, :n_out].transpose(0, 2, 1) - np.einsum("boit,bt->boi", C, d)
    E = Yt - np.einsum("blot,bt->blo", Pt, d)  # the last fit's residuals
    Cv = np.einsum("bla,blc->bac", E, np.conj(E)) / q
    PtC = Pt.reshape(B, L, n_out * Rd)
    H = np.einsum("blu,blv->buv", np.conj(PtC), PtC).reshape(B, n_out, Rd, n_out, Rd)
    mid = np.einsum("bac,batcs->bts", Cv, H)  # sum_{o,o2} C_v[o,o2] Phi~_o^H Phi~_o2
    Sd = Binv @ mid @ np.conj(Binv.transpose(0, 2, 1))
    return G, Cv, Ainv[:, :n_in, :n_in], C, Sd, bad


def lrm_bins_last(
    Ua: NDArray[np.complex128],
    Ya: NDArray[np.complex128],
    n: int,
    degree: int,
    q: int,
    workers: int = 1,
) -> tuple[ComplexArray, ComplexArray, ComplexArray, int, DenominatorTerm]:
    """The LRM at every centre bin of padded spectra (options already checked).

    Parameters
    ----------
    Ua : ndarray, shape (K + 2n, n_in), complex
    Ya : ndarray, shape (K + 2n, n_out), complex
    n, degree : int
        Window half-width and order R (numerator, transient; denominator :func:`den_degree`).
    q : int
        Degrees of freedom, :func:`dof`.
    workers : int
        Threads over chunks of bins.

    Returns
    -------
    G : ndarray, shape (n_out, n_in, K)
    noise_cov : ndarray, shape (n_out, n_out, K)
    inv_gram : ndarray, shape (n_in, n_in, K)
        With ``noise_cov`` the LPM-form part of the covariance (see the module docstring).
    n_bad : int
        Bins whose regressor is rank deficient (NaN there).
    den : DenominatorTerm
        The denominator's part of the covariance.
    """
    n_in, n_out = Ua.shape[1], Ya.shape[1]
    K = Ua.shape[0] - 2 * n
    L = 2 * n + 1
    Rd = den_degree(degree)
    step = lrm_chunk_bins(n_in, n_out, degree, n)
    G = np.empty((n_out, n_in, K), dtype=np.complex128)
    Cv = np.empty((n_out, n_out, K), dtype=np.complex128)
    Ainv = np.empty((n_in, n_in, K), dtype=np.complex128)
    C0 = np.empty((n_out, n_in, Rd, K), dtype=np.complex128)
    Sd = np.empty((Rd, Rd, K), dtype=np.complex128)

    def chunk(k0: int) -> int:
        B = min(step, K - k0)
        parts = _fit_chunk(_windows(Ua, k0, B, L), _windows(Ya, k0, B, L), n, degree, q)
        *arrays, bad = parts
        for dst, src in zip((G, Cv, Ainv, C0, Sd), arrays, strict=True):
            dst[..., k0 : k0 + B] = np.moveaxis(src, 0, -1)
        if bad.any():
            idx = np.nonzero(bad)[0] + k0
            for dst in (G, Cv, Ainv, C0, Sd):
                dst[..., idx] = np.nan
        return int(bad.sum())

    n_bad = sum(thread_map(chunk, range(0, K, step), workers))
    d = np.arange(n_out)
    Cv[d, d] = np.maximum(Cv[d, d].real, 0.0)
    return G, Cv, Ainv, n_bad, DenominatorTerm(C0, Sd)
