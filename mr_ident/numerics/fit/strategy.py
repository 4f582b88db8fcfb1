# SPDX-License-Identifier: Apache-2.0
"""One order's fit: two vector-fitting starts, the delay candidates, the refinement, restarts.

Many bins (past :data:`COARSE_BINS`) are fitted coarse to fine: the starts, their
refinement and the restarts run on a subset of the bins (:func:`coarse_rows`: the same
cost on fewer bins, every d-th and those of the narrow resonances; the poles of a plant do
not need 1e5 bins to be placed); only the last refinement runs on all bins, from the
coarse solution. A problem of at most :data:`COARSE_BINS` bins is fitted on all of them
throughout.

The start weighted by 1/σ (vector fitting) is refined and restarts (:mod:`.restart`: the
weakest pair moved to where the residual is largest, refined) leave a minimum above the
cost's band, kept at any decrease of V. Then the second start (weighted by 1/|P̂|) is
made, and refined unless its cost exceeds :data:`SECOND_START` times the first's; the
lower minimum is kept. With a coarse stage the second start is made only when the first
one's minimum still lies above the band. A problem without a coarse stage is cheap: there
the second start is always made, and restarts run inside the band too, kept when they
lower V by more than :data:`IN_BAND_GAIN` sd{V} (a minimum inside the band can still be a
local one; kept at any decrease, the weakest pair moved onto the noise in some fits: the
counts are in docs/benchmarks.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..arrays import ComplexArray, FloatArray, IndexArray
from .basis import initial_poles
from .refine import Problem, Solution, cost, refine
from .restart import escape
from .start import relocate

#: Bins of the coarse stage: at most this many (every d-th bin of a larger problem).
COARSE_BINS = 8192

#: Most relocations per start (vector fitting stops earlier once its cost settles: no
#: decrease beyond a tenth of sd{V} in fifteen relocations), and the few that tell delay
#: candidates apart.
RELOCATIONS = 60
PROBE = 5

#: The second start is refined only when its cost is within this factor of the first's.
SECOND_START = 4.0

#: Inside the band (problems without a coarse stage), the least decrease of V, in units
#: of sd{V} (the band's, the bins' correlation included), for which a restart is kept.
IN_BAND_GAIN = 0.25


def continuous_poles(lam: ComplexArray, fs: float) -> ComplexArray:
    """Discrete poles as continuous ones (a negative real λ stays a real pole)."""
    lam = np.where(np.abs(lam) < 1e-9, 1e-9, lam)
    out = np.log(lam.astype(complex)) * fs
    real = lam.imag == 0
    out[real] = np.log(np.abs(lam[real])) * fs
    return np.asarray(out, dtype=complex)


def domain_poles(lam: ComplexArray, domain: str, fs: float) -> ComplexArray:
    """Discrete poles in the fit's domain, sorted by magnitude."""
    poles = lam if domain == "discrete" else continuous_poles(lam, fs)
    return np.asarray(poles[np.argsort(np.abs(poles))], dtype=complex)


def coarse_rows(prob: Problem) -> IndexArray | None:
    """The bins of the coarse stage (None: all bins, at most :data:`COARSE_BINS`).

    Half of them every d-th bin; the other half where the response changes fastest in σ
    units, ``Σ_e |P̂_e(k+1) - P̂_e(k-1)|² / σ_e(k)²`` (the narrow resonances: a mode
    narrower than d bins would otherwise be seen on a bin or two, and its poles placed
    on the coarse bins would be far from their minimum on all of them).
    """
    K = prob.P.shape[0]
    if K <= COARSE_BINS:
        return None
    keep = np.zeros(K, dtype=bool)
    keep[:: math.ceil(2 * K / COARSE_BINS)] = True
    speed = np.full(K, -1.0)
    dP = (prob.P[2:] - prob.P[:-2]) * prob.W[1:-1]
    speed[1:-1] = np.sum(dP.real**2 + dP.imag**2, axis=1)
    speed[keep] = -1.0
    more = COARSE_BINS - int(keep.sum())
    keep[np.argpartition(-speed, more)[:more]] = True
    out: IndexArray = np.flatnonzero(keep)
    return out


