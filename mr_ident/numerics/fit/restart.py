# SPDX-License-Identifier: Apache-2.0
"""Leaving a local minimum: the weakest pair moved to where the residual is largest.

A minimum whose cost lies above its band has, in the fits measured, placed two poles on
one feature (a spurious near-double pole) or split a pair into two real poles that fit
nothing in particular, while a close pair of modes elsewhere is fitted by one: the
residual in σ units then stands out around the missed mode. A restart takes the pair the
cost needs least, a complex pair or two of the real poles (the least increase of V when
their columns are dropped and the other residues solved again: ``cᵀ ((G⁻¹)_JJ)⁻¹ c`` per
entry from the Gram G of the weighted columns), puts one pair in its place where the
residual's excess over its expectation is most significant on any of a few widths, and
refines; the result is kept when its cost is lower. (With complex pairs alone, two real
poles left by the start were never moved: of bench-fit's 200 drawn 3x3 fits, 10 ended in
a local minimum, 5 of them above the band, and 2 with two real poles movable.)

Up to :data:`RESTARTS` times, while the cost lies above its band; when the caller
gives a ``gain`` (:func:`escape`: problems without a coarse stage) inside the band too,
kept there only when V drops by more than that gain.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .basis import columns
from .normal import weighted_gram
from .refine import F_TOL, Problem, Solution, refine

#: Most restarts per order, and the most evaluations of each one's refinement.
RESTARTS = 3
RESTART_NFEV = 40

#: Half-widths (bins) over which the residual's excess is summed.
WIDTHS = (0, 1, 3, 9, 27)


def weakest(prob: Problem, sol: Solution) -> tuple[int, ...] | None:
    """Indices (into ``sol.poles``) of the pair whose removal raises V least, or None.

    A pair: one complex pole (its conjugate implied) or two real poles (the order a pair
    takes when it is moved). None when there is neither.
    """
    poles = sol.poles
    pair = poles.imag > 0
    real = [int(k) for k in np.flatnonzero(~pair)]
    groups = [(int(k),) for k in np.flatnonzero(pair)] + list(itertools.combinations(real, 2))
    if not groups:
        return None
    Phi = columns(poles, prob.z, prob.domain, prob.h, sol.delay, direct=prob.direct)
    G = weighted_gram(Phi, prob.W, workers=prob.workers)
    d = np.sqrt(np.maximum(np.diagonal(G, axis1=1, axis2=2), 1e-300))
    Gi = np.linalg.pinv(G / d[:, :, None] / d[:, None, :], rcond=1e-14, hermitian=True)
    Gi = Gi / d[:, :, None] / d[:, None, :]
    width = np.where(pair, 2, 1)
    first = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(int)
    best, best_g = np.inf, None
    for g in groups:
        J = [first[g[0]], first[g[0]] + 1] if len(g) == 1 else [first[g[0]], first[g[1]]]
        c = sol.coef[J].T[:, :, None]  # (E, 2, 1)
        block = Gi[:, J][:, :, J]
        rise = float(np.sum(np.swapaxes(c, 1, 2) @ np.linalg.pinv(block) @ c))
        if rise < best:
            best, best_g = rise, g
    return best_g


def excess_peak(f: FloatArray, residual: ComplexArray) -> tuple[float, float, float]:
    """Frequency (Hz), relative width (a damping) and z-score of the most significant excess.

    Per bin the excess ``Σ_e |r_e|² - E`` (mean 0, variance E for unit-variance
    residuals), summed over 2L+1 bins for each half-width L of :data:`WIDTHS`; the
    largest sum in units of its std names the bin and the width.
    """
    K, E = residual.shape
    ex = np.sum(residual.real**2 + residual.imag**2, axis=1) - E
    c = np.concatenate([[0.0], np.cumsum(ex)])
    best, at, half = -np.inf, 0, 0
    for L in WIDTHS:
        n = 2 * L + 1
        if n > K:
            break
        z = (c[n:] - c[:-n]) / np.sqrt(E * n)
        i = int(np.argmax(z))
        if z[i] > best:
            best, at, half = float(z[i]), i + L, L
    lo, hi = f[max(at - half - 1, 0)], f[min(at + half + 1, K - 1)]
    return float(f[at]), float(np.clip((hi - lo) / (2.0 * f[at]), 0.002, 0.5)), best


def moved(prob: Problem, f: FloatArray, sol: Solution) -> ComplexArray | None:
    """The poles with the weakest pair moved to the residual's excess (None: no pair).

    Two real poles moved become one complex pair (the same order).
    """
    g = weakest(prob, sol)
    if g is None:
        return None
    f0, zeta, _ = excess_peak(f, sol.residual)
    w = 2.0 * np.pi * f0
    s = complex(-zeta * w, w * np.sqrt(1.0 - zeta * zeta))
    poles = sol.poles.copy()
    poles[g[0]] = s if prob.domain == "continuous" else np.exp(s * prob.h)
    out: ComplexArray = np.delete(poles, g[1:])
    return out


def escape(
    prob: Problem,
    f: FloatArray,
    sol: Solution,
    bound: float,
    *,
    free_delay: bool,
    max_delay: float,
    gain: float = np.inf,
) -> Solution:
    """``sol`` or a restart's lower minimum (module docstring); ``bound``: the band's top.

    Inside the band a restart is made too when ``gain`` is finite, and kept only when it
    lowers V by more than ``gain`` (moving the weakest pair onto the noise gains a little).
    """
    for _ in range(RESTARTS):
        inside = sol.cost <= bound
        if inside and not np.isfinite(gain):
            break
        poles = moved(prob, f, sol)
        if poles is None:
            break
        new = refine(
            prob,
            poles,
            sol.delay,
            free_delay=free_delay,
            max_delay=max_delay,
            max_nfev=RESTART_NFEV,
        )
        if not new.cost < sol.cost - (gain if inside else 0.5 * F_TOL):  # F_TOL is of 2V
            break
        sol = new
    return sol
