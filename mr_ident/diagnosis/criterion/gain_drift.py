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
``F(S - 1, ν)``. Open loop: u's mean is taken out (:func:`~.prediction.centred`), and what
it did to y (the plant's step responses from the segment's start; an integrator's ramp) is
projected off too. Not done (None) where the plant is unstable, fewer than two segments of
:data:`MIN_SEGMENT` samples fit, y is at the low rate (its samples are not ŷ's: the gains
were compared at the wrong times), or too many samples are missing (below).

Missing samples (NaN in u or y: a bag's dropped messages) are unknowns, nothing is
interpolated:

- A missing y_i(t) leaves that sample out: of the projection (over the samples kept),
  of the inner products and of the periodograms (z and e 0 there). Exact.
- A missing u_j(t_m) would corrupt ŷ from t_m on for the plant's memory (forever with an
  integrator), and dropping those samples would drop nearly all of a lossy record. ŷ
  takes the closed loop's own prediction there (z's, from r; open loop: u's mean, 0), and
  whatever the true u was, ``ŷ`` and ``P u`` then differ by ``(u - û)(t_m) h_j(t - t_m)``,
  h the plant's unit-sample response: its columns ``h_ij(t - t_m)`` (from t_m to the
  segment's end; beyond, they are free responses of the next segment) join the free
  responses that y and ŷ are projected off, as the criterion eliminates a hole's unknown
  (docs/diagnose.md, "Missing samples"). Exact where the model is the plant (the segments'
  gains of a noise-free lossy record are the plant's to rounding); a model error leaks
  ``(P - P_h) δ`` as it does through the free responses. A run of consecutive holes with
  more entries than the plant's order n_x instead drops its own samples and takes the n_x
  free responses from its end (the state there unknown): fewer columns, the same span
  after it. A segment's holes take at most :data:`MAX_HOLE_COLUMNS` columns, and
  samples times columns² at most :data:`MAX_HOLE_WORK` (the projection's cost).
- z (from r, never missing) needs no filling; the instrument stays independent of the
  noise (in open loop ŷ's holes hold 0, not an estimate from y).
- The variance: the periodograms are of the series with the samples left out at 0. For
  the sum over the samples kept, ``var = Σ_τ a(τ) γ_x(τ)`` with ``a_ij(τ) = Σ_t m_i(t + τ)
  m_j(t)`` the pairs kept at lag τ (m the samples kept), whereas a product of two masked
  periodograms weighs lag τ by ``a(τ)² / L`` (a share q of white holes would read the
  variance a factor 1 - q low). The smoothed factor is therefore scaled by ``L / a(1)``
  (:func:`_pairs_fix`; the raw one kept): every lag near its due weight where the
  products' correlation time is short against the holes' spacing, lag 0 a factor ``a(0) /
  a(1)`` high (conservative); scaling each lag by its own ``L / a(τ)`` is exact in
  expectation but can read a record's variance negative (below 0 where z has no power and
  e a sinusoid's line). A segment's share is its count of samples kept over the record's,
  ``V_s = Σ T̂ n_s / Σ n``. Periodic data: the period mean over the periods present at
  each sample, ``n / (n - 1)`` with its own n.
- Not done where more than :data:`MAX_MISSING` of the samples used are missing (y's, and
  the samples of long holes of u): the segments stay alike enough for the shares above,
  the scaling near 1.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import BoolArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.lti import StateSpace
from ...numerics.systems.model import Model
from .objective import settle_samples
from .prediction import centred, grows, predict

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
#: Largest share of the samples used that may be missing (y's, and those of long holes
#: of u) ...
MAX_MISSING = 0.2
#: ... and most columns of u's holes per segment (module docstring, "Missing samples") ...
MAX_HOLE_COLUMNS = 400
#: ... and most ``samples x columns²`` per segment (the projection's cost, which this bounds
#: per segment and channel; a 10 kHz record of 60 s, 50 000 samples a segment, takes 89
#: columns in all, the free responses among them).
MAX_HOLE_WORK = 4e8


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
    if rec.y.shape[0] != rec.n_samples:  # y at the low rate: not done (module docstring)
        return None
    Pd = model.plant_discrete()  # realised once: the regressor's plant and its free responses
    got = _signals(rec, model, Pd)
    if got is None:
        return None
    z, y, yh, start, holes = got
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
    z, y, yh, holes = z[used], y[used], yh[used], holes[used]
    free, h = _responses(Pd, size)
    if free is None:
        return None
    got2 = _project_all(y, yh, holes, free, h, k, step=model.controller is None)
    if got2 is None:
        return None
    y, yh, keep = got2
    z = np.where(keep, z - _masked_mean(z, keep), 0.0)
    num, D = _per_segment(z, y, k), _per_segment(z, yh, k)
    if np.any(D == 0):
        return None
    cs = num / D
    e = np.where(keep, y - (np.repeat(cs, size)[:, None] * yh), 0.0)  # each segment's own gain
    if rec.period is not None:  # only the noise: e less its period mean
        e, keep = _less_period_mean(e, keep, rec.period)
        z = np.where(keep, z, 0.0)
    T = long_run(z, e, periodic=rec.period is not None, mask=None if keep.all() else keep)
    total = float(T.sum())
    if not total > 0:
        return None
    n_s = keep.reshape(k, size, -1).sum(axis=(1, 2))
    V = total * n_s / n_s.sum()  # per segment: N_s Σ T̂ / L over the samples used
    w = D**2 / V
    cbar = float(np.sum(w * cs) / np.sum(w))
    X = float(np.sum(w * (cs - cbar) ** 2))
    nu = dof(T)
    ratio = X / (k - 1)
    p = float(scipy.stats.f.sf(ratio, k - 1, nu))
    change = math.sqrt(float(np.mean((cs / cbar - 1.0) ** 2))) if cbar else math.inf
    std = tuple(float(x) for x in np.sqrt(V) / np.abs(D))
    return GainDrift(tuple(float(x) for x in cs), std, ratio, (k - 1, nu), p, change)


def _masked_mean(x: FloatArray, keep: BoolArray) -> FloatArray:
    """Each column's mean over its samples kept (0 where none is)."""
    n = np.maximum(keep.sum(axis=0), 1)
    out: FloatArray = np.where(keep, x, 0.0).sum(axis=0) / n
    return out


def _less_period_mean(e: FloatArray, keep: BoolArray, P: int) -> tuple[FloatArray, BoolArray]:
    """``e`` less its mean over the periods present at each sample of the period.

    Times ``sqrt(n / (n - 1))`` (n present); a sample of the period present in fewer than
    two periods is dropped (the samples kept returned with it).
    """
    shape = e.shape
    e3, k3 = e.reshape(-1, P, shape[1]), keep.reshape(-1, P, shape[1])
    n = k3.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(k3, e3, 0.0).sum(axis=0) / n
        scale = np.sqrt(n / (n - 1.0))
    k3 = k3 & (n >= 2)
    out = np.where(k3, (e3 - mean) * scale, 0.0)
    return out.reshape(shape), k3.reshape(shape)


def _per_segment(a: FloatArray, b: FloatArray, k: int) -> FloatArray:
    """``<a, b>_s`` over k equal consecutive segments of a, b (n, n_y)."""
    n = a.shape[1]
    out: FloatArray = np.einsum("sti,sti->s", a.reshape(k, -1, n), b.reshape(k, -1, n))
    return out


def long_run(
    z: FloatArray, e: FloatArray, periodic: bool = False, mask: BoolArray | None = None
) -> FloatArray:
    """``T̂_k`` (module docstring) on every bin of the full circle, (L,) for z, e (L, n).

    ``Σ_k T̂_k / L`` estimates ``Σ_τ γ_x(τ)`` of ``x_t = Σ_i z_i(t) e_i(t)``. ``periodic``:
    z is periodic (a line spectrum) and e noise independent of it: ``I^z`` raw against
    e's smoothed spectrum, no cross term. ``mask`` (L, n): the samples used, z and e 0
    elsewhere; the smoothed factor is then scaled by L over its pairs kept one sample apart
    (module docstring, "Missing samples"), so ``Σ_k T̂_k`` estimates (a little high) the
    variance of the sum over the samples used.
    """
    L = z.shape[0]
    Z, E = np.fft.fft(z, axis=0), np.fft.fft(e, axis=0)  # (L, n)
    Iz = np.einsum("ki,kj->kij", Z, Z.conj()) / L
    Ie = np.einsum("ki,kj->kij", E, E.conj()) / L
    fix = _pairs_fix(mask)
    if periodic:
        T = np.einsum("kij,kij->k", Iz, neighbours(fix(Ie)).conj())
    else:
        Ize = np.einsum("ki,kj->kij", Z, E.conj()) / L
        T = np.einsum("kij,kij->k", neighbours(fix(Iz)), Ie.conj())
        T += np.einsum("kij,kji->k", neighbours(fix(Ize)), Ize)
    out: FloatArray = T.real
    return out


def _pairs_fix(mask: BoolArray | None) -> Callable[[np.ndarray], np.ndarray]:
    """The correction of a cross-periodogram (L, n, n) of series masked by ``mask`` (L, n).

    Scaled by ``L / a_ij(1)``, ``a_ij(1)`` the pairs kept one sample apart (the mean of
    lags ±1): every lag but 0 to about its pairs kept, lag 0 by ``a(0) / a(1)`` (about
    ``1 / (1 - q)`` for a share q of single holes) more, which errs high, never low (module
    docstring). The exact per-lag scaling ``L / a_ij(τ)`` and a lag-0 term of its own read
    a benchmark record's variance negative: where z has no power and e a sinusoidal
    disturbance's line, the corrected ``I^z`` dips below 0. The identity without a mask.
    """
    if mask is None:
        return lambda x: x
    L = mask.shape[0]
    m = mask.astype(float)
    a1 = (m[1:].T @ m[:-1] + m[:-1].T @ m[1:]) / 2
    scale = L / np.maximum(a1, 1.0)

    def fix(x: np.ndarray) -> np.ndarray:
        out: np.ndarray = scale * x
        return out

    return fix


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
) -> tuple[FloatArray, FloatArray, FloatArray, int, BoolArray] | None:
    """``(z, y, ŷ, start, holes)`` over the whole record (module docstring); None: not done.

    ``Pd``: the model's plant, discrete (``model.plant_discrete()``). y keeps its missing
    samples (NaN); ``holes`` (N, n_u) marks u's, which ŷ takes from the closed loop's
    prediction (in open loop as 0, the centred u's mean): their part is projected out.
    """
    from ...numerics.systems.simulate import StateRecursion

    _, u, y = centred(rec, model)
    holes = np.isnan(u)
    pred = None if model.controller is None else predict(model, rec)
    if holes.any():
        u = np.where(holes, 0.0 if pred is None else pred.u, u)
    start = 0 if model.controller is None else settle_samples(model, rec.n_samples)
    if model.disturbances:  # the model's own sinusoids: not the plant's
        y = y - model.disturbance(0, rec.n_samples)
    if rec.period is not None:
        start = -(-max(start, rec.period) // rec.period) * rec.period
    if grows(Pd):
        return None
    with warnings.catch_warnings():  # a double integrator's: the direct recursion, slower
        warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
        yh = StateRecursion(Pd).run(u)
    z = yh if pred is None else pred.y
    return z, y, yh, start, holes


def _responses(Pd: StateSpace, n: int) -> tuple[FloatArray | None, FloatArray]:
    """The free responses ``C A^t`` (n, n_y, n_x) and the unit-sample responses h.

    h (n, n_y, n_u): ``h[0] = D``, ``h[t] = C A^(t-1) B``, t = 0..n-1. None (free) where
    not finite.
    """
    A, B = np.asarray(Pd.A, dtype=float), np.asarray(Pd.B, dtype=float)
    C, D = np.asarray(Pd.C, dtype=float), np.asarray(Pd.D, dtype=float)
    free = np.zeros((n, C.shape[0], A.shape[0]))
    h = np.zeros((n, C.shape[0], B.shape[1]))
    h[0] = D
    M = C
    for t in range(n):
        free[t] = M
        if t + 1 < n:
            h[t + 1] = M @ B
        M = M @ A
    if not (np.all(np.isfinite(free)) and np.all(np.isfinite(h))):
        return None, h
    return free, h


def _project_all(
    y: FloatArray,
    yh: FloatArray,
    holes: BoolArray,
    free: FloatArray,
    h: FloatArray,
    k: int,
    *,
    step: bool = False,
) -> tuple[FloatArray, FloatArray, BoolArray] | None:
    """``y`` and ``ŷ`` (k size, n_y) projected per segment and channel; 0 where not kept.

    Off a constant, the free responses and the responses to u's missing samples, over the
    samples kept (y present, outside long holes of u), which come with them. None where
    more than :data:`MAX_MISSING` of the samples are not kept or a segment's holes take more
    than :data:`MAX_HOLE_COLUMNS` columns or :data:`MAX_HOLE_WORK` (module docstring,
    "Missing samples"). ``step``
    (open loop): also off the step responses (what u's mean, taken out, did).
    """
    keep = ~np.isnan(y)
    size = free.shape[0]
    base = np.concatenate(
        [np.ones((size, free.shape[1], 1)), free, *([np.cumsum(h, axis=0)] if step else [])],
        axis=2,
    )
    ys, yhs = np.nan_to_num(y).reshape(k, size, -1), yh.reshape(k, size, -1)
    ks, hs = keep.reshape(k, size, -1), holes.reshape(k, size, -1)
    outy, outh = np.zeros_like(ys), np.zeros_like(yhs)
    shared = None
    for s in range(k):
        cols, ks[s] = _hole_columns(hs[s], ks[s], free, h)
        m = cols.shape[2]
        if m and (m > MAX_HOLE_COLUMNS or size * (m + base.shape[2]) ** 2 > MAX_HOLE_WORK):
            return None
        if not cols.shape[2] and ks[s].all():  # a complete segment: the shared basis
            shared = _orthonormal(base) if shared is None else shared
            for x, out in ((ys, outy), (yhs, outh)):
                out[s] = x[s] - np.einsum(
                    "tim,im->ti", shared, np.einsum("tim,ti->im", shared, x[s])
                )
            continue
        full = np.concatenate([base, cols], axis=2)
        for i in range(ys.shape[2]):
            rows = ks[s][:, i]
            Q = _orthonormal(full[rows, i : i + 1, :])[:, 0, :]
            for x, out in ((ys, outy), (yhs, outh)):
                v = x[s][rows, i]
                out[s][rows, i] = v - Q @ (Q.T @ v)
    kept: BoolArray = ks.reshape(keep.shape)
    if kept.mean() < 1.0 - MAX_MISSING:
        return None
    py: FloatArray = outy.reshape(y.shape)
    ph: FloatArray = outh.reshape(yh.shape)
    return py, ph, kept


def _hole_columns(
    holes: BoolArray, keep: BoolArray, free: FloatArray, h: FloatArray
) -> tuple[FloatArray, BoolArray]:
    """The columns (size, n_y, m) spanning what u's missing samples of a segment do to ŷ.

    Within the segment; with the samples kept. Per run of consecutive holes: their
    unit-sample responses where they are no more than n_x, else the run's samples dropped
    and the free responses from its end (the state there unknown).
    """
    size, n_x = free.shape[0], free.shape[2]
    keep = keep.copy()
    cols: list[FloatArray] = []
    any_hole = holes.any(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], any_hole.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        entries = np.argwhere(holes[a:b])
        if len(entries) <= n_x:
            for dt, j in entries:
                c = np.zeros((size, free.shape[1]))
                c[a + dt :] = h[: size - a - dt, :, j]
                cols.append(c)
        else:
            keep[a:b] = False
            for j in range(n_x):
                c = np.zeros((size, free.shape[1]))
                c[b:] = free[: size - b, :, j]
                cols.append(c)
    out = np.stack(cols, axis=2) if cols else np.zeros((size, free.shape[1], 0))
    return out, keep


def _orthonormal(cols: FloatArray) -> FloatArray:
    """``cols`` (n, n_y, m) orthonormal per channel over its n samples.

    Columns below ``1e-9`` of the largest singular value dropped: modes that decayed, a
    delay's states.
    """
    out = np.zeros_like(cols)
    for i in range(cols.shape[1]):
        U, s, _ = np.linalg.svd(cols[:, i, :], full_matrices=False)
        keep = s > 1e-9 * s[0]
        out[:, i, : int(keep.sum())] = U[:, keep]
    return out
