# SPDX-License-Identifier: Apache-2.0
"""Variable projection: the poles (and delay) by Levenberg–Marquardt, residues solved linearly.

The cost ``V = Σ_k Σ_e |P̂_e(k) - G_e(k, θ)|² / σ_e(k)²`` is, for fixed poles and delay,
a weighted linear least-squares problem in the residues (one per entry, all sharing the
columns of :func:`~mr_ident.numerics.fit.basis.columns`); its solution put back leaves a
function of the poles alone (Golub & Pereyra 1973), minimised by Levenberg–Marquardt over
the stable parametrisation. Nothing of the size bins x parameters is factorised: every
product the method needs is a Gram matrix summed over blocks of bins (:mod:`.normal`), so
one step costs about one pass over the data per entry (1e5 bins, 3 x 3, order 40: about
0.5 s of one core). The Jacobian is Kaufman's (1975), ``J = -√2 P⊥ D`` with ``D = ∂(Φ c)/∂x``
from the exact pole derivatives of the columns (:func:`~.basis.pole_derivatives`); its
normal matrix ``JᵀJ = 2 (DᵀD - DᵀA (AᵀA)⁻¹ AᵀD)`` and the gradient ``Jᵀr = -2 Re(Dᴴ r)``
(exact: the dropped term is orthogonal to r). The covariance of every parameter is that of
the full problem at the minimum, ``(JᵀJ)⁻¹`` of the residual in units of its std (real and
imaginary parts each of variance σ²/2 for the LPM's circular errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arrays import ComplexArray, FloatArray, IndexArray
from .basis import columns, delay_derivatives, from_params, pole_derivatives, to_params
from .normal import gram, solve

#: Least decrease of ``‖r‖² = 2V`` that continues Levenberg–Marquardt.
F_TOL = 0.02

#: Most refinement steps of a linear solve (stopped once the correction is at rounding).
REFINEMENTS = 4


@dataclass(frozen=True)
class Problem:
    """The data of one fit: bins ``z`` (K,), responses ``P`` (K, E), weights ``W = 1/σ``.

    ``workers``: threads over the entries (None: every CPU).
    """

    z: ComplexArray
    P: ComplexArray
    W: FloatArray
    domain: str
    h: float
    w_ref: float
    direct: bool
    workers: int | None = None


def _coefficients(prob: Problem, Phi: ComplexArray) -> tuple[FloatArray, ComplexArray, float]:
    """Coefficients (n_cols, E), weighted residuals (K, E), condition number (columns)."""
    K, E = prob.P.shape
    W = prob.W
    G = gram(lambda r, e: W[r, e, None] * Phi[r], K, E, Phi.shape[1], prob.workers)
    Ph = Phi.conj().T
    coef, kappa = solve(G, (Ph @ (W * W * prob.P)).real.T)
    res = W * (prob.P - Phi @ coef.T)
    for _ in range(REFINEMENTS):  # on the residual: each step gains -log10(κ² eps) digits
        fix, _ = solve(G, (Ph @ (W * res)).real.T)
        coef = coef + fix
        res = W * (prob.P - Phi @ coef.T)
        if np.max(np.abs(fix)) <= 1e-14 * np.max(np.abs(coef)):
            break
    return coef.T, res, kappa


def solve_linear(
    prob: Problem, poles: ComplexArray, delay: float
) -> tuple[FloatArray, ComplexArray]:
    """Coefficients (n_cols, E) and weighted residuals ``W (P - Φ c)`` (K, E)."""
    Phi = columns(poles, prob.z, prob.domain, prob.h, delay, direct=prob.direct)
    coef, res, _ = _coefficients(prob, Phi)
    return coef, res


def cost(prob: Problem, poles: ComplexArray, delay: float) -> float:
    """``V`` with the residues solved."""
    return float(np.sum(np.abs(solve_linear(prob, poles, delay)[1]) ** 2))


def _stack(res: ComplexArray) -> FloatArray:
    """Weighted complex residuals as unit-variance reals: ``√2 [Re; Im]``."""
    r = res.ravel()
    return np.asarray(np.sqrt(2.0) * np.concatenate([r.real, r.imag]), dtype=float)


class _Point:
    """One evaluation: poles, delay, columns, coefficients, residuals, cost 2V."""

    def __init__(self, prob: Problem, x: FloatArray, poles: ComplexArray, tau: float) -> None:
        self.x, self.poles, self.tau = x, poles, tau
        self.Phi = columns(poles, prob.z, prob.domain, prob.h, tau, direct=prob.direct)
        self.coef, self.res, self.kappa = _coefficients(prob, self.Phi)
        self.f = 2.0 * float(np.sum(self.res.real**2 + self.res.imag**2))


class _Projected:
    """The projected problem in ``x`` = [pole parameters, delay / h (when free)]."""

    def __init__(self, prob: Problem, pair: list[bool], delay: float | None) -> None:
        self.prob, self.pair, self.delay = prob, pair, delay
        self.n_u = sum(2 if q else 1 for q in pair)
        self.n_x = self.n_u + (1 if delay is None else 0)
        widths = [2 if q else 1 for q in pair]  # parameters and columns per pole
        self.first = np.concatenate([[0], np.cumsum(widths)[:-1]]).astype(int)
        self.is_pair = np.array(pair, dtype=bool)

    def unpack(self, x: FloatArray) -> tuple[ComplexArray, float]:
        """Poles and delay of x."""
        prob = self.prob
        u = np.clip(x[: self.n_u], -40.0, 40.0)
        tau = self.delay if self.delay is not None else float(x[-1]) * prob.h
        return from_params(u, self.pair, prob.domain, prob.h, prob.w_ref), tau

    def point(self, x: FloatArray) -> _Point:
        """Coefficients and residuals at x."""
        poles, tau = self.unpack(x)
        return _Point(self.prob, x.copy(), poles, tau)

    def _chain(self, x: FloatArray) -> FloatArray:
        """``∂(Re p, Im p)/∂(u_a, u_b)`` per pole (n_p, 2, 2); a real pole's in [0, 0]."""
        prob = self.prob
        u = np.clip(x[: self.n_u], -40.0, 40.0)
        T = np.zeros((len(self.pair), 2, 2))
        for k, q in enumerate(self.pair):
            j = int(self.first[k])
            for i in range(2 if q else 1):
                step = 1e-5 * max(abs(u[j + i]), 1.0)
                uu = [u[j : j + (2 if q else 1)].copy() for _ in range(2)]
                uu[0][i] += step
                uu[1][i] -= step
                hi, lo = (from_params(v, [q], prob.domain, prob.h, prob.w_ref)[0] for v in uu)
                d = (hi - lo) / (2 * step)
                T[k, :, i] = [d.real, d.imag]
        return T

    def derivative(self, pt: _Point) -> tuple[ComplexArray, ComplexArray | None, FloatArray]:
        """What :meth:`columns_d` needs: Ψ, the delay's columns (or None), the chain.

        Ψ in grouped order (:attr:`group_u`).
        """
        prob = self.prob
        Psi = pole_derivatives(pt.poles, prob.z, prob.domain, prob.h, pt.tau)[:, self.group_u]
        Dt = None
        if self.delay is None:
            Dt = prob.h * delay_derivatives(pt.poles, prob.z, prob.h, pt.tau, direct=prob.direct)
        return np.ascontiguousarray(Psi), Dt, self._chain(pt.x)

    @property
    def group_u(self) -> IndexArray:
        """The pole parameters (and columns) grouped: pairs' first, second, real poles'."""
        f, q = self.first, self.is_pair
        out: IndexArray = np.concatenate([f[q], f[q] + 1, f[~q]]).astype(np.intp)
        return out

    @property
    def group(self) -> IndexArray:
        """Which parameter each column of :meth:`columns_d` is (the delay last)."""
        out: IndexArray = np.concatenate([self.group_u, np.arange(self.n_u, self.n_x)])
        return out.astype(np.intp)

    def columns_d(
        self,
        Psi: ComplexArray,
        Dt: ComplexArray | None,
        T: FloatArray,
        c: FloatArray,
        rows: slice,
    ) -> ComplexArray:
        """``D = ∂(Φ c)/∂x`` on ``rows`` for coefficients ``c`` (n_cols,), (rows, n_x).

        Its columns in the order of :attr:`group`.
        """
        P = Psi[rows]
        D = np.empty((P.shape[0], self.n_x), dtype=complex)
        q = self.is_pair
        n2, nr = int(q.sum()), int((~q).sum())
        cg = c[self.group_u]
        if n2:
            c1, c2, Tp = cg[:n2], cg[n2 : 2 * n2], T[q]
            P1, P2 = P[:, :n2], P[:, n2 : 2 * n2]
            a = P1 * c1 + P2 * c2  # ∂/∂Re p
            b = P2 * c1 - P1 * c2  # ∂/∂Im p
            D[:, :n2] = a * Tp[:, 0, 0] + b * Tp[:, 1, 0]
            D[:, n2 : 2 * n2] = a * Tp[:, 0, 1] + b * Tp[:, 1, 1]
        if nr:
            D[:, 2 * n2 : 2 * n2 + nr] = P[:, 2 * n2 :] * (cg[2 * n2 :] * T[~q, 0, 0])
        if Dt is not None:
            D[:, -1] = Dt[rows] @ c
        return D

    def normal(self, pt: _Point) -> tuple[FloatArray, FloatArray]:
        """``(JᵀJ, Jᵀr)`` at a point (Kaufman's Jacobian of the projected residual)."""
        prob = self.prob
        K, E = prob.P.shape
        Psi, Dt, T = self.derivative(pt)
        W, Phi, nc = prob.W, pt.Phi, pt.Phi.shape[1]
        g_e = np.zeros((E, self.n_x))  # each entry's part of Jᵀr (one thread per entry)

        def build(r: slice, e: int) -> ComplexArray:
            w = W[r, e, None]
            X = np.empty((w.shape[0], nc + self.n_x), dtype=complex)
            np.multiply(w, Phi[r], out=X[:, :nc])
            D = np.multiply(w, self.columns_d(Psi, Dt, T, pt.coef[:, e], r), out=X[:, nc:])
            g_e[e] -= 2.0 * (pt.res[r, e] @ D.conj()).real
            return X

        G = gram(build, K, E, nc + self.n_x, prob.workers)
        AD = G[:, :nc, nc:]
        Y, _ = solve(G[:, :nc, :nc], AD)
        Hg = 2.0 * np.sum(G[:, nc:, nc:] - np.swapaxes(AD, 1, 2) @ Y, axis=0)
        lam, V = np.linalg.eigh(0.5 * (Hg + Hg.T))  # a Gram: what rounding made negative is 0
        back = np.argsort(self.group)  # grouped order to x's
        H = ((V * np.maximum(lam, 0.0)) @ V.T)[np.ix_(back, back)]
        return H, g_e.sum(axis=0)[back]


