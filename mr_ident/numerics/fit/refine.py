# SPDX-License-Identifier: Apache-2.0
"""Variable projection: the poles (and delay) by Levenberg–Marquardt, residues solved linearly.

The cost ``V = Σ_k Σ_e |P̂_e(k) - G_e(k, θ)|² / σ_e(k)²`` is, for fixed poles and delay,
a weighted linear least-squares problem in the residues (one per entry, all sharing the
columns of :func:`~mr_ident.numerics.fit.basis.columns`); its solution put back leaves a
function of the poles alone (Golub & Pereyra 1973), minimised by Levenberg–Marquardt over
the stable parametrisation. Nothing of the size bins x parameters is factorised: every
product the method needs is a Gram matrix summed over blocks of bins (:mod:`.normal`).
Every entry's Jacobian is the same pole derivatives Ψ mixed by its own coefficients
(``Dₑ = Ψ Mₑ``), so one step is one weighted Gram of the common ``[Φ, Ψ]`` per entry
(``make bench-fit`` times the whole fit at 1e5 bins, 3 x 3, order 40). The Jacobian is
Kaufman's (1975), ``J = -√2 P⊥ D`` with ``D = ∂(Φ c)/∂x`` from the exact pole derivatives of
the columns (:func:`~.basis.pole_derivatives`); its normal matrix
``JᵀJ = 2 (DᵀD - DᵀA (AᵀA)⁻¹ AᵀD)`` and the gradient ``Jᵀr = -2 Re(Dᴴ r)`` (exact: the
dropped term is orthogonal to r). The covariance of every parameter is that of the full
problem at the minimum, ``(JᵀJ)⁻¹`` of the residual in units of its std (real and
imaginary parts each of variance σ²/2 for the LPM's circular errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arrays import ComplexArray, FloatArray, IndexArray
from .basis import columns, delay_derivatives, from_params, pole_derivatives, to_params
from .normal import real_product, solve, times_real, weighted_gram

#: Least decrease of ``‖r‖² = 2V`` that continues Levenberg–Marquardt.
F_TOL = 0.02

#: Most refinement steps of a linear solve (stopped once the correction is at rounding).
REFINEMENTS = 4
EPS = float(np.finfo(float).eps)


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


def _coefficients(
    prob: Problem, Phi: ComplexArray, G: FloatArray | None = None
) -> tuple[FloatArray, ComplexArray, float]:
    """Coefficients (n_cols, E), weighted residuals (K, E), condition number (columns).

    ``G``: the Gram of the weighted columns per entry when already at hand.
    """
    K, E = prob.P.shape
    W = prob.W
    if G is None:
        G = weighted_gram(Phi, W, workers=prob.workers)
    coef, kappa = solve(G, real_product(Phi, W * W * prob.P).T)
    res = W * (prob.P - times_real(Phi, coef.T))
    # on the residual: each step gains -log10(κ² eps) digits; none needed when the normal
    # equations' own error, κ² eps relative, is already below 1e-12
    for _ in range(REFINEMENTS if kappa * kappa * EPS > 1e-12 else 0):
        fix, _ = solve(G, real_product(Phi, W * res).T)
        coef = coef + fix
        res = W * (prob.P - times_real(Phi, coef.T))
        if np.max(np.abs(fix)) <= 1e-14 * np.max(np.abs(coef)):
            break
    return coef.T, res, kappa


@dataclass(frozen=True)
class Solution:
    """Poles and delay with what the linear step gives there.

    ``cost``: V; ``condition``: the condition number of the residues' weighted columns
    (scaled to unit norm, the largest over the entries); ``coef`` (n_cols, E); ``residual``
    ``W (P - Φ c)`` (K, E); ``blocks``: the Gram of ``wₑ [Φ, Dₑ]`` per entry
    (:meth:`_Projected.blocks`, the delay per sample) when the refinement formed it there.
    """

    poles: ComplexArray
    delay: float
    cost: float
    condition: float
    coef: FloatArray
    residual: ComplexArray
    blocks: FloatArray | None = None


def solution(prob: Problem, poles: ComplexArray, delay: float) -> Solution:
    """The residues solved at fixed poles and delay."""
    Phi = columns(poles, prob.z, prob.domain, prob.h, delay, direct=prob.direct)
    coef, res, kappa = _coefficients(prob, Phi)
    v = float(np.sum(res.real**2 + res.imag**2))
    return Solution(np.asarray(poles, dtype=complex), float(delay), v, kappa, coef, res)


def cost(prob: Problem, poles: ComplexArray, delay: float) -> float:
    """``V`` with the residues solved."""
    return solution(prob, poles, delay).cost


class _Point:
    """One evaluation: poles, delay, columns, coefficients, residuals, cost 2V."""

    def __init__(
        self,
        prob: Problem,
        x: FloatArray,
        poles: ComplexArray,
        tau: float,
        known: Solution | None = None,
    ) -> None:
        self.x, self.poles, self.tau = x, poles, tau
        self.Phi = columns(poles, prob.z, prob.domain, prob.h, tau, direct=prob.direct)
        if known is not None:  # the linear step at these poles, solved before
            self.coef, self.res, self.kappa = known.coef, known.residual, known.condition
        else:
            self.coef, self.res, self.kappa = _coefficients(prob, self.Phi)
        self.blocks: FloatArray | None = None if known is None else known.blocks
        self.f = 2.0 * float(np.sum(self.res.real**2 + self.res.imag**2))

    def solution(self) -> Solution:
        """What the linear step gave at this point."""
        return Solution(
            self.poles, self.tau, 0.5 * self.f, self.kappa, self.coef, self.res, self.blocks
        )


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

    def mix(self, T: FloatArray, coef: FloatArray) -> FloatArray:
        """``M`` per entry with ``∂(Φ cₑ)/∂u = Ψ Mₑ`` (E, n_poles_cols, n_u), grouped order.

        A pair's ``∂/∂Re p = ψ1 c1 + ψ2 c2``, ``∂/∂Im p = ψ2 c1 - ψ1 c2`` (the columns of
        :func:`~.basis.pole_derivatives`), then the chain ``T`` to its two parameters; a
        real pole's ``ψ c T``. Every entry's derivative is the same Ψ mixed by its own
        coefficients: the data are passed once for all parameters.
        """
        q = self.is_pair
        n2, nr = int(q.sum()), int((~q).sum())
        cg = coef[self.group_u].T  # (E, n)
        E = cg.shape[0]
        M = np.zeros((E, 2 * n2 + nr, self.n_u))
        i2, ir = np.arange(n2), np.arange(nr)
        if n2:
            c1, c2, Tp = cg[:, :n2], cg[:, n2 : 2 * n2], T[q]
            for k in range(2):  # the pair's parameter k
                M[:, i2, i2 + k * n2] = c1 * Tp[:, 0, k] - c2 * Tp[:, 1, k]
                M[:, n2 + i2, i2 + k * n2] = c2 * Tp[:, 0, k] + c1 * Tp[:, 1, k]
        if nr:
            M[:, 2 * n2 + ir, 2 * n2 + ir] = cg[:, 2 * n2 :] * T[~q, 0, 0]
        return M

    def blocks(self, pt: _Point, delay_scale: float = 1.0) -> tuple[FloatArray, FloatArray]:
        """Per entry the Gram of ``wₑ [Φ, Dₑ]`` (E, nc + n_x, nc + n_x) and ``Re(Dₑᴴ wₑ rₑ)``.

        ``Dₑ = ∂(Φ cₑ)/∂x`` in grouped order (:attr:`group`); the second is (E, n_x).

        One pass over the data: the weighted Gram of the common ``[Φ, Ψ]`` (and of each
        entry's delay column ``Dt cₑ``), mixed afterwards by ``Mₑ`` (:meth:`mix`).
        ``delay_scale`` multiplies the delay's column (1: per sample of h).
        """
        prob = self.prob
        Psi, Dt, T = self.derivative(pt)
        if Dt is not None:
            Dt = Dt * delay_scale
        nc, npc = pt.Phi.shape[1], Psi.shape[1]
        coef = pt.coef
        extra = None if Dt is None else (lambda r, e: Dt[r] @ coef[:, e, None])
        Y = np.hstack([pt.Phi, Psi])
        G = weighted_gram(Y, prob.W, extra, 0 if Dt is None else 1, prob.workers)
        E = G.shape[0]
        n = nc + self.n_x
        B = np.zeros((E, nc + npc + (0 if Dt is None else 1), n))  # [Φ, Ψ, Dt c] -> [Φ, D]
        B[:, np.arange(nc), np.arange(nc)] = 1.0
        B[:, nc : nc + npc, nc : nc + self.n_u] = self.mix(T, coef)
        if Dt is not None:
            B[:, -1, -1] = 1.0
        out = np.swapaxes(B, 1, 2) @ G @ B
        WR = prob.W * pt.res
        gr = real_product(Psi, WR).T[:, None, :] @ B[:, nc : nc + npc, nc : nc + self.n_u]
        grad = gr[:, 0, :]
        if Dt is not None:
            grad = np.column_stack([grad, np.sum(real_product(Dt, WR) * coef, axis=0)])
        return out, grad

    def normal(self, pt: _Point) -> tuple[FloatArray, FloatArray]:
        """``(JᵀJ, Jᵀr)`` at a point (Kaufman's Jacobian of the projected residual)."""
        nc = pt.Phi.shape[1]
        G, grad = self.blocks(pt)
        pt.blocks = G
        AD = G[:, :nc, nc:]
        Y, _ = solve(G[:, :nc, :nc], AD)
        Hg = 2.0 * np.sum(G[:, nc:, nc:] - np.swapaxes(AD, 1, 2) @ Y, axis=0)
        lam, V = np.linalg.eigh(0.5 * (Hg + Hg.T))  # a Gram: what rounding made negative is 0
        back = np.argsort(self.group)  # grouped order to x's
        H = ((V * np.maximum(lam, 0.0)) @ V.T)[np.ix_(back, back)]
        return H, -2.0 * grad.sum(axis=0)[back]

    def columns_d(self, pt: _Point, e: int, delay_scale: float = 1.0) -> ComplexArray:
        """``Dₑ = ∂(Φ cₑ)/∂x`` of entry e on every bin (K, n_x), grouped order."""
        Psi, Dt, T = self.derivative(pt)
        D = times_real(Psi, self.mix(T, pt.coef)[e])
        if Dt is not None:
            D = np.column_stack([D, delay_scale * (Dt @ pt.coef[:, e])])
        return D


def _converged(H: FloatArray, g: FloatArray) -> bool:
    """Whether the Gauss–Newton step would lower ``2V`` by less than :data:`F_TOL`."""
    gn, _ = solve(H, -g)
    return bool(np.all(np.isfinite(gn)) and -(2.0 * g @ gn + gn @ H @ gn) < F_TOL)


def _levenberg_marquardt(
    f: _Projected, x0: FloatArray, lo: FloatArray, hi: FloatArray, max_nfev: int
) -> _Point:
    """Minimise ``‖r(x)‖²`` within the box [lo, hi] (Marquardt's scaling, Nielsen's damping).

    Stops when a step lowers ``‖r‖² = 2V`` by less than :data:`F_TOL`, or the
    Gauss–Newton step at a point predicts less (the parameters are then within about a
    tenth of their std of the minimum, whatever the number of bins), the step is below
    1e-9 of x, the scaled gradient is below 1e-10, or after ``max_nfev`` evaluations.
    """
    pt = f.point(x0)
    nfev = 1
    H, g = f.normal(pt)
    mu, nu = 1e-3, 2.0
    while nfev < max_nfev and not _converged(H, g):
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
    return pt


def refine(
    prob: Problem,
    poles: ComplexArray,
    delay: float,
    *,
    free_delay: bool,
    max_delay: float,
    max_nfev: int = 100,
) -> Solution:
    """Poles (and the delay when ``free_delay``) at the minimum of the projected cost."""
    pair = [bool(p.imag > 0) for p in poles]
    u0 = to_params(poles, prob.domain, prob.h, prob.w_ref)
    x0 = np.concatenate([u0, [delay / prob.h]]) if free_delay else u0
    if x0.size == 0:
        return solution(prob, poles, delay)
    lo = np.full(x0.size, -np.inf)
    hi = np.full(x0.size, np.inf)
    if free_delay:
        lo[-1], hi[-1] = 0.0, max(max_delay / prob.h, 1e-9)
        x0[-1] = np.clip(x0[-1], lo[-1], hi[-1])
    f = _Projected(prob, pair, None if free_delay else delay)
    return _levenberg_marquardt(f, x0, lo, hi, max_nfev).solution()


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
    known: Solution | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(x, cov, coef)``: the full parameter vector, its covariance, the coefficients.

    ``kernel``: the correlation ``ρ(l)``, l = 0, 1, ..., of the errors of bins l apart (the
    LPM's windows overlap); the covariance is then the sandwich ``M⁻¹ B M⁻¹``,
    ``M = JᵀJ``, ``B = Σ_l ρ(l) Σ_k J_kᵀ J_{k+l}`` (both signs of l).

    ``x`` = [pole parameters (:func:`~mr_ident.numerics.fit.basis.to_params`), delay in s
    (when free), coefficients entry-major (E, n_cols) flattened]. ``known``: the linear
    step at these poles and delay, when solved before.
    """
    pair = [bool(p.imag > 0) for p in poles]
    u = to_params(poles, prob.domain, prob.h, prob.w_ref)
    x = np.concatenate([u, [delay] if free_delay else []])
    f = _Projected(prob, pair, None if free_delay else delay)
    xf = np.concatenate([u, [delay / prob.h]]) if free_delay else u
    pt = _Point(prob, xf, poles, delay, known)
    K, E = prob.P.shape
    nu, nc = x.size, pt.Phi.shape[1]
    if pt.blocks is None:
        pt.blocks = f.blocks(pt)[0]
    blocks = 2.0 * pt.blocks
    if free_delay:  # the delay in s
        blocks[:, -1, :] /= prob.h
        blocks[:, :, -1] /= prob.h
    n = nu + E * nc
    M = np.zeros((n, n))
    B = None if kernel is None or len(kernel) <= 1 else np.zeros((n, n))
    for e in range(E):
        idx = np.concatenate([nu + e * nc + np.arange(nc), f.group])
        M[np.ix_(idx, idx)] += blocks[e]
        if B is not None and kernel is not None:  # the whole entry at once: T couples bins
            F = prob.W[:, e, None] * np.hstack([pt.Phi, f.columns_d(pt, e, 1.0 / prob.h)])
            Fr, Fi = np.ascontiguousarray(F.real), np.ascontiguousarray(F.imag)
            Be = Fr.T @ _toeplitz(Fr, kernel) + Fi.T @ _toeplitz(Fi, kernel)
            B[np.ix_(idx, idx)] += 2.0 * Be  # 2 FᵀTF (the √2 of r, squared)
    scale = np.sqrt(np.maximum(np.diag(M), 0.0))
    scale[scale == 0] = 1.0
    Mi = np.linalg.pinv(M / np.outer(scale, scale))
    if B is not None:
        Mi = Mi @ (B / np.outer(scale, scale)) @ Mi
    cov = Mi / np.outer(scale, scale)
    return np.concatenate([x, pt.coef.T.ravel()]), cov, pt.coef
