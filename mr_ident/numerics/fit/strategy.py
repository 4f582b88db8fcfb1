# SPDX-License-Identifier: Apache-2.0
"""One order's fit: two vector-fitting starts, the delay candidates, the refinement.

Many bins (past :data:`COARSE_BINS`) are fitted coarse to fine: the starts and their
refinement run on every d-th bin (the same cost on fewer bins: the poles of a plant do not
need 1e5 bins to be placed), the better start, judged on all bins, is refined on all
bins. A problem of at most :data:`COARSE_BINS` bins is fitted on all of them throughout.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .basis import initial_poles
from .refine import Problem, cost, refine
from .start import relocate

#: Bins of the coarse stage: at most this many (every d-th bin of a larger problem).
COARSE_BINS = 8192

#: Relocations per start (vector fitting stops earlier once its poles settle), and the
#: few that tell delay candidates apart.
RELOCATIONS = 60
PROBE = 5


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


def _subset(prob: Problem, f: FloatArray) -> tuple[Problem, FloatArray]:
    d = math.ceil(f.size / COARSE_BINS)
    if d <= 1:
        return prob, f
    k = slice(0, None, d)
    return replace(prob, z=prob.z[k], P=prob.P[k], W=prob.W[k]), f[k]


def _start(
    prob: Problem,
    f: FloatArray,
    W: FloatArray,
    order: int,
    fs: float,
    delays: list[float],
) -> tuple[ComplexArray, float]:
    """Vector fitting weighted by ``W``.

    Each delay candidate by a few relocations, the best one relocated until its poles
    settle.
    """
    h = 1.0 / fs
    best: tuple[float, ComplexArray, float] | None = None
    for tau in delays:
        H = prob.P * np.exp(2j * np.pi * f * tau)[:, None]
        start = initial_poles(order, f[0], f[-1], "discrete", h)
        its = PROBE if len(delays) > 1 else RELOCATIONS
        lam = relocate(prob.z, H, W, start, iterations=its, workers=prob.workers)
        v = cost(prob, domain_poles(lam, prob.domain, fs), tau)
        if best is None or v < best[0]:
            best = (v, lam, tau)
    assert best is not None
    lam, tau = best[1], best[2]
    if len(delays) > 1:
        H = prob.P * np.exp(2j * np.pi * f * tau)[:, None]
        lam = relocate(prob.z, H, W, lam, iterations=RELOCATIONS, workers=prob.workers)
    return domain_poles(lam, prob.domain, fs), tau


def fit_order(
    prob: Problem,
    f: FloatArray,
    order: int,
    fs: float,
    delays: list[float],
    free_delay: bool,
    max_delay: float,
) -> tuple[ComplexArray, float]:
    """Poles and delay of one order: the better of two starts, each refined.

    Vector fitting weighted by 1/σ (the cost's own weights) and by 1/|P̂| (relative: where
    σ peaks at a resonance, the 1/σ start can miss the resonance, measured on the motor
    bench); per start the delay candidates told apart by five relocations, the best one
    relocated further. Coarse to fine past :data:`COARSE_BINS` bins (module docstring).
    """
    coarse, fc = _subset(prob, f)
    rel = 1.0 / np.maximum(np.abs(coarse.P), 1e-300 + np.abs(coarse.P).max() * 1e-12)
    found: list[tuple[float, ComplexArray, float]] = []
    for W in (coarse.W, rel):
        poles, tau = _start(coarse, fc, W, order, fs, delays)
        poles, tau = refine(coarse, poles, tau, free_delay=free_delay, max_delay=max_delay)
        found.append((cost(prob, poles, tau), poles, tau))
    _, poles, tau = min(found, key=lambda t: t[0])
    if coarse is not prob:
        poles, tau = refine(prob, poles, tau, free_delay=free_delay, max_delay=max_delay)
    return poles, tau