def _subset(prob: Problem, f: FloatArray) -> tuple[Problem, FloatArray]:
    rows = coarse_rows(prob)
    if rows is None:
        return prob, f
    return replace(prob, z=prob.z[rows], P=prob.P[rows], W=prob.W[rows]), f[rows]


def _start(
    prob: Problem,
    f: FloatArray,
    W: FloatArray,
    order: int,
    fs: float,
    *,
    delays: list[float],
    sd: float,
) -> tuple[float, ComplexArray, float, float]:
    """Vector fitting weighted by ``W``: ``(V, poles, delay, condition number)``.

    Each delay candidate by a few relocations, the best one relocated until its cost
    settles (no decrease beyond a tenth of ``sd``, sd{V}, in :data:`~.start.PATIENCE` of them).
    """
    h = 1.0 / fs
    tol = 0.1 * sd
    best: tuple[float, ComplexArray, float] | None = None
    cond = 1.0
    for tau in delays:
        H = prob.P * np.exp(2j * np.pi * f * tau)[:, None]
        spacing = 2.0 * (f[-1] - f[0]) / f.size  # two bins (of the mean spacing)
        start = initial_poles(order, f[0], f[-1], "discrete", h, spacing)
        probe = len(delays) > 1
        lam, v, kappa = relocate(
            prob.z,
            H,
            W,
            start,
            iterations=PROBE if probe else RELOCATIONS,
            workers=prob.workers,
            judge=_judge(prob, fs, tau),
            tol=0.0 if probe else tol,
        )
        cond = max(cond, kappa)
        if best is None or v < best[0]:
            best = (v, lam, tau)
    assert best is not None
    v, lam, tau = best
    if len(delays) > 1:
        H = prob.P * np.exp(2j * np.pi * f * tau)[:, None]
        lam, v, kappa = relocate(
            prob.z,
            H,
            W,
            lam,
            iterations=RELOCATIONS,
            workers=prob.workers,
            judge=_judge(prob, fs, tau),
            tol=tol,
        )
        cond = max(cond, kappa)
    return v, domain_poles(lam, prob.domain, fs), tau, cond


def _judge(prob: Problem, fs: float, tau: float) -> Callable[[ComplexArray], float]:
    return lambda lam: cost(prob, domain_poles(lam, prob.domain, fs), tau)


def fit_order(
    prob: Problem,
    f: FloatArray,
    order: int,
    fs: float,
    *,
    delays: list[float],
    free_delay: bool,
    max_delay: float,
    bound: Callable[[int], tuple[float, float]],
) -> tuple[Solution, float]:
    """One order's solution on all bins and the largest condition number of its start.

    Vector fitting weighted by 1/σ (the cost's own weights) and by 1/|P̂| (relative: where
    σ peaks at a resonance, the 1/σ start can miss the resonance, measured on the motor
    bench); per start the delay candidates told apart by five relocations, the best one
    relocated further. ``bound(N)``: the cost's band ``(E{V}, sd{V})`` for N complex
    terms (sd{V} with the bins' correlation length: the relocations' stopping tolerance
    and the restarts' least gain are in its units). Coarse to fine past
    :data:`COARSE_BINS` bins (module docstring).
    """
    coarse, fc = _subset(prob, f)
    rel = 1.0 / np.maximum(np.abs(coarse.P), 1e-300 + np.abs(coarse.P).max() * 1e-12)
    small = coarse is prob  # cheap: both starts, and restarts inside the band too
    e, sd = bound(coarse.P.size)
    top = e + 2.0 * sd
    gain = IN_BAND_GAIN * sd if small else np.inf
    sol: Solution | None = None
    first, cond = np.inf, 1.0
    for W in (coarse.W, rel):
        v, poles, tau, kappa = _start(coarse, fc, W, order, fs, delays=delays, sd=sd)
        cond = max(cond, kappa)
        first = min(first, v)
        if sol is not None and v > SECOND_START * first:
            continue
        new = refine(coarse, poles, tau, free_delay=free_delay, max_delay=max_delay)
        new = escape(coarse, fc, new, top, free_delay=free_delay, max_delay=max_delay, gain=gain)
        sol = new if sol is None or new.cost < sol.cost else sol
        if sol.cost <= top and not small:
            break
    assert sol is not None
    if coarse is not prob:
        sol = refine(prob, sol.poles, sol.delay, free_delay=free_delay, max_delay=max_delay)
    return sol, cond
