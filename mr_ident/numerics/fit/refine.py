# SPDX-License-Identifier: Apache-2.0
"""Variable projection: the poles (and delay) by Levenberg–Marquardt, residues solved linearly.

The cost ``V = Σ_k Σ_e |P̂_e(k) - G_e(k, θ)|² / σ_e(k)²`` is, for fixed poles and delay,
a weighted linear least-squares problem in the residues (one per entry, all sharing the
columns of :func:`~mr_ident.numerics.fit.basis.columns`); its solution put back leaves a
function of the poles alone (Golub & Pereyra 1973), minimised by a trust-region
Levenberg–Marquardt (``scipy.optimize.least_squares``) over the stable parametrisation.
The covariance of every parameter is that of the full problem at the minimum,
``(JᵀJ)⁻¹`` of the residual in units of its std (real and imaginary parts each of
variance σ²/2 for the LPM's circular errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .basis import columns, from_params, to_params


@dataclass(frozen=True)
class Problem:
    """The data of one fit: bins ``z`` (K,), responses ``P`` (K, E), weights ``W = 1/σ``."""

    z: ComplexArray
    P: ComplexArray
    W: FloatArray
    domain: str
    h: float
    w_ref: float
    direct: bool


def solve_linear(
    prob: Problem, poles: ComplexArray, delay: float
) -> tuple[FloatArray, ComplexArray]:
    """Coefficients (n_cols, E) and weighted residuals ``W (P - Φ c)`` (K, E)."""
    Phi = columns(poles, prob.z, prob.domain, prob.h, delay, direct=prob.direct)
    E = prob.P.shape[1]
    coef = np.zeros((Phi.shape[1], E))
    res = np.empty(prob.P.shape, dtype=complex)
    for e in range(E):
        w = prob.W[:, e]
        A = w[:, None] * Phi
        Ar = np.vstack([A.real, A.imag])
        y = w * prob.P[:, e]
        scale = np.linalg.norm(Ar, axis=0)
        scale[scale == 0] = 1.0
        c, *_ = np.linalg.lstsq(Ar / scale, np.concatenate([y.real, y.imag]), rcond=None)
        coef[:, e] = c / scale
        res[:, e] = y - A @ coef[:, e]
    return coef, res


def cost(prob: Problem, poles: ComplexArray, delay: float) -> float:
    """``V`` with the residues solved."""
    return float(np.sum(np.abs(solve_linear(prob, poles, delay)[1]) ** 2))


def _stack(res: ComplexArray) -> FloatArray:
    """Weighted complex residuals as unit-variance reals: ``√2 [Re; Im]``."""
    r = res.ravel()
    return np.asarray(np.sqrt(2.0) * np.concatenate([r.real, r.imag]), dtype=float)


class _Projected:
    """The projected residual of parameters x and its Jacobian (Kaufman's form).

    ``x`` = [pole parameters, delay / h (when free)]. Per entry a QR of the weighted
    columns gives the residues and the projector ``P⊥ = I - Q Qᵀ``; the Jacobian column of
    a parameter is ``-√2 P⊥ (∂A/∂x_j) c`` (the term through ∂c dropped: Kaufman 1975), the
    derivative of a pole's own columns taken by central differences (cheap: one pole).
    """

    def __init__(self, prob: Problem, pair: list[bool], n_u: int, delay: float | None) -> None:
        self.prob, self.pair, self.n_u, self.delay = prob, pair, n_u, delay
        self._x: FloatArray | None = None
        self._r = np.zeros(0)
        self._state: tuple[list[FloatArray], FloatArray, ComplexArray, float] | None = None
        widths = [2 if q else 1 for q in pair]  # parameters and columns per pole
        self.offsets = np.concatenate([[0], np.cumsum(widths)]).astype(int)

    def unpack(self, x: FloatArray) -> tuple[ComplexArray, float]:
        """Poles and delay of x."""
        prob = self.prob
        u = np.clip(x[: self.n_u], -40.0, 40.0)
        tau = self.delay if self.delay is not None else float(x[-1]) * prob.h
        return from_params(u, self.pair, prob.domain, prob.h, prob.w_ref), tau

    def _solve(self, x: FloatArray) -> None:
        if self._x is not None and np.array_equal(x, self._x):
            return
        prob = self.prob
        poles, tau = self.unpack(x)
        Phi = columns(poles, prob.z, prob.domain, prob.h, tau, direct=prob.direct)
        E = prob.P.shape[1]
        Qs, coef = [], np.zeros((Phi.shape[1], E))
        res = np.empty(prob.P.shape, dtype=complex)
        for e in range(E):
            w = prob.W[:, e]
            A = w[:, None] * Phi
            Ar = np.vstack([A.real, A.imag])
            scale = np.linalg.norm(Ar, axis=0)
            scale[scale == 0] = 1.0
            Q, R = np.linalg.qr(Ar / scale)
            y = w * prob.P[:, e]
            yr = np.concatenate([y.real, y.imag])
            c = np.linalg.lstsq(R, Q.T @ yr, rcond=None)[0] / scale
            coef[:, e] = c
            res[:, e] = y - A @ c
            Qs.append(Q)
        self._x, self._r = x.copy(), _stack(res)
        self._state = (Qs, coef, Phi, tau)

    def fun(self, x: FloatArray) -> FloatArray:
        """The projected residual (unit-variance reals)."""
        self._solve(x)
        return self._r

    def jac(self, x: FloatArray) -> FloatArray:
        """Its Jacobian, (2 K E, x.size)."""
        self._solve(x)
        assert self._state is not None
        Qs, coef, Phi, tau = self._state
        prob = self.prob
        K, E = prob.P.shape
        u = np.clip(x[: self.n_u], -40.0, 40.0)
        dA: list[tuple[int, ComplexArray, slice]] = []  # (parameter, d columns, which columns)
        for k in range(len(self.pair)):
            sl = slice(int(self.offsets[k]), int(self.offsets[k + 1]))
            for j in range(sl.start, sl.stop):
                step = 1e-6 * max(abs(u[j]), 1.0)
                cols = []
                for sgn in (1.0, -1.0):
                    uu = u[sl].copy()
                    uu[j - sl.start] += sgn * step
                    p = from_params(uu, [self.pair[k]], prob.domain, prob.h, prob.w_ref)
                    cols.append(columns(p, prob.z, prob.domain, prob.h, tau))
                dA.append((j, (cols[0] - cols[1]) / (2 * step), sl))
        if self.delay is None:
            st = 1e-4
            poles, _ = self.unpack(x)
            hi = columns(poles, prob.z, prob.domain, prob.h, tau + st * prob.h, direct=prob.direct)
            lo = columns(
                poles, prob.z, prob.domain, prob.h, max(tau - st * prob.h, 0.0), direct=prob.direct
            )
            span = (tau + st * prob.h - max(tau - st * prob.h, 0.0)) / prob.h  # x is τ / h
            dA.append((x.size - 1, (hi - lo) / span, slice(0, Phi.shape[1])))
        J = np.zeros((2 * K * E, x.size))
        for e in range(E):
            D = np.zeros((2 * K, x.size))
            w = prob.W[:, e]
            for j, dcols, sl in dA:
                d = w * (dcols @ coef[sl, e])
                D[:, j] = np.concatenate([d.real, d.imag])
            D -= Qs[e] @ (Qs[e].T @ D)
            J[e : K * E : E] = -np.sqrt(2.0) * D[:K]
            J[K * E + e :: E] = -np.sqrt(2.0) * D[K:]
        return J


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
    import scipy.optimize  # noqa: PLC0415 (the fit alone needs it)

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
    f = _Projected(prob, pair, u0.size, None if free_delay else delay)
    sol = scipy.optimize.least_squares(
        f.fun, x0, jac=f.jac, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev
    )
    return f.unpack(sol.x)


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
    coef, _ = solve_linear(prob, poles, delay)
    E = prob.P.shape[1]
    nu = u.size + (1 if free_delay else 0)

    def resid(x: FloatArray) -> FloatArray:
        p = from_params(x[: u.size], pair, prob.domain, prob.h, prob.w_ref)
        tau = float(x[u.size]) if free_delay else delay
        Phi = columns(p, prob.z, prob.domain, prob.h, tau, direct=prob.direct)
        return _stack(prob.W * (prob.P - Phi @ coef))

    x = np.concatenate([u, [delay] if free_delay else []])
    r0 = resid(x)
    Ju = np.empty((r0.size, nu))
    for j in range(nu):
        step = 1e-6 * max(abs(x[j]), 1.0) if j < u.size else 1e-4 * prob.h
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        Ju[:, j] = (resid(xp) - resid(xm)) / (2 * step)
    Phi = columns(poles, prob.z, prob.domain, prob.h, delay, direct=prob.direct)
    K, nc = Phi.shape
    Jc = np.zeros((2 * K * E, E * nc))
    for e in range(E):
        A = -np.sqrt(2.0) * prob.W[:, e, None] * Phi
        rows = np.arange(K) * E + e  # ravel order of (K, E)
        Jc[rows, e * nc : (e + 1) * nc] = A.real
        Jc[K * E + rows, e * nc : (e + 1) * nc] = A.imag
    J = np.hstack([Ju, Jc])
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    Mi = np.linalg.pinv(Js.T @ Js)
    if kernel is not None and len(kernel) > 1:
        parts = Js.reshape(2, K, E, -1)
        B = Js.T @ Js * float(kernel[0])
        for lag in range(1, min(len(kernel), K)):
            C = np.einsum("akep,akeq->pq", parts[:, :-lag], parts[:, lag:])
            B += float(kernel[lag]) * (C + C.T)
        Mi = Mi @ B @ Mi
    cov = Mi / np.outer(scale, scale)
    return np.concatenate([x, coef.T.ravel()]), cov, coef
