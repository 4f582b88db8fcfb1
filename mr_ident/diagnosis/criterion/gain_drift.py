# SPDX-License-Identifier: Apache-2.0
"""Does the plant's gain move within a record? One instrumental-variable gain per segment.

The frequency-domain comparison of the segments (:mod:`.timevarying`) estimates an FRF per
segment, with few degrees of freedom per line. A change of the plant's gain moves the
whole band alike, so it is pooled here into one scalar per segment, in time.

With a controller: the instrument ``z`` is the model's noise-free closed-loop prediction
of y from the measured r (:func:`~.prediction.predict`; independent of the noise), the
regressor ``ŷ`` the model's plant driven by the measured u (P_h alone, from rest). Without
one (open loop) ``z = ŷ``, the plant driven by the measured (centred) u. Per segment s of
the samples used (the loop's start skipped, :func:`~.objective.settle_samples`; for periodic
data the first period, and segments of whole periods) the gain, traced over the output
channels,

    ``c_s = <z, y>_s / <z, ŷ>_s``,  ``<a, b>_s = Σ_{t in s} Σ_i a_i(t) b_i(t)``.

Whatever the plant's state at a segment's start, y and ŷ differ there by its free
response: both are projected, per segment and channel, off the span of a constant and the
plant's free responses ``C A^t e_j`` from the segment's start (an integrator's offset, a
slow mode's decay, and the drift of ŷ from y that a changing gain leaves in an integrating
plant; a handful of degrees of freedom over hundreds of samples, which only lowers the
variance below its estimate). Under a time-invariant loop ``y = P u + v``
(P the true plant, a model error allowed) the segments are stretches of one stationary
process, so E c_s is the same for each: with ``c`` the gain over the whole record and
``e = y - c ŷ`` (coloured, and correlated with z through any model error),

    ``c_s - c = w_s / D_s``, ``w_s = <z, e>_s``, ``D_s = <z, ŷ>_s``.

A plant gain ``1 + a(t)`` moves c_s by a weighted mean of a over the segment. The variance
of w_s (a sum of the products ``x_t = Σ_i z_i(t) e_i(t)``, zero-mean under the null) is
``N_s`` times the long-run variance ``Σ_τ γ_x(τ)``; for Gaussian z and e (Isserlis)
``γ_x(τ) = Σ_ij R_{z_i z_j}(τ) R_{e_i e_j}(τ) + R_{z_i e_j}(τ) R_{e_i z_j}(τ)``, so

    ``var w_s = N_s ∫ T(f) df``,  ``T = Σ_ij Φ^z_ij conj(Φ^e_ij) + Φ^{ze}_ij Φ^{ze}_ji``

(Φ the spectral densities, ``Φ^{ze}_ij`` of z_i against e_j; SISO: ``Φ_z Φ_e + Φ_ze²``).
T is estimated on the L samples used, from the periodograms of the whole record
(``I^{ab}_ij = A_i conj(B_j) / L``, every bin of the full circle), one factor of each
product raw and the other the mean of its :data:`NEIGHBOURS` bins either side, the bin
itself left out (``S``):

    ``T̂_k = Re Σ_ij [S(I^z)_ij conj(I^e_ij) + S(I^{ze})_ij I^{ze}_ji]``,  ``var ŵ_s = N_s
    Σ_k T̂_k / L``.

Distinct bins are independent, so ``E T̂ = T`` where the spectra are smooth over the
neighbours (no ``|Φ_ze|²`` of a bin's product with itself); a line of e (a sinusoidal
disturbance) meets z's spectrum around it, not the one draw of its own bin (raw products
of both read a benchmark record's variance 4x too low, p 2e-6). Periodic data: z is a line
spectrum, so ``I^z`` raw against S(I^e), and e's periodic part is the same in every
segment (whole periods), which leaves the c_s alike: only its noise counts, e less its
period mean times ``P / (P - 1)`` (P periods), independent of z (no cross term). Each
segment's own gain is taken out of e (``e = y - c_s ŷ`` in segment s): under the null the
same as c's, under a changing gain the change stays out of the variance.

The test: ``c_s`` with variance ``V_s / D_s²``, weights ``ω_s = D_s² / V_s``, their
weighted mean ``c̄``, ``X = Σ_s ω_s (c_s - c̄)²``, which is ``χ²(S - 1)`` under the null.
The variance is estimated, with about ``ν = 2 (Σ_k T̂_k)² / Σ_k T̂_k²`` degrees of freedom
(:func:`dof`): ``X / (S - 1)`` against
``F(S - 1, ν)``. Not done (None) where a sample of u or y is missing, the plant is
unstable, or fewer than two segments of :data:`MIN_SEGMENT` samples fit.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.lti import StateSpace
from ...numerics.systems.model import Model
from .objective import settle_samples
from .prediction import centred, driving_input, predict

#: Segments the samples used are cut into (at most). Measured on bench_timevarying's records
#: (4, 6, 8, 12): the 10 s gains named by this test alone 87, 95, 96, 99 of 100, the 30 s
#: 93, 99, 100, 100; of 1120 time-invariant records 36, 32, 50, 60 below p = 0.05, 5, 4, 10,
#: 11 below 0.01, none below 1e-3 (a gain whose period is a third of the record averages
#: out over long segments).
PARTS = 12
#: Bins either side whose periodograms stand for a bin's spectrum (itself left out).
NEIGHBOURS = 4
#: Fewest samples per segment.
MIN_SEGMENT = 200


@dataclass(frozen=True)
class GainDrift:
    """The segments' instrumental-variable gains compared (module docstring).

    ``gains`` the c_s, ``std`` their standard deviations under the null; ``ratio`` the F
    ratio ``X / (S - 1)`` with ``dof`` (S - 1, ν); ``p`` the probability that noise alone
    reaches it; ``change`` the rms of ``c_s / c̄ - 1``.
    """

    gains: tuple[float, ...]
    std: tuple[float, ...]
    ratio: float
    dof: tuple[int, float]
    p: float
    change: float


def gain_drift(rec: LoopData, model: Model, parts: int = PARTS) -> GainDrift | None:
    """The segments' gains of ``rec`` under ``model`` compared (module docstring)."""
    import scipy.stats  # not at the top: identify's start-up stays light

    if parts < 2:
        raise ValueError(f"parts must be at least 2, got {parts}")
    Pd = model.plant_discrete()  # realised once: the regressor's plant and its free responses
    got = _signals(rec, model, Pd)
    if got is None:
        return None
    z, y, yh, start = got
    N = y.shape[0]
    if rec.period is not None:
        P = rec.period
        periods = (N - start) // P
        k = min(parts, periods)
        size = periods // max(k, 1) * P
    else:
        k = min(parts, (N - start) // MIN_SEGMENT)
        size = (N - start) // max(k, 1)
    if k < 2 or size < MIN_SEGMENT:
        return None
    used = slice(start, start + k * size)
    z, y, yh = z[used], y[used], yh[used]
    basis = _free_basis(Pd, size)
    if basis is None:
        return None
    y, yh = _project(y, basis, k), _project(yh, basis, k)
    z = z - z.mean(axis=0)
    num, D = _per_segment(z, y, k), _per_segment(z, yh, k)
    if np.any(D == 0):
        return None
    cs = num / D
    e = y - (np.repeat(cs, size)[:, None] * yh)  # each segment's own gain taken away
    if rec.period is not None:  # only the noise: e less its period mean
        Pn = k * size // rec.period
        e3 = e.reshape(Pn, rec.period, -1)
        e = (e3 - e3.mean(axis=0)).reshape(e.shape) * math.sqrt(Pn / (Pn - 1))
    T = long_run(z, e, periodic=rec.period is not None)
    total = float(T.sum())
    if not total > 0:
        return None
    V = total / k  # per segment: N_s Σ T̂ / L with N_s = size, L = k size
    w = D**2 / V
    cbar = float(np.sum(w * cs) / np.sum(w))
    X = float(np.sum(w * (cs - cbar) ** 2))
    nu = dof(T)
    ratio = X / (k - 1)
    p = float(scipy.stats.f.sf(ratio, k - 1, nu))
    change = math.sqrt(float(np.mean((cs / cbar - 1.0) ** 2))) if cbar else math.inf
    std = tuple(float(x) for x in np.sqrt(V) / np.abs(D))
    return GainDrift(tuple(float(x) for x in cs), std, ratio, (k - 1, nu), p, change)


def _per_segment(a: FloatArray, b: FloatArray, k: int) -> FloatArray:
    """``<a, b>_s`` over k equal consecutive segments of a, b (n, n_y)."""
    n = a.shape[1]
    out: FloatArray = np.einsum("sti,sti->s", a.reshape(k, -1, n), b.reshape(k, -1, n))
    return out


def long_run(z: FloatArray, e: FloatArray, periodic: bool = False) -> FloatArray:
    """``T̂_k`` (module docstring) on every bin of the full circle, (L,) for z, e (L, n).

    ``Σ_k T̂_k / L`` estimates ``Σ_τ γ_x(τ)`` of ``x_t = Σ_i z_i(t) e_i(t)``. ``periodic``:
    z is periodic (a line spectrum) and e noise independent of it: ``I^z`` raw against
    e's smoothed spectrum, no cross term.
    """
    L = z.shape[0]
    Z, E = np.fft.fft(z, axis=0), np.fft.fft(e, axis=0)  # (L, n)
    Iz = np.einsum("ki,kj->kij", Z, Z.conj()) / L
    Ie = np.einsum("ki,kj->kij", E, E.conj()) / L
    if periodic:
        T = np.einsum("kij,kij->k", Iz, neighbours(Ie).conj())
    else:
        Ize = np.einsum("ki,kj->kij", Z, E.conj()) / L
        T = np.einsum("kij,kij->k", neighbours(Iz), Ie.conj())
        T += np.einsum("kij,kji->k", neighbours(Ize), Ize)
    out: FloatArray = T.real
    return out


def neighbours(P: np.ndarray, m: int = NEIGHBOURS) -> np.ndarray:
    """The mean of ``P`` (L, ...) over the m bins either side of each, itself left out.

    Circularly: the bins are the full circle's.
    """
    L = P.shape[0]
    c = np.cumsum(np.concatenate([P[-m - 1 :], P, P[:m]]), axis=0)  # wrapped
    win = c[2 * m + 1 : 2 * m + 1 + L] - c[:L]  # the sum over k - m .. k + m
    out: np.ndarray = (win - P) / (2 * m)
    return out


def dof(T: FloatArray) -> float:
    """The degrees of freedom of ``Σ_k T̂_k`` (``T`` over the full circle, :func:`long_run`).

    Satterthwaite over the independent bins (half the circle), each bin's T̂ taken as
    exponential (relative variance 1, ``E T̂² = 2 T²``): ``ν = 2 (Σ T̂)² / Σ T̂²``, which
    reads ν about half its value where T is broad (``2 (Σ T)² / Σ T²``; conservative) and
    about right where one bin dominates.
    """
    half = T[: T.size // 2 + 1]
    return float(2.0 * np.sum(half) ** 2 / np.sum(half**2))


def _signals(
    rec: LoopData, model: Model, Pd: StateSpace
) -> tuple[FloatArray, FloatArray, FloatArray, int] | None:
    """``(z, y, ŷ, start)`` over the whole record (module docstring); None: not done.

    ``Pd``: the model's plant, discrete (``model.plant_discrete()``).
    """
    from ...numerics.systems.simulate import StateRecursion

    _, u, y = centred(rec, model)
    if model.controller is None:
        u = driving_input(rec, model)
        if np.isnan(y).any():
            return None
        start = 0
    else:
        if np.isnan(u).any() or np.isnan(y).any():
            return None
        start = settle_samples(model, rec.n_samples)
    if model.disturbances:  # the model's own sinusoids: not the plant's
        y = y - model.disturbance(0, rec.n_samples)
    if rec.period is not None:
        start = -(-max(start, rec.period) // rec.period) * rec.period
    if Pd.A.size and np.max(np.abs(np.linalg.eigvals(Pd.A))) > 1.0 + 1e-9:
        return None
    with warnings.catch_warnings():  # a double integrator's: the direct recursion, slower
        warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
        yh = StateRecursion(Pd).run(u)
    z = yh if model.controller is None else predict(model, rec).y
    return z, y, yh, start


def _free_basis(Pd: StateSpace, n: int) -> FloatArray | None:
    """A constant and the plant's free responses ``C A^t``, t = 0..n-1: (n, n_y, 1 + n_x).

    Orthonormal per channel over the n samples (columns below ``1e-9`` of the largest
    singular value dropped: modes that decayed, a delay's states). None where not finite.
    """
    A, C = np.asarray(Pd.A, dtype=float), np.asarray(Pd.C, dtype=float)
    nx, ny = A.shape[0], C.shape[0]
    cols = np.zeros((n, ny, 1 + nx))
    cols[:, :, 0] = 1.0
    M = C
    for t in range(n):
        cols[t, :, 1:] = M
        M = M @ A
    if not np.all(np.isfinite(cols)):
        return None
    out = np.zeros_like(cols)
    for i in range(ny):
        U, s, _ = np.linalg.svd(cols[:, i, :], full_matrices=False)
        keep = s > 1e-9 * s[0]
        out[:, i, : int(keep.sum())] = U[:, keep]
    return out


def _project(x: FloatArray, basis: FloatArray, k: int) -> FloatArray:
    """``x`` (k size, n_y) less its projection on the basis (size, n_y, m).

    Per segment and channel.
    """
    xs = x.reshape(k, -1, x.shape[1])
    coef = np.einsum("tim,sti->sim", basis, xs)
    out: FloatArray = (xs - np.einsum("tim,sim->sti", basis, coef)).reshape(x.shape)
    return out
