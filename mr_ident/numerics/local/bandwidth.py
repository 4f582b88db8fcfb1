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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray

#: Ratio between successive candidate half-widths.
GROWTH = 1.5
#: The largest candidate is at most this many times the smallest.
SPAN = 4.0


def candidates(n_min: int, n_max: int) -> tuple[int, ...]:
    """Half-widths ``n_min, ⌈1.5 n_min⌉, ...`` up to ``min(n_max, 4 n_min)``.

    >>> candidates(8, 1000)
    (8, 12, 18, 27)
    >>> candidates(8, 10)
    (8,)
    """
    if n_min < 1 or n_max < n_min:
        raise ConfigError(
            f"candidate half-widths need 1 <= n_min <= n_max, got n_min={n_min}, n_max={n_max}"
        )
    top = min(n_max, int(SPAN * n_min))
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
    var = V.sum(axis=(2, 3))  # (J, K)
    d = (np.abs(P - P[:1]) ** 2).sum(axis=(2, 3))
    h = halfwidth
    mse = moving_mean(d, h) + 2.0 * moving_mean(var, h) - moving_mean(var[:1], h)
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
