# SPDX-License-Identifier: Apache-2.0
"""P_h from an output sampled at the low rate only, on a rotated lifted multisine.

With y measured at samples q, q + F, ... only, its M-point DFT (M = N/F, one period of
N high-rate samples) sees the F aliases of each lifted bin a at once:

    Y_low(a) = (1/F) sum_l Y(a + lM) e^{j 2π (a + lM) q / N},   Y(κ) = P_h(κ) U(κ)

(the plant is LTI at the high rate; U the fast input's N-point DFT, the whole circle). In
periodic steady state that is one exact equation per realization in the F unknowns
``P_h(a + lM)``. One realization cannot give them: the loop puts every alias into u
(the held controller output), but in proportion to what r excites, so realizations that
excite the same alias give proportional rows. A rotated design
(:func:`~mr_ident.numerics.excitation.multisine.design` with ``rotate=True``) excites every alias
of every lifted bin once in F realizations, so the rows span all F: least squares per lifted
bin gives P_h at every line of every excited family, up to fs_high/2, with no local model
(no alias range, :mod:`~mr_ident.numerics.lifted.alias_range`, no leakage). The std is first
order in the period-mean noise of Y_low (the spread over periods); u is the recorded
plant input, taken as exact.

The same design measures the lifted r -> u map: ``Ũ_m(k) = S̃(k) R̃_m(k)`` over the F
realizations gives ``S̃(k)`` whole, so the lifted closed loop r -> y follows as
``J̃(k) = diag(P_h(k + lM)) S̃(k)`` (y = P_h u at every line), and with it the PFG from data
(the 2-norm of block column l, :mod:`~mr_ident.numerics.lifted.pfg`), no controller model: the
fast output's response is not measured, but the plant and u determine it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray
from ..lifting import unlift_bins

#: The source of the PFG from data of a rotated design (:attr:`SlowPlant.pfg`).
SLOW_PFG_SOURCE = "data:rotated lifted design"


@dataclass(frozen=True)
class SlowPlant:
    """P_h and the PFG from data at the lines of the excited alias families.

    Attributes
    ----------
    lines : ndarray of int, shape (K,)
        Lines in (0, N/2] (frequency ``lines fs / N``).
    response, std : ndarray, shape (K,)
        P_h and its first-order std (from the spread of Y_low over periods; nan with one
        period).
    pfg, pfg_std : ndarray, shape (K,)
        The PFG from data (``J̃ = diag(P_h) S̃``) and its std from P_h's (S̃ taken as
        exact).
    """

    lines: IntArray
    response: ComplexArray
    std: FloatArray
    pfg: FloatArray
    pfg_std: FloatArray


def slow_output_plant(
    r: FloatArray,
    u: FloatArray,
    y_low: FloatArray,
    period: int,
    ratio: int,
    *,
    phase: int = 0,
    rcond: float = 1e-6,
) -> SlowPlant:
    """P_h and the PFG at every line of a lifted bin whose aliases r excited all.

    A lifted bin counts when the reference's spectra at its F aliases over the
    realizations have rank F (entries below 1e-3 of r's peak line taken as zero, as
    :func:`~mr_ident.numerics.excitation.bla.excited_lines` does): from the design, not from u,
    which carries the loop's noise and transient at every bin.

    Parameters
    ----------
    r, u : ndarray, shape (R, P * N)
        The reference and the plant input of R realizations of P periods (steady state),
        one channel.
    y_low : ndarray, shape (R, P * N / F)
        The output at samples ``phase``, ``phase + F``, ... of the same records.
    period, ratio : int
        N (a multiple of F) and F.
    phase : int
        q, the high-rate sample of the first low-rate output (0..F-1).
    rcond : float
        Singular-value floor of the alias rows (relative to the largest), below which a
        lifted bin counts as not excited.

    Returns
    -------
    SlowPlant
    """
    ra = np.atleast_2d(np.asarray(r, float))
    ua = np.atleast_2d(np.asarray(u, float))
    ya = np.atleast_2d(np.asarray(y_low, float))
    F, N = int(ratio), int(period)
    if F < 1 or N % F or not 0 <= phase < F:
        raise ConfigError(
            f"period must be a multiple of ratio F >= 1 and phase in 0..F-1; got period {N}, "
            f"F {F}, phase {phase}"
        )
    M = N // F
    if (
        ua.shape[1] % N
        or ra.shape != ua.shape
        or ya.shape[0] != ua.shape[0]
        or ya.shape[1] * F != ua.shape[1]
    ):
        raise DimensionError(
            f"r and u must be (R, P*N) with N = {N} and y_low (R, P*N/F) with F = {F}; got "
            f"{ra.shape}, {ua.shape} and {ya.shape}"
        )
    R, P = ua.shape[0], ua.shape[1] // N
    U = np.fft.fft(ua.reshape(R, P, N).mean(axis=1), axis=1)  # (R, N)
    Yp = np.fft.fft(ya.reshape(R, P, M), axis=2)  # (R, P, M)
    Y = Yp.mean(axis=1)  # (R, M)
    var = (
        np.sum(np.abs(Yp - Y[:, None]) ** 2, axis=1) / (P - 1) / P
        if P > 1
        else np.full(Y.shape, np.nan)
    )
    kappa = unlift_bins(np.arange(M), F, N)  # (M, F) aliases of each bin
    w = np.exp(2j * np.pi * kappa * phase / N) / F
    A = U[:, kappa].transpose(1, 0, 2) * w[:, None, :]  # (M, R, F)
    Rf = np.fft.fft(ra.reshape(R, P, N).mean(axis=1), axis=1)
    Rf = np.where(np.abs(Rf) > 1e-3 * np.abs(Rf).max(), Rf, 0.0)
    s = np.linalg.svd(Rf[:, kappa].transpose(1, 0, 2), compute_uv=False)  # (M, min(R, F))
    full = (s.shape[1] == F) & (s[:, -1] > rcond * max(float(s.max()), 1e-300))
    pinv = np.linalg.pinv(A)  # (M, F, R)
    X = np.einsum("afr,ra->af", pinv, Y)  # (M, F): P_h(a + lM)
    cov = np.einsum("afr,ra,agr->afg", pinv, var, np.conj(pinv))
    sd = np.sqrt(np.real(np.einsum("aff->af", cov)))
    X[~full], sd[~full] = np.nan, np.nan
    # the lifted r -> u map over the realizations, then J = diag(P_h) S and its columns' norms
    Rk = Rf[:, kappa].transpose(1, 2, 0)  # (M, F, R)
    S = np.einsum("afr,arg->afg", U[:, kappa].transpose(1, 2, 0), np.linalg.pinv(Rk))
    J = X[:, :, None] * S  # (M, F, F): rows output aliases, columns input aliases
    gain = np.linalg.norm(J, axis=1)  # (M, F)
    with np.errstate(invalid="ignore", divide="ignore"):
        a_ = np.conj(J) * S  # d gain_l = Re(sum_i a_il dX_i) / gain_l
        gvar = 0.5 * np.real(np.einsum("afl,afg,agl->al", a_, cov, np.conj(a_))) / gain**2
    gsd = np.sqrt(np.maximum(gvar, 0.0))
    gain[~full], gsd[~full] = np.nan, np.nan
    lines = np.arange(1, N // 2 + 1)
    a, l_ = lines % M, lines // M
    keep = np.isfinite(X[a, l_])
    pick = (a[keep], l_[keep])
    return SlowPlant(lines[keep], X[pick], sd[pick], gain[pick], gsd[pick])
