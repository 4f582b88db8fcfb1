# SPDX-License-Identifier: Apache-2.0
"""The noise spectrum of a record, from the data alone (no model)."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.ndimage
import scipy.stats

from ...numerics.arrays import FloatArray, IntArray
from ...numerics.excitation.bla import excited_lines, unexcited_lines
from ...numerics.results import Identification
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .evidence import identify_record
from .prediction import centred

#: A bin of the LPM noise above this many times its far neighbours' median is a plateau
#: (a sinusoid that r does not explain), not noise.
PLATEAU_CAP = 3.0
#: Least noise gain kept, relative to its median (where integral action rejects the
#: noise at DC the gain is 0: the weight there stays finite).
GAIN_FLOOR = 1e-4


def loop_noise_gain(
    model: Model, n_samples: int, variances: FloatArray | None = None
) -> FloatArray:
    """Power gain from white output noise to the measured y, bins 0..N//2, (N//2+1, n_y).

    In closed loop the noise reaches y through the loop: lifted, ``ỹ = T̃ ṽ`` with
    ``T̃ = I - J̃ C̃`` (J̃ the lifted r -> y map, C̃ the lifted controller), so white noise of
    unit variance per sample gives at alias i of lifted bin k the power
    ``sum_j |T̃(k)[i, j]|²`` (F = 1: ``|1/(1 + P K)|²``); with ``variances`` (n_y,), each
    output's own, ``sum_j |T̃(k)[i, j]|² σ_j²`` (a coupled loop carries one output's noise
    into the others). Its narrow peaks are the loop's lightly damped poles, which no
    window of bins resolves (a pole 1 % damped is a bin wide in a 30 s record). Ones (the
    variances) in open loop; at least :data:`GAIN_FLOOR` of its median.
    """
    from ...numerics.lifted.loop import closed_loop_maps, lifted_controller
    from ...numerics.lifting import unlift_bins

    N = int(n_samples)
    var = np.ones(model.n_y) if variances is None else np.asarray(variances, float)
    if model.controller is None or N % model.ratio:
        return np.ones((N // 2 + 1, model.n_y)) * var
    F, M, ny = model.ratio, N // model.ratio, model.n_y
    P = model.plant_discrete().freqresp(np.arange(N) * model.fs_high / N)
    K = model.controller_frf(M)
    bins = np.arange(M)
    kw = {"phase": model.sample_phase, "delay": model.control_delay}
    with np.errstate(all="ignore"):
        J, _ = closed_loop_maps(P, K, bins, F, **kw)
        C = lifted_controller(K, bins, F, N, **kw)
        T = np.eye(F * ny)[None] - J @ C
        power = np.abs(T) ** 2
        if variances is not None:  # input j = (alias, output): that output's variance
            power = power * np.tile(var, F)[None, None, :]
        g = np.sum(power, axis=2).reshape(M, F, ny)  # (k, alias, output)
    full = np.empty((N, ny))
    full[unlift_bins(bins, F, N)] = g
    out = full[: N // 2 + 1]
    med = np.nanmedian(out, axis=0)
    out = np.where(np.isfinite(out), out, med)
    return np.maximum(out, GAIN_FLOOR * med)


def _ring_median(S: FloatArray, inner: int, width: int) -> FloatArray:
    """Per column, the median of the bins ``inner`` to ``inner + width - 1`` away, both sides."""
    ring = np.zeros((2 * (inner + width) - 1, 1), bool)
    ring[:width] = ring[-width:] = True
    return np.asarray(scipy.ndimage.median_filter(S, footprint=ring, mode="nearest"))


def noise_spectrum(
    rec: LoopData,
    model: Model,
    *,
    n: int = 8,
    degree: int = 2,
    ident: Identification | None = None,
    shaped: bool = True,
) -> FloatArray:
    """The noise level of y on the bins of ``rfft(y[skip:], norm="ortho")``, (n_bins, n_y).

    From the LPM noise covariance of the r -> y fit (the part of y that r does not
    explain: in closed loop the noise as the loop shapes it), divided by the nominal loop's
    :func:`loop_noise_gain` (the shaping, whose lightly damped peaks are narrower than any
    window of bins: a 1 %-damped closed-loop pole is one bin wide in 30 s), so that what is
    smoothed is smooth; the criterion multiplies the gain back on its own bins
    (:class:`~mr_ident.diagnosis.criterion.objective.Objective`). Open loop and periodic data: the
    spectrum itself, for periodic data from the spread of y over periods (interpolated to
    the record's bins).
    Smoothed by a running median over 33 bins, corrected to a mean. A sinusoid that r does
    not explain enters the LPM noise of every window that holds it, a plateau of 2n + 1
    bins at each of its aliases, which a 33-bin median keeps; so each bin is first capped
    at :data:`PLATEAU_CAP` times the median of its ring of neighbours 2n + 2 to 2n + 33
    bins away (outside any plateau it lies in). A closed-loop pole's hump, smooth over more
    bins, stays. ``ident``: :func:`identify_record` of ``rec``, computed when not given.
    ``shaped`` False: ``ident`` is of a model's output error ``y - P u``
    (:func:`~.matched.output_error`), whose residual is the noise before the loop shapes
    it: the level itself, not divided by the loop's gain.
    """
    _, u, y = centred(rec, model)
    if rec.period is not None:
        Pn = rec.period
        n_per = rec.n_samples // Pn - 1
        Y = np.fft.rfft(y[Pn:].reshape(n_per, Pn, -1), axis=1, norm="ortho")
        var = np.var(Y, axis=0, ddof=1).real if n_per > 1 else np.abs(Y[0]) ** 2  # (Pn//2+1, n_y)
        n_bins = (rec.n_samples - Pn) // 2 + 1
        line = np.rint(np.arange(n_bins) * Pn / (rec.n_samples - Pn)).astype(int)
        S = var[np.minimum(line, var.shape[0] - 1)]
        dof = 2 * (n_per - 1)
    else:
        ident = ident or identify_record(rec, model, n=n, degree=degree)
        assert ident is not None
        J = ident.lifted_J
        assert J is not None
        F, N, ny = J.ratio, rec.n_samples, y.shape[1]  # F = 1: a setpoint's high-rate fit
        M = N // F
        cv = np.real(np.diagonal(J.row_cov, axis1=1, axis2=2)).reshape(-1, F, ny)  # (K, F, n_y)
        S = np.full((N // 2 + 1, ny), np.nan)
        kappa = J.bins[:, None] + M * np.arange(F)[None, :]
        kappa = np.minimum(kappa, N - kappa)
        S[kappa.ravel()] = cv.reshape(-1, ny)
        dof = 2 * J.dof
    S = np.where(np.isfinite(S) & (S > 0), S, np.nan)
    unshaped = rec.period is not None or not shaped
    gain = np.ones(S.shape) if unshaped else loop_noise_gain(model, rec.n_samples)
    S = S / gain  # the level: the loop's sharp shaping divided out
    fill = np.nanmedian(S, axis=0) if np.any(np.isfinite(S)) else np.ones(S.shape[1])
    S = np.where(np.isnan(S), fill, S)
    if rec.period is None:
        S = np.minimum(S, PLATEAU_CAP * _ring_median(S, 2 * n + 2, 32))
    med = scipy.ndimage.median_filter(S, size=(33, 1), mode="nearest")
    S = med * dof / scipy.stats.chi2.median(dof)
    if rec.period is not None:
        S = S + distortion_floor(rec, y)  # periodic distortion counts as noise (the BLA's)
    return np.maximum(S, 1e-30 * max(float(S.max()), 1e-300))


def distortion_floor(rec: LoopData, y: FloatArray) -> FloatArray:
    """Nonlinear distortion's variance on the record's bins (periodic data), (n_bins, n_y).

    In a best linear approximation the stochastic nonlinear distortion acts as noise
    (Pintelon and Schoukens 2012, sec. 3.6), but it is periodic: the spread over periods
    does not see it. At the lines r does not excite it is measured directly, the power of
    the period mean less its noise part; at every line it is taken from the unexcited
    lines *of the same parity* nearby (:func:`parity_level`): with an odd design the
    excited lines carry odd distortion, which the odd detection lines measure, and the
    even lines, which only even distortion reaches, would say nothing about it. Amid a
    fully excited band (no unexcited line of that parity near) it cannot be measured: 0.
    In the record's DFT (P periods, orthonormal) a periodic component lies on every P-th
    bin with P times its period-DFT power; elsewhere it adds nothing.
    """
    Pn = rec.period
    assert Pn is not None
    n_per = rec.n_samples // Pn - 1  # the first period is transient
    n_bins = (rec.n_samples - Pn) // 2 + 1
    out = np.zeros((n_bins, y.shape[1]))
    if n_per < 2:
        return out
    R = np.fft.rfft(rec.r[Pn:, 0].reshape(n_per, Pn), axis=1)  # (P, L)
    Y = np.fft.rfft(y[Pn:].reshape(n_per, Pn, -1), axis=1, norm="ortho")  # (P, L, n_y)
    Ym = Y.mean(axis=0)
    var_mean = np.var(Y, axis=0, ddof=1) / n_per
    quiet = unexcited_lines(excited_lines(R[None]), Pn, rec.ratio or 1)
    excess = np.maximum(np.abs(Ym[quiet]) ** 2 - var_mean[quiet], 0.0)  # (Q, n_y)
    D = parity_level(quiet, excess, Ym.shape[0])
    b = np.arange(0, n_bins, n_per)
    out[b] = n_per * D[: b.size]
    return out


def parity_level(quiet: IntArray, excess: FloatArray, n_lines: int, near: int = 8) -> FloatArray:
    """Distortion power at every line 0..n_lines-1 from the unexcited lines ``quiet``.

    ``excess`` (Q, n_y): the power above the noise at each unexcited line. At line k: the
    median of ``excess`` over the ``near`` unexcited lines of k's parity nearest to k (within
    max(48, k/2) lines), divided by ln 2 (the power of a random-phase component at one
    line is exponential: its median is ln 2 times its mean); fewer than 3 such lines: 0.
    Noise alone gives 0 (the excess of an exponential over its mean is 0 at the median).
    """
    lines = np.arange(n_lines)
    D = np.zeros((n_lines, excess.shape[1]))
    for parity in (0, 1):  # odd lines from odd unexcited lines, even from even
        q = quiet[quiet % 2 == parity]
        at = lines[lines % 2 == parity]
        if q.size == 0 or at.size == 0:
            continue
        pos = np.searchsorted(q, at)
        idx = pos[:, None] + np.arange(-near // 2, near - near // 2)[None, :]  # (A, near)
        ok = (idx >= 0) & (idx < q.size)
        idx = np.clip(idx, 0, q.size - 1)
        ok &= np.abs(q[idx] - at[:, None]) <= np.maximum(48, at[:, None] // 2)
        vals = np.where(ok[:, :, None], excess[quiet % 2 == parity][idx], np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-nan rows: no neighbour
            med = np.nanmedian(vals, axis=1) / np.log(2.0)
        D[at] = np.where((ok.sum(axis=1) >= 3)[:, None] & np.isfinite(med), med, 0.0)
    return D