def _levenberg_marquardt(
    f: _Projected, x0: FloatArray, lo: FloatArray, hi: FloatArray, max_nfev: int
) -> FloatArray:
    """Minimise ``‖r(x)‖²`` within the box [lo, hi] (Marquardt's scaling, Nielsen's damping).

    Stops when a step lowers ``‖r‖² = 2V`` by less than :data:`F_TOL` (the parameters are
    then within about a tenth of their std of the minimum, whatever the number of
    bins), the step is below 1e-9 of x, the scaled gradient is below 1e-10, or after
    ``max_nfev`` evaluations.
    """
    pt = f.point(x0)
    nfev = 1
    H, g = f.normal(pt)
    mu, nu = 1e-3, 2.0
    while nfev < max_nfev:
        d = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        if np.max(np.abs(g) / np.sqrt(d * max(pt.f, 1e-300))) < 1e-10:
            break
        step, _ = solve(H + mu * np.diag(d), -g)
        if not np.all(np.isfinite(step)):
            mu, nu = mu * nu, nu * 2.0
            if mu > 1e16:
                break
            continue
        x = np.clip(pt.x + step, lo, hi)
        s = x - pt.x
        pred = -(2.0 * g @ s + s @ H @ s)
        new = f.point(x)
        nfev += 1
        gain = float((pt.f - new.f) / pred) if pred > 0 else -1.0
        if gain > 1e-4:
            small = pt.f - new.f < max(F_TOL, 1e-12 * pt.f) or np.linalg.norm(s) < 1e-9 * (
                np.linalg.norm(pt.x) + 1e-9
            )
            pt = new
            if small:
                break
            H, g = f.normal(pt)
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
            nu = 2.0
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e16:
                break
    return pt.x


