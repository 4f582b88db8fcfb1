# SPDX-License-Identifier: Apache-2.0
"""Where a model is wrong: the model against the identified FRFs, bin by bin, in σ units.

The identified P̂_h with its std is held against the model's P_h, per bin the error in
σ units; with a controller also the identified lifted closed-loop maps J̃ (r→y) and S̃
(r→u) against the model's. A bin is *significant* when ``|P̂ - P|² / σ̂²`` exceeds the
``1 - alpha / n_tests`` quantile of its null distribution F(2, 2q) (complex Gaussian
error over a variance estimated with q degrees of freedom), Bonferroni-corrected over all
bins and entries, so that noise alone raises an alarm with probability at most ``alpha``.
The lowest n bins of a local fit (window half-width n) are not tested, nor counted in the
correction (:func:`~mr_ident.numerics.local.lpm.reaches_dc`, as the monitor's drift): their
window reaches DC and is one-sided, and where the plant bends fast there (an integrator's
1/f) the estimate's bias exceeds its std (measured on random loops whose model is exact:
the first bin flagged in 4 of 30 records at up to 85 σ, in steady state too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats
from numpy.typing import NDArray

from ...errors import DataFieldError
from ...numerics.arrays import FloatArray
from ...numerics.identify import identify
from ...numerics.lifted.loop import closed_loop_maps
from ...numerics.lifting import half_to_full
from ...numerics.local.lpm import dof as lpm_dof
from ...numerics.local.lpm import reaches_dc
from ...numerics.results import Identification
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .prediction import centred


@dataclass(frozen=True)
class Evidence:
    """The model against the identified FRFs, per bin in σ units.

    Attributes
    ----------
    frequency : ndarray, shape (K,)
        Hz, the bins where the plant was estimated.
    P_hat, P_std : ndarray, shape (K, n_y, n_u)
        Identified plant and its std (std of the complex entry).
    P_model : ndarray, shape (K, n_y, n_u)
    sigma_error : ndarray, shape (K,)
        ``max_entries |P̂ - P| / σ̂``, at every bin (the untested ones too: see ``tested``).
    threshold : float
        σ-error above which a bin is significant (the test in the module docstring).
    significant : ndarray of bool, shape (K,)
        Above the threshold at a tested bin: False at the bins not tested (``tested``).
    loop_frequency, loop_sigma_error : ndarray, shape (K_l,)
        The same for the lifted maps J̃ and S̃ (max over their entries) at the tested
        low-rate bins (those whose window reaches DC left out); empty without a controller.
    loop_threshold : float
    loop_significant : ndarray of bool, shape (K_l,)
    dof : int
        Degrees of freedom q of the variance estimate.
    tested : ndarray of bool, shape (K,)
        The bins tested and counted in the correction: not those whose window reaches DC
        (module docstring).
    """

    frequency: FloatArray
    P_hat: NDArray[np.complex128]
    P_std: FloatArray
    P_model: NDArray[np.complex128]
    sigma_error: FloatArray
    threshold: float
    significant: NDArray[np.bool_]
    loop_frequency: FloatArray
    loop_sigma_error: FloatArray
    loop_threshold: float
    loop_significant: NDArray[np.bool_]
    dof: int
    tested: NDArray[np.bool_]

    def bands(self, merge_hz: float | None = None) -> list[tuple[float, float]]:
        """Significant frequency bands [(f_lo, f_hi), ...] in Hz, plant and loop maps together."""
        f = np.concatenate(
            [self.frequency[self.significant], self.loop_frequency[self.loop_significant]]
        )
        if f.size == 0:
            return []
        f = np.unique(f)
        df = float(np.min(np.diff(self.frequency))) if self.frequency.size > 1 else 1.0
        gap = merge_hz if merge_hz is not None else 3.0 * df
        out = []
        lo = hi = f[0]
        for x in f[1:]:
            if x - hi > gap:
                out.append((float(lo), float(hi)))
                lo = x
            hi = x
        out.append((float(lo), float(hi)))
        return out

    @property
    def median_sigma_error(self) -> float:
        """Median σ-error of the plant over its bins."""
        return float(np.nanmedian(self.sigma_error))


def threshold(alpha: float, n_tests: int, dof: int) -> float:
    """σ-error bound: sqrt of the F(2, 2 dof) quantile at 1 - alpha/n_tests."""
    return float(np.sqrt(scipy.stats.f.isf(alpha / max(n_tests, 1), 2, 2 * dof)))


def periodic_plant(rec: LoopData) -> tuple[NDArray, NDArray, NDArray, NDArray, int]:
    """Plant at the excited lines of a periodic record from the period means (F = 1, by entry).

    Returns the line indices (per period), P̂ (K, n_y, n_u), its std, J and S are not formed.
    The std of the complex entry follows from the sample (co)variances over periods
    (first-order, Pintelon & Schoukens 2012, ch. 2); q = periods - 1.
    """
    Pn = rec.period
    assert Pn is not None
    n_per = rec.n_samples // Pn - 1  # the first period is transient
    r, u, y = (x[Pn:].reshape(n_per, Pn, -1) for x in (rec.r, rec.u, rec.y))
    R, U, Y = (np.fft.rfft(x, axis=1) / math.sqrt(Pn) for x in (r, u, y))
    Rm = R.mean(axis=0)  # (L, n_r)
    lines = np.nonzero(np.abs(Rm[:, 0]) > 1e-3 * np.abs(Rm[:, 0]).max())[0]
    lines = lines[lines > 0]
    if u.shape[2] != 1:
        raise DataFieldError("periodic ({period}) validation supports one input channel", "period")
    Um, Ym = U.mean(axis=0)[lines], Y.mean(axis=0)[lines]  # (K, 1), (K, n_y)
    P = Ym / Um  # (K, n_y)
    dU = U[:, lines] - Um[None]
    dY = Y[:, lines] - Ym[None]
    var_u = np.mean(np.abs(dU) ** 2, axis=0) * n_per / (n_per - 1) / n_per  # of the mean
    var_y = np.mean(np.abs(dY) ** 2, axis=0) * n_per / (n_per - 1) / n_per
    cov_yu = np.mean(dY * np.conj(dU), axis=0) * n_per / (n_per - 1) / n_per
    var_P = (var_y + np.abs(P) ** 2 * var_u - 2 * np.real(np.conj(P) * cov_yu)) / np.abs(Um) ** 2
    return lines, P[:, :, None], np.sqrt(np.maximum(var_P, 0.0))[:, :, None], Rm, n_per - 1


def _rowmax(z: FloatArray) -> FloatArray:
    """The largest finite entry of each bin, (K,); NaN where a bin has none (not determined)."""
    flat = z.reshape(z.shape[0], -1)
    ok = np.isfinite(flat).any(axis=1)
    return np.where(ok, np.max(np.where(np.isfinite(flat), flat, -np.inf), axis=1), np.nan)


def identify_record(
    rec: LoopData, model: Model, *, n: int = 8, degree: int = 2
) -> Identification | None:
    """``freq-lifted`` identification of a record, r where the model's ``injection`` says.

    Lifted maps kept (None for periodic data, which is estimated from its periods instead).
    One run serves :func:`frf_evidence` for any model with the same controller structure and
    :func:`noise_spectrum`; its ``pfg`` is of the model's controller (beside ``pfg_data``,
    for :mod:`~mr_ident.numerics.lifted.pfg_check`).
    """
    if rec.period is not None:
        return None
    r, u, y = centred(rec, model)
    return identify(
        r,
        u,
        y,
        fs_high=rec.rates()[0],
        ratio=rec.rates()[1],
        method="freq-lifted",
        n=n,
        degree=degree,
        keep_lifted=True,
        injection=model.injection or "plant_input",
        **model.identify_arguments(rec.n_samples),
    )


def frf_evidence(
    model: Model,
    rec: LoopData,
    *,
    n: int = 8,
    degree: int = 2,
    alpha: float = 0.01,
    ident: Identification | None = None,
) -> Evidence:
    """Hold the model against the record's identification.

    Bin by bin (see the module docstring). ``ident``: :func:`identify_record` of ``rec``,
    computed when not given.
    """
    N = rec.n_samples
    empty = np.zeros(0)
    if rec.period is not None:
        lines, P_hat, P_std, _, dof = periodic_plant(rec)
        f = lines * rec.fs_high / rec.period
        P_model = model.plant_discrete().freqresp(f)
        loop = (empty, empty, math.inf, np.zeros(0, bool))
    else:
        ident = ident or identify_record(rec, model, n=n, degree=degree)
        assert ident is not None
        f = ident.plant.frequency
        P_hat, P_std = ident.plant.response, ident.plant.std
        P_model = model.plant_frf(N)[1:]
        dof = (
            ident.lifted_J.dof
            if ident.lifted_J is not None
            else lpm_dof(n, degree, model.n_u * model.ratio)
        )
        loop = (empty, empty, math.inf, np.zeros(0, bool))
        if (
            model.controller is not None
            and ident.lifted_J is not None
            and ident.lifted_S is not None
            and ident.lifted_J.ratio == model.ratio  # a setpoint's maps are not lifted
        ):
            J, S = ident.lifted_J, ident.lifted_S
            P_full = half_to_full(model.plant_frf(N), N)
            Jm, Sm = closed_loop_maps(
                P_full,
                model.controller_frf(N // model.ratio)[J.bins],
                J.bins,
                model.ratio,
                phase=model.sample_phase,
                delay=model.control_delay,
            )
            with np.errstate(divide="ignore", invalid="ignore"):
                zJ = np.abs(J.response - Jm) / J.std
                zS = np.abs(S.response - Sm) / S.std
            z = np.concatenate([zJ.reshape(zJ.shape[0], -1), zS.reshape(zS.shape[0], -1)], axis=1)
            keep = ~reaches_dc(J.bins, 1.0, n)  # the window reaches DC: not tested
            zl = np.nanmax(np.where(np.isfinite(z), z, np.nan)[keep], axis=1)
            thr_l = threshold(alpha, int(np.isfinite(z[keep]).sum()), dof)
            loop = (J.bins[keep] * rec.rates()[0] / N, zl, thr_l, zl > thr_l)
    with np.errstate(divide="ignore", invalid="ignore"):
        zP = np.abs(P_hat - P_model) / P_std
    # a local fit whose window reaches DC is one-sided there and biased beyond its std
    # where the plant bends fast (an integrator's 1/f): those bins are not tested
    f = np.asarray(f, float)
    untested = (
        reaches_dc(f, rec.rates()[0] / N, n) if rec.period is None else np.zeros(f.size, bool)
    )
    zP = np.where(np.isfinite(zP), zP, np.nan)
    z = _rowmax(zP)
    thr = threshold(alpha, int(np.isfinite(zP[~untested]).sum()), dof)
    return Evidence(
        f,
        P_hat,
        P_std,
        P_model,
        z,
        thr,
        (z > thr) & ~untested,
        loop[0],
        loop[1],
        loop[2],
        loop[3],
        dof,
        ~untested,
    )
