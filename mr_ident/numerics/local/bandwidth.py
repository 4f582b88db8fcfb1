# SPDX-License-Identifier: Apache-2.0
"""Automatic local bandwidth: the LPM window half-width n chosen per frequency from the data.

A wider window averages more bins (variance falls about as 1/n) but lets more of the
FRF's curvature into the estimate (the bias of a degree-R local polynomial grows about as
``n^(R+1)`` times the (R+1)-th derivative; for ``lpm`` also the alias term, about as n).
For candidates ``n_0 < n_1 < ...`` the estimates ``P_j`` with their variances ``v_j``
(each method's own noise model) give, per high-rate bin,

* the variance: ``v_j``, from the LPM residual noise covariance, propagated;
* the bias: the smallest window is the least biased, so ``P_j - P_0`` is the bias
  difference plus noise. For nested least-squares windows ``Cov(P_j, P_0) ~ v_j``, so
  ``E|P_j - P_0|^2 ~ |b_j - b_0|^2 + v_0 - v_j`` and, b_0 neglected,
  ``b_j^2 ~ <|P_j - P_0|^2> - <v_0 - v_j>``;

where ``<.>`` is a moving average over ``2h + 1`` bins (h the largest candidate: a
bin's neighbours share its window). The bin takes the n of the least

    MSE_j = <|P_j - P_0|^2> + 2 <v_j> - <v_0>      (= <b_j^2> + <v_j>)

summed over the entries of a MIMO plant (one window per bin). The bias estimate is
not clipped at zero: it is unbiased, so its noise does not systematically favour the
narrow windows (a Mallows C_p-like criterion; Fan & Gijbels 1996, ch. 4, on local
polynomial bandwidths; Lepski's comparison of nested estimates). The per-bin variance
stays the chosen window's: the choice is made on averages over many bins, so it hardly
depends on one bin's noise (the Monte Carlo test of the reported std holds with it).

**At the cost of one fit** (:func:`probe_runs`, :func:`choose_widths`). Fitting every
candidate on every bin costs one full fit per candidate. But the criterion is a moving
average over ``2h + 1`` bins of quantities that change slowly along frequency, so it is
estimated on a *probe*: segments of ``2h + 1`` centre bins (a full moving window each),
about :data:`PROBE_SHARE` of the centre bins, half of the segments spaced evenly and half
log-spaced (the FRF's features crowd at low frequencies). Every candidate is fitted on the
probe only; the criterion of each candidate is interpolated linearly between the probed
bins; each centre bin takes the width of least criterion; and one fit runs with those
widths, bin by bin (:mod:`mr_ident.numerics.local.segments`). The cost is the final fit plus
``J`` fits of the probe (each its share in the per-bin solves, about
``(2h + 1 + 2 n_j) / (2h + 1)`` times it in the windowed sums).

*One window per centre bin.* A lifted method fits, at low-rate bin k, one window that
gives P_h at all F aliases ``k + l M``; its width is one choice for the F of them. The
criterion of a centre bin is the sum over its aliases (and entries) of each alias's MSE
*relative to its own noise level* ``<v_0>``: the aliases of one bin differ by orders of
magnitude in |P_h|, and an absolute sum would let the largest decide for all. For ``lpm``
(one high-rate bin per centre) this is the per-bin rule above. Measured on the paper's
loop with noise (600 s, seeds 0 and 1, all bins), the median relative error of
``freq-lifted`` was 0.0102 with the per-alias choice from four full fits and 0.0097 with
one window per centre bin; of ``structured`` 0.0091 and 0.0088.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray
from .strided import offsets_for

#: Ratio between successive candidate half-widths.
GROWTH = 1.5
#: The largest candidate is at most this many times the smallest.
SPAN = 4.0
#: The same with r at the setpoint, at most: above the controller's band the plant input is
#: only the hold's images of the controller's output, weak, and the plant smooth there:
#: wider windows win. Paper's loop, 600 s, noise 0.02, 30 seeds, median error in 80-120 Hz:
#: 16.2 % with 32 (widest candidate n = 210), 10.3 % with 64 (473), 8.6 % with 128 (710);
#: 0-40 Hz 0.165 / 0.114 / 0.108 %, 40-80 Hz 1.01 / 0.66 / 0.59 %. The widest window's
#: moment sums cost about the same as the narrowest's (doubling), so the time stays a
#: plant-input identification's with 64 (0.98x wall, 1.02x CPU) but not with 128 (1.25x,
#: 1.34x; 2 cores at load 14); make bench-setpoint.
SPAN_SETPOINT = 64.0
#: With r at the setpoint the widest candidate spans this many Hz on either side (at least
#: SPAN, at most SPAN_SETPOINT times the narrowest): the plant's smoothness is in Hz, so a
#: short record needs fewer bins for it. 600 s reaches SPAN_SETPOINT (widest 473 bins,
#: 0.79 Hz).
WIDEST_SETPOINT_HZ = 0.86


def setpoint_span(n_min: int, duration_s: float) -> float:
    """The span of the candidates of a setpoint-excited record of ``duration_s`` seconds.

    >>> setpoint_span(8, 600.0), setpoint_span(8, 120.0), setpoint_span(8, 30.0)
    (64.0, 12.9, 4.0)
    """
    return float(np.clip(WIDEST_SETPOINT_HZ * duration_s / n_min, SPAN, SPAN_SETPOINT))


#: Share of the centre bins on which the candidates are fitted (the probe).
PROBE_SHARE = 0.02
#: Probe segments at least, whatever the record's length. 6, 12 and 24 were measured on
#: ``make bench-structured`` (records of 120-600 s, where the floor matters): every error
#: figure of ``n = auto`` was as good or better with 6 than with 12, and with 12 than with 24;
#: with 3 and with 2 the random loops with noise were worse (docs/method.md).
MIN_PROBES = 6


def candidates(n_min: int, n_max: int, span: float = SPAN) -> tuple[int, ...]:
    """Half-widths ``n_min, ⌈1.5 n_min⌉, ...`` up to ``min(n_max, span n_min)``.

    >>> candidates(8, 1000)
    (8, 12, 18, 27)
    >>> candidates(8, 1000, span=SPAN_SETPOINT)
    (8, 12, 18, 27, 41, 62, 93, 140, 210, 315, 473)
    >>> candidates(8, 10)
    (8,)
    """
    if n_min < 1 or n_max < n_min:
        raise ConfigError(
            f"candidate half-widths need 1 <= n_min <= n_max, got n_min={n_min}, n_max={n_max}"
        )
    top = min(n_max, int(span * n_min))
    out = [n_min]
    while True:
        nxt = int(np.ceil(out[-1] * GROWTH))
        if nxt > top:
            return tuple(out)
        out.append(nxt)


def moving_mean(x: FloatArray, h: int) -> FloatArray:
    """Mean over the bins ``i-h .. i+h`` along axis -1, NaN ignored, shrunk at the ends."""
    ok = np.isfinite(x)
    xs = np.where(ok, x, 0.0)
    c = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(xs, axis=-1)], axis=-1)
    cn = np.concatenate(
        [np.zeros(x.shape[:-1] + (1,)), np.cumsum(ok, axis=-1, dtype=float)], axis=-1
    )
    K = x.shape[-1]
    lo = np.clip(np.arange(K) - h, 0, K)
    hi = np.clip(np.arange(K) + h + 1, 0, K)
    with np.errstate(invalid="ignore", divide="ignore"):
        out: FloatArray = (c[..., hi] - c[..., lo]) / (cn[..., hi] - cn[..., lo])
    return out


@dataclass(frozen=True)
class Choice:
    """The chosen window per bin and the estimate it gives.

    Attributes
    ----------
    response : ndarray, shape (K, n_out, n_in), complex128
    variance : ndarray, shape (K, n_out, n_in), float64
    n : ndarray of int, shape (K,)
        The half-width used at each bin.
    mse : ndarray, shape (J, K), float64
        The estimated mean-squared error of every candidate (summed over entries).
    """

    response: ComplexArray
    variance: FloatArray
    n: IntArray
    mse: FloatArray


def select(
    ns: tuple[int, ...], responses: ComplexArray, variances: FloatArray, *, halfwidth: int
) -> Choice:
    """Choose, per bin, the candidate of least estimated mean-squared error.

    Parameters
    ----------
    ns : tuple of int, length J
        The candidate half-widths, increasing.
    responses : ndarray, shape (J, K, n_out, n_in), complex
        The estimate with each candidate, on the same K bins.
    variances : ndarray, shape (J, K, n_out, n_in), float
        Their variances ``E|dP|^2`` (NaN where unknown).
    halfwidth : int
        h of the moving averages (bins each side).

    Returns
    -------
    Choice

    Raises
    ------
    DimensionError
        If the shapes disagree.
    """
    P = np.asarray(responses)
    V = np.asarray(variances, dtype=float)
    J = len(ns)
    if P.ndim != 4 or P.shape[0] != J or V.shape != P.shape:
        raise DimensionError(
            f"responses and variances must both be (J={J}, K, n_out, n_in), got "
            f"{P.shape} and {V.shape}"
        )
    mse = _mse(P, V, lambda x: moving_mean(x, halfwidth))
    bad = ~np.isfinite(P).all(axis=(2, 3)) | ~np.isfinite(mse)
    mse = np.where(bad, np.inf, mse)
    j = np.argmin(mse, axis=0)  # all inf -> 0, the smallest window (NaN stays NaN)
    K = P.shape[1]
    k = np.arange(K)
    return Choice(
        response=P[j, k],
        variance=V[j, k],
        n=np.asarray(ns, dtype=np.int64)[j],
        mse=np.where(np.isfinite(mse), mse, np.nan),
    )


def _mse(P: ComplexArray, V: FloatArray, mean: Callable[[FloatArray], FloatArray]) -> FloatArray:
    """``<|P_j - P_0|^2> + 2 <v_j> - <v_0>`` summed over entries: (J, K) from (J, K, o, i).

    ``mean`` is ``<.>`` along the last axis: :func:`moving_mean`, or within the probe's
    segments (:func:`_segmented_mean`).
    """
    var = V.sum(axis=(2, 3))
    d = (np.abs(P - P[:1]) ** 2).sum(axis=(2, 3))
    mse: FloatArray = mean(d) + 2.0 * mean(var) - mean(var[:1])
    return mse


def probe_runs(n_bins: int, n_max: int) -> tuple[tuple[int, int], ...]:
    """Segments ``(start, stop)`` of the centre bins 0..n_bins-1 on which candidates are fitted.

    At least :data:`MIN_PROBES` segments of ``2 n_max + 1`` bins, about
    :data:`PROBE_SHARE` of the bins, half spaced evenly and half log-spaced from bin 0 to the
    last, overlapping ones merged; every bin (one segment) when that would be half of them.

    >>> probe_runs(600, 27)          # below 2 x MIN_PROBES segments of 55 bins: every bin
    ((0, 600),)
    >>> len(probe_runs(240_001, 27)) > 24
    True
    """
    L = 2 * n_max + 1
    count = max(MIN_PROBES, int(np.ceil(PROBE_SHARE * n_bins / L)))
    if 2 * count * L >= n_bins:
        return ((0, n_bins),)
    even = count // 2
    centres = np.concatenate(
        [
            np.geomspace(L / 2, n_bins - L / 2, count - even),
            np.linspace(L / 2, n_bins - L / 2, even),
        ]
    )
    starts = np.unique(np.clip(np.round(centres - L / 2), 0, n_bins - L).astype(np.int64))
    out: list[list[int]] = []
    for a in starts:
        if out and a <= out[-1][1]:
            out[-1][1] = int(a) + L
        else:
            out.append([int(a), int(a) + L])
    return tuple((a, b) for a, b in out)


def centre_bins(n_samples: int, lift: int) -> IntArray:
    """The centre bin of each bin 0..N//2 of the half spectrum: shape (N//2 + 1,).

    A lifted method (``lift`` = F) fits low-rate bin k for the high-rate bins
    ``±k + l M`` (M = N/F), folded into 0..M//2; otherwise (``lift`` = 1) each bin is its own.
    """
    kappa = np.arange(n_samples // 2 + 1)
    if lift == 1:
        return kappa
    M = n_samples // lift
    k = kappa % M
    out: IntArray = np.minimum(k, M - k)
    return out


def choose_widths(
    ns: tuple[int, ...],
    responses: ComplexArray,
    variances: FloatArray,
    centre_of: IntArray,
    n_centres: int,
    *,
    halfwidth: int,
    min_run: int | None = None,
    strided: bool = False,
) -> tuple[IntArray, IntArray]:
    """One half-width per centre bin from candidates fitted on a probe (module docstring).

    Parameters
    ----------
    ns : tuple of int, length J
        The candidate half-widths, increasing.
    responses, variances : ndarray, shape (J, H, n_out, n_in)
        Each candidate's estimate and variance on the H bins of the half spectrum, NaN
        outside the probe.
    centre_of : ndarray of int, shape (H,)
        The centre bin of each of the H bins (:func:`centre_bins`).
    n_centres : int
        Centre bins 0..n_centres-1.
    halfwidth : int
        h of the moving averages.
    min_run : int, optional
        Runs of one width shorter than this join the run before (default ``halfwidth``):
        each run costs the engine ``2 n`` extra bins.
    strided : bool, default False
        Where the widest candidate is chosen, its windows solved every ``2h + 1`` bins
        (h = ``offsets_for(ns[-1])``; the engine solves at every centre where the
        off-centre bias shows: :mod:`mr_ident.numerics.local.strided`).

    Returns
    -------
    widths : ndarray of int, shape (n_centres,)
        The half-width of every centre bin.
    offsets : ndarray of int, shape (n_centres,)
        h of :mod:`~mr_ident.numerics.local.strided` for every centre bin: ``offsets_for(n)``
        where the widest candidate is chosen (with ``strided``), else 0.
    """
    P = np.asarray(responses)
    V = np.asarray(variances, dtype=float)
    J = len(ns)
    if P.ndim != 4 or P.shape[0] != J or V.shape != P.shape or centre_of.shape != P.shape[1:2]:
        raise DimensionError(
            f"responses and variances must both be (J={J}, H, n_out, n_in) with centre_of "
            f"(H,), got {P.shape}, {V.shape} and {centre_of.shape}"
        )
    probed = np.flatnonzero(np.isfinite(P).all(axis=(0, 2, 3)))
    widths = np.full(n_centres, ns[0], dtype=np.int64)
    none = np.zeros(n_centres, dtype=np.int64)
    if probed.size == 0:
        return widths, none
    # the moving means run over the probed bins only: compress them (they are runs of
    # consecutive bins, so a neighbour in the compressed order is a neighbour in frequency
    # within a segment; the means are cut at the segments' ends)
    sub = P[:, probed]

    def mean(x: FloatArray) -> FloatArray:
        return _segmented_mean(x, probed, halfwidth)

    mse = _mse(sub, V[:, probed], mean)
    scale = mean((V[0, probed] + 1e-24 * np.abs(sub[0]) ** 2).sum(axis=(1, 2))[None])[0]
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero level: no criterion there
        rel = mse / scale
    ok = np.isfinite(rel).all(axis=0)
    c = centre_of[probed][ok]
    counts = np.bincount(c, minlength=n_centres)
    seen = np.flatnonzero(counts)
    if seen.size == 0:
        return widths, none

    def spread(x: FloatArray) -> FloatArray:
        """Rows of values on the probed bins: averaged per centre, interpolated."""
        return np.stack(
            [
                np.interp(
                    np.arange(n_centres),
                    seen,
                    np.bincount(c, weights=row[ok], minlength=n_centres)[seen] / counts[seen],
                )
                for row in x
            ]
        )

    j = np.argmin(spread(rel), axis=0)
    h = offsets_for(ns[-1]) if strided else 0
    key = _merge_short(j * 2 + ((j == J - 1) & (h > 0)), halfwidth if min_run is None else min_run)
    return np.asarray(ns, dtype=np.int64)[key // 2], np.where(key % 2 == 1, h, 0)


def _segmented_mean(x: FloatArray, bins: IntArray, h: int) -> FloatArray:
    """:func:`moving_mean` along axis -1 of values at increasing ``bins``, within runs.

    A run is a stretch of consecutive bins; the mean of bin i takes the bins of its own run
    within ``i-h .. i+h`` only.
    """
    out = np.empty_like(x)
    breaks = np.flatnonzero(np.diff(bins) != 1) + 1
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, bins.size], strict=True):
        out[..., a:b] = moving_mean(x[..., a:b], h)
    return out


def _merge_short(widths: IntArray, min_run: int) -> IntArray:
    """Runs of one width shorter than ``min_run`` take the width of the run before them."""
    edges = np.flatnonzero(np.diff(widths)) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, widths.size]
    values = widths[starts].copy()
    for i in range(1, starts.size):  # a loop over runs (few), not bins
        if stops[i] - starts[i] < min_run:
            values[i] = values[i - 1]
    out: IntArray = np.repeat(values, stops - starts)
    return out