def refine(
    prob: Problem,
    poles: ComplexArray,
    delay: float,
    *,
    free_delay: bool,
    max_delay: float,
    max_nfev: int = 100,
) -> tuple[ComplexArray, float]:
    """Poles (and the delay when ``free_delay``) at the minimum of the projected cost."""
    pair = [bool(p.imag > 0) for p in poles]
    u0 = to_params(poles, prob.domain, prob.h, prob.w_ref)
    x0 = np.concatenate([u0, [delay / prob.h]]) if free_delay else u0
    if x0.size == 0:
        return poles, delay
    lo = np.full(x0.size, -np.inf)
    hi = np.full(x0.size, np.inf)
    if free_delay:
        lo[-1], hi[-1] = 0.0, max(max_delay / prob.h, 1e-9)
        x0[-1] = np.clip(x0[-1], lo[-1], hi[-1])
    f = _Projected(prob, pair, None if free_delay else delay)
    return f.unpack(_levenberg_marquardt(f, x0, lo, hi, max_nfev))


def _toeplitz(F: FloatArray, kernel: FloatArray) -> FloatArray:
    """``T F`` along the bins, ``T_{k,k+l} = ρ(|l|)`` (zero past the ends)."""
    out = float(kernel[0]) * F
    for lag in range(1, min(len(kernel), F.shape[0])):
        out[:-lag] += float(kernel[lag]) * F[lag:]
        out[lag:] += float(kernel[lag]) * F[:-lag]
    return out


