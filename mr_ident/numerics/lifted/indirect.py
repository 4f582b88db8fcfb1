# SPDX-License-Identifier: Apache-2.0
"""The indirect closed-loop step ``P = J S^-1`` on a joint local fit of r -> [y; u].

Shared by the methods (:mod:`mr_ident.numerics.lifted.methods`): P and the Kronecker
factors of its covariance, ``row = E C_v Eᴴ`` with ``E = [I, -P]`` and
``col = S^-T A^-1 conj(S^-1)``, and a rational fit's denominator share.
"""

from __future__ import annotations

import numpy as np

from .. import batched
from ..arrays import BoolArray, ComplexArray, FloatArray
from ..lifting import half_to_full, unlift_frf
from ..local.fit import LocalFit
from ..local.lrm import DenominatorTerm


def indirect_full(
    G: ComplexArray, Cv: ComplexArray, Ainv: ComplexArray, n_y: int
) -> tuple[ComplexArray, ComplexArray, ComplexArray]:
    """Indirect step ``P = J S^-1`` on a joint LPM fit of [J; S] (bins-first arrays).

    Returns P (K, n_y, n_u) and the Kronecker covariance factors of P:
    ``row = E C_v E^H`` with ``E = [I, -P]`` and ``col = S^-T A^-1 conj(S^-1)``.
    """
    J, S = G[:, :n_y], G[:, n_y:]
    Sinv = np.linalg.inv(S)
    P: ComplexArray = J @ Sinv
    E = np.concatenate([np.broadcast_to(np.eye(n_y), P.shape[:1] + (n_y, n_y)), -P], axis=2)
    row: ComplexArray = E @ Cv @ np.conj(np.swapaxes(E, 1, 2))
    col: ComplexArray = np.swapaxes(Sinv, 1, 2) @ Ainv @ np.conj(Sinv)
    return P, row, col


def indirect_diag(
    fit: LocalFit, n_y: int
) -> tuple[ComplexArray, FloatArray, FloatArray, FloatArray | None]:
    """:func:`indirect_full` bins-last, keeping only the diagonals of the covariance factors.

    ``fit`` of [J; S]: G (n_y + n_u, n_u, K), C_v (n_y + n_u, n_y + n_u, K), A^-1 (n_u, n_u,
    K). Returns P (n_y, n_u, K), ``diag(E C_v E^H)`` (n_y, K) and
    ``diag(S^-T A^-1 conj(S^-1))`` (n_u, K): enough for the standard deviation of every
    entry of P; and, for a rational fit, the denominator's share of it (n_y, n_u, K)
    (:func:`_den_variance`), else None.
    """
    G, Cv, Ainv = fit.G, fit.noise_cov, fit.inv_gram
    J, S = G[:n_y], G[n_y:]
    Sinv = batched.inv(S)
    P = batched.matmul(J, Sinv)
    # diag(E Cv E^H)_a = Cv_yy[a,a] - 2 Re(Cv_yu[a,:] P[a,:]^H) + P[a,:] Cv_uu P[a,:]^H
    d = np.arange(n_y)
    row = (
        Cv[d, d].real
        - 2.0 * batched.real_dot(Cv[:n_y, n_y:], P, axis=1)
        + batched.real_dot(batched.matmul(P, Cv[n_y:, n_y:]), P, axis=1)
    )
    # diag(S^-T A^-1 conj(S^-1))_b = Re sum_j (S^-T A^-1)[b, j] conj(S^-1[j, b])
    col = batched.real_dot(
        batched.matmul(Sinv.transpose(1, 0, 2), Ainv), Sinv.transpose(1, 0, 2), axis=1
    )
    extra = None if fit.den is None else _den_variance(_den_gain(fit.den, P, Sinv, n_y), fit.den)
    return P, np.maximum(row, 0.0), np.maximum(col, 0.0), extra


def _den_gain(den: DenominatorTerm, P: ComplexArray, Sinv: ComplexArray, n_y: int) -> ComplexArray:
    """How the denominator's error moves P = J S^-1, bins last: g (n_y, n_u, R_d, K).

    ``dG[o, j] = -sum_t C0[o, j, t] dd_t``, so ``dP = E dG S^-1 = -g dd`` with
    ``g[a, b, t] = sum_{o, j} E[a, o] C0[o, j, t] S^-1[j, b]``, ``E = [I, -P]``.
    """
    C0 = den.gain
    EC = C0[:n_y] - np.einsum("ack,cjtk->ajtk", P, C0[n_y:])
    g: ComplexArray = np.einsum("ajtk,jbk->abtk", EC, Sinv)
    return g


def _den_variance(g: ComplexArray, den: DenominatorTerm) -> FloatArray:
    """``E|g dd|^2 = Re sum_{t,s} g_t S_d[t, s] conj(g_s)`` per entry: g (..., R_d, K)."""
    v: FloatArray = np.maximum(
        np.einsum("...tk,tsk,...sk->...k", g, den.cov, np.conj(g)).real, 0.0
    )
    return v


def indirect_on(
    G: ComplexArray, Cv: ComplexArray, Ainv: ComplexArray, n_y: int, fitted: BoolArray
) -> tuple[ComplexArray, ComplexArray, ComplexArray]:
    """:func:`indirect_full` on the ``fitted`` bins; NaN on the others."""
    if fitted.all():
        return indirect_full(G, Cv, Ainv, n_y)
    parts = indirect_full(G[fitted], Cv[fitted], Ainv[fitted], n_y)
    out = []
    for a in parts:
        full = np.full((G.shape[0],) + a.shape[1:], np.nan + 0j)
        full[fitted] = a
        out.append(full)
    return out[0], out[1], out[2]


def time_den_variance(
    den: DenominatorTerm, P: ComplexArray, S: ComplexArray, n_y: int, ratio: int, M: int
) -> FloatArray:
    """The denominator's variance of the time-lifted P_h: (M, F, n_y, n_u) as unlift_variance.

    P (K, F n_y, F n_u) and S on the lifted bins 0..M//2; each coefficient's gain g_t
    extended to all M bins by conjugate symmetry (with S_d conjugated there, which leaves
    the variance real and mirrored) and unlifted like P.
    """
    Sinv = np.asarray(np.linalg.inv(S), dtype=np.complex128)
    g = _den_gain(den, P.transpose(1, 2, 0), Sinv.transpose(1, 2, 0), n_y)
    g_full = half_to_full(np.moveaxis(g, -1, 0), M)  # (M, F n_y, F n_u, R_d)
    cov = half_to_full(np.moveaxis(den.cov, -1, 0), M)  # (M, R_d, R_d)
    h = np.stack(
        [unlift_frf(g_full[..., t], ratio, domain="time") for t in range(g.shape[2])], axis=-1
    )  # (M, F, n_y, n_u, R_d)
    v: FloatArray = np.maximum(np.einsum("mlabt,mts,mlabs->mlab", h, cov, np.conj(h)).real, 0.0)
    return v