def covariance(
    prob: Problem,
    poles: ComplexArray,
    delay: float,
    *,
    free_delay: bool,
    kernel: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(x, cov, coef)``: the full parameter vector, its covariance, the coefficients.

    ``kernel``: the correlation ``ρ(l)``, l = 0, 1, ..., of the errors of bins l apart (the
    LPM's windows overlap); the covariance is then the sandwich ``M⁻¹ B M⁻¹``,
    ``M = JᵀJ``, ``B = Σ_l ρ(l) Σ_k J_kᵀ J_{k+l}`` (both signs of l).

    ``x`` = [pole parameters (:func:`~mr_ident.numerics.fit.basis.to_params`), delay in s
    (when free), coefficients entry-major (E, n_cols) flattened].
    """
    pair = [bool(p.imag > 0) for p in poles]
    u = to_params(poles, prob.domain, prob.h, prob.w_ref)
    x = np.concatenate([u, [delay] if free_delay else []])
    f = _Projected(prob, pair, None if free_delay else delay)
    xf = np.concatenate([u, [delay / prob.h]]) if free_delay else u
    pt = _Point(prob, xf, poles, delay)
    Psi, Dt, T = f.derivative(pt)
    if Dt is not None:
        Dt = Dt / prob.h  # the delay in s
    K, E = prob.P.shape
    nu, nc = x.size, pt.Phi.shape[1]
    W, Phi = prob.W, pt.Phi

    def build(r: slice, e: int) -> ComplexArray:
        F = np.hstack([f.columns_d(Psi, Dt, T, pt.coef[:, e], r), Phi[r]])
        return np.asarray(W[r, e, None] * F, dtype=complex)

    m = nu + nc
    blocks = 2.0 * gram(build, K, E, m, prob.workers)
    n = nu + E * nc
    M = np.zeros((n, n))
    B = None if kernel is None or len(kernel) <= 1 else np.zeros((n, n))
    for e in range(E):
        idx = np.concatenate([f.group, nu + e * nc + np.arange(nc)])
        M[np.ix_(idx, idx)] += blocks[e]
        if B is not None and kernel is not None:  # the whole entry at once: T couples bins
            F = build(slice(0, K), e)
            Fr, Fi = np.ascontiguousarray(F.real), np.ascontiguousarray(F.imag)
            Be = Fr.T @ _toeplitz(Fr, kernel) + Fi.T @ _toeplitz(Fi, kernel)
            B[np.ix_(idx, idx)] += Be + Be.T  # 2 FᵀTF (the √2 of r, squared), symmetric
    scale = np.sqrt(np.maximum(np.diag(M), 0.0))
    scale[scale == 0] = 1.0
    Mi = np.linalg.pinv(M / np.outer(scale, scale))
    if B is not None:
        Mi = Mi @ (B / np.outer(scale, scale)) @ Mi
    cov = Mi / np.outer(scale, scale)
    return np.concatenate([x, pt.coef.T.ravel()]), cov, pt.coef
