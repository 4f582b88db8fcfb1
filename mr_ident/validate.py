"""Model validation: where a nominal model is wrong, why, and how much a fix gains.

Given measured r_h, u_h, y_h and a nominal :class:`~mr_ident.model.Model`:

1. **Where** (:func:`frf_evidence`): the identified P̂_h with its std against the
   model's P_h, per bin the error in σ units; with a controller also the identified
   lifted closed-loop maps J̃ (r→y) and S̃ (r→u) against the model's. A bin is
   *significant* when ``|P̂ - P|² / σ̂²`` exceeds the ``1 - alpha / n_tests`` quantile
   of its null distribution F(2, 2q) (complex Gaussian error over a variance estimated
   with q degrees of freedom), Bonferroni-corrected over all bins and entries, so
   that noise alone raises an alarm with probability at most ``alpha`` (default 1 %).
2. **Why** (:func:`diagnose`): every cause of :data:`CAUSES` is a parametric
   extension of the model, fitted to the data by least squares on the whitened
   spectrum of the simulation residual y - ŷ (whitened by the residual spectrum of
   the model being extended, see :class:`_Objective`).
   Causes are ranked by the Bayesian information criterion
   ``BIC = 2 sum_k |E(k)|^2 / S(k) + p ln n`` (n the number of bins, p the cause's
   free parameters; lower is better). The model being extended is the cause ``none``
   (p = 0). A cause is accepted only when its BIC is below that of the model it
   extends; accepted causes are applied greedily (up to ``max_causes``), each step
   re-ranking the rest against the extended model.
3. **Gain** (:func:`gain`): fit % of y and u, and the FRF error in σ units, of the
   nominal and the extended model on validation data.

Simulation for the comparison: with a controller, the loop is simulated from the
measured r_h; without one (open loop), the plant is driven by the measured u_h. In
open loop the means of u and y are removed first (a linear model describes deviations
from the operating point; a constant current that balances friction is not modelled).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.stats
from numpy.typing import NDArray

from .errors import ConfigError, DataError
from .identify import identify
from .loop import closed_loop_maps
from .model import Model
from .results import Identification
from .pfg import half_to_full
from .simulate import LoopStream
from .systems import TransferMatrix

#: The cause vocabulary, in the order of the README table.
CAUSES: tuple[str, ...] = ("none", "gain_error", "input_delay", "extra_resonance", "resonance_shift",
                           "sampling_offset", "control_delay", "periodic_disturbance")

#: Parameters of each cause (names as in the report).
CAUSE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "none": (),
    "gain_error": ("gain",),
    "input_delay": ("delay_s",),
    "extra_resonance": ("frequency_hz", "damping"),
    "resonance_shift": ("frequency_hz", "damping"),
    "sampling_offset": ("offset_samples",),
    "control_delay": ("delay_samples",),
    "periodic_disturbance": ("frequency_hz", "amplitude"),
}

#: Free parameters counted in the BIC penalty (a disturbance also has a phase).
_N_FREE = {"none": 0, "gain_error": 1, "input_delay": 1, "extra_resonance": 2, "resonance_shift": 2,
           "sampling_offset": 1, "control_delay": 1, "periodic_disturbance": 3}


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class Record:
    """Measured signals, each (N, channels), and their rates.

    ``period`` (samples) marks a periodic excitation: the first period is treated as
    transient and the noise is estimated from the spread over periods.
    """

    r: NDArray[np.float64]
    u: NDArray[np.float64]
    y: NDArray[np.float64]
    fs_high: float
    ratio: int
    period: int | None = None

    @property
    def n_samples(self) -> int:
        return int(self.r.shape[0])

    def part(self, start: int, stop: int) -> Record:
        return replace(self, r=self.r[start:stop], u=self.u[start:stop], y=self.y[start:stop])


def check_record(model: Model, rec: Record, *, n: int = 8, what: str = "data") -> None:
    """Model and data must agree on rates and channels, and the data must be long enough.

    Raises
    ------
    DataError
    """
    if not math.isclose(rec.fs_high, model.fs_high, rel_tol=1e-9):
        raise DataError(f"{what}: fs_high is {rec.fs_high:g} Hz but the model says {model.fs_high:g} Hz")
    if rec.ratio != model.ratio:
        raise DataError(f"{what}: the ratio F is {rec.ratio} but the model says {model.ratio}")
    if rec.u.shape[1] != model.n_u or rec.y.shape[1] != model.n_y:
        raise DataError(f"{what} has {rec.u.shape[1]} input and {rec.y.shape[1]} output channels; "
                        f"the model has n_u={model.n_u}, n_y={model.n_y}")
    if rec.period is not None:
        if rec.period < 2 or rec.n_samples % rec.period or rec.n_samples // rec.period < 4:
            raise DataError(f"{what}: period {rec.period} must divide N = {rec.n_samples} into at least "
                            f"4 periods (the first is dropped as transient)")
        return
    need = 4 * (2 * n + 1) * model.ratio
    if rec.n_samples < need:
        raise DataError(f"{what} is too short for the LPM window: N = {rec.n_samples} samples, "
                        f"need at least {need} (4 x (2n+1) x F with n = {n})")


def split(rec: Record, fraction: float = 0.7) -> int:
    """Sample index where the estimation part ends and the held-out part begins.

    The first ``fraction`` of the record, rounded down to whole periods (periodic data)
    or to a multiple of F.
    """
    unit = rec.period if rec.period else rec.ratio
    return int(rec.n_samples * fraction) // unit * unit


# --------------------------------------------------------------------------- simulation


@dataclass(frozen=True)
class Prediction:
    """Simulated (u, y) for a record, and the samples compared (from ``skip`` on)."""

    u: NDArray[np.float64]
    y: NDArray[np.float64]
    skip: int


def _centred(rec: Record, model: Model) -> tuple[NDArray, NDArray, NDArray]:
    if model.controller is None:
        return rec.r, rec.u - rec.u.mean(axis=0), rec.y - rec.y.mean(axis=0)
    return rec.r, rec.u, rec.y


def predict(model: Model, rec: Record) -> Prediction:
    """Simulate ``model`` on the measured excitation of ``rec`` (see the module docstring)."""
    r, u, _ = _centred(rec, model)
    if model.controller is None:
        _, y_hat = LoopStream(model).next(u)
        u_hat = u
    else:
        u_hat, y_hat = LoopStream(model).next(r)
    return Prediction(u_hat, y_hat, rec.period or 0)


def fit_percent(measured: NDArray, simulated: NDArray) -> float:
    """MATLAB ``compare`` fit: ``100 (1 - |y - y_hat| / |y - mean y|)``, averaged over channels."""
    e = np.linalg.norm(measured - simulated, axis=0)
    d = np.linalg.norm(measured - measured.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.mean(100.0 * (1.0 - e / d)))


@dataclass(frozen=True)
class TimeFit:
    """Fit % of y and u (u is None in open loop, where the measured u drives the model)."""

    y: float
    u: float | None


def time_fit(model: Model, rec: Record, start: int = 0, pred: Prediction | None = None) -> TimeFit:
    """Fit % of the model's simulated y (and u) against ``rec`` from sample ``start`` on
    (``pred``: the model's :func:`predict` on ``rec`` when already at hand)."""
    pred = pred or predict(model, rec)
    _, u, y = _centred(rec, model)
    s = max(start, pred.skip)
    fy = fit_percent(y[s:], pred.y[s:])
    fu = None if model.controller is None else fit_percent(u[s:], pred.u[s:])
    return TimeFit(fy, fu)


# --------------------------------------------------------------------------- frequency evidence


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
        ``max_entries |P̂ - P| / σ̂``.
    threshold : float
        σ-error above which a bin is significant (the test in the module docstring).
    significant : ndarray of bool, shape (K,)
    loop_frequency, loop_sigma_error : ndarray, shape (K_l,)
        The same for the lifted maps J̃ and S̃ (max over their entries) at low-rate
        bins; empty without a controller.
    loop_threshold : float
    loop_significant : ndarray of bool, shape (K_l,)
    dof : int
        Degrees of freedom q of the variance estimate.
    """

    frequency: NDArray[np.float64]
    P_hat: NDArray[np.complex128]
    P_std: NDArray[np.float64]
    P_model: NDArray[np.complex128]
    sigma_error: NDArray[np.float64]
    threshold: float
    significant: NDArray[np.bool_]
    loop_frequency: NDArray[np.float64]
    loop_sigma_error: NDArray[np.float64]
    loop_threshold: float
    loop_significant: NDArray[np.bool_]
    dof: int

    def bands(self, merge_hz: float | None = None) -> list[tuple[float, float]]:
        """Significant frequency bands [(f_lo, f_hi), ...] in Hz, plant and loop maps together."""
        f = np.concatenate([self.frequency[self.significant], self.loop_frequency[self.loop_significant]])
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
        return float(np.nanmedian(self.sigma_error))


def _threshold(alpha: float, n_tests: int, dof: int) -> float:
    """σ-error bound: sqrt of the F(2, 2 dof) quantile at 1 - alpha/n_tests."""
    return float(np.sqrt(scipy.stats.f.isf(alpha / max(n_tests, 1), 2, 2 * dof)))


def _periodic_plant(rec: Record) -> tuple[NDArray, NDArray, NDArray, NDArray, int]:
    """Plant at the excited lines of a periodic record from the period means (F = 1, SISO-by-entry).

    Returns the line indices (per period), P̂ (K, n_y, n_u), its std, J and S are not formed.
    The std of the complex entry follows from the sample (co)variances over periods
    (first-order, Pintelon & Schoukens 2012, ch. 2); q = periods - 1.
    """
    Pn = rec.period
    assert Pn is not None
    n_per = rec.n_samples // Pn - 1                    # the first period is transient
    r, u, y = (x[Pn:].reshape(n_per, Pn, -1) for x in (rec.r, rec.u, rec.y))
    R, U, Y = (np.fft.rfft(x, axis=1) / math.sqrt(Pn) for x in (r, u, y))
    Rm = R.mean(axis=0)                                                  # (L, n_r)
    lines = np.nonzero(np.abs(Rm[:, 0]) > 1e-3 * np.abs(Rm[:, 0]).max())[0]
    lines = lines[lines > 0]
    if u.shape[2] != 1:
        raise DataError("periodic (--period) validation supports one input channel")
    Um, Ym = U.mean(axis=0)[lines], Y.mean(axis=0)[lines]              # (K, 1), (K, n_y)
    P = Ym / Um                                                          # (K, n_y)
    dU = U[:, lines] - Um[None]
    dY = Y[:, lines] - Ym[None]
    var_u = np.mean(np.abs(dU) ** 2, axis=0) * n_per / (n_per - 1) / n_per     # of the mean
    var_y = np.mean(np.abs(dY) ** 2, axis=0) * n_per / (n_per - 1) / n_per
    cov_yu = np.mean(dY * np.conj(dU), axis=0) * n_per / (n_per - 1) / n_per
    var_P = (var_y + np.abs(P) ** 2 * var_u - 2 * np.real(np.conj(P) * cov_yu)) / np.abs(Um) ** 2
    return lines, P[:, :, None], np.sqrt(np.maximum(var_P, 0.0))[:, :, None], Rm, n_per - 1


def identify_record(rec: Record, model: Model, *, n: int = 8, degree: int = 2) -> Identification | None:
    """``freq-lifted`` identification of a record, lifted maps kept (None for periodic data,
    which is estimated from its periods instead). One run serves :func:`frf_evidence` for
    any model with the same controller structure and :func:`noise_spectrum`."""
    if rec.period is not None:
        return None
    _, u, y = _centred(rec, model)
    return identify(rec.r, u, y, fs_high=rec.fs_high, ratio=rec.ratio, method="freq-lifted", n=n,
                    degree=degree, keep_lifted=True)


def frf_evidence(model: Model, rec: Record, *, n: int = 8, degree: int = 2, alpha: float = 0.01,
                 ident: Identification | None = None) -> Evidence:
    """Hold the model against the record's identification, bin by bin (see the module
    docstring). ``ident``: :func:`identify_record` of ``rec``, computed when not given."""
    N = rec.n_samples
    empty = np.zeros(0)
    if rec.period is not None:
        lines, P_hat, P_std, _, dof = _periodic_plant(rec)
        f = lines * rec.fs_high / rec.period
        P_model = model.plant_discrete().freqresp(f)
        loop = (empty, empty, math.inf, np.zeros(0, bool))
    else:
        K_low = model.controller_frf(N // model.ratio) if model.controller is not None else None
        ident = ident or identify_record(rec, model, n=n, degree=degree)
        assert ident is not None
        f = ident.plant.frequency
        P_hat, P_std = ident.plant.response, ident.plant.std
        P_model = model.plant_frf(N)[1:]
        dof = 2 * n + 1 - (degree + 1) * (model.n_u * model.ratio + 1)
        loop = (empty, empty, math.inf, np.zeros(0, bool))
        if model.controller is not None and ident.lifted_J is not None and ident.lifted_S is not None:
            J, S = ident.lifted_J, ident.lifted_S
            P_full = half_to_full(model.plant_frf(N), N)
            Jm, Sm = closed_loop_maps(P_full, K_low[J.bins], J.bins, model.ratio,        # type: ignore[index]
                                      phase=model.sample_phase, delay=model.control_delay)
            with np.errstate(divide="ignore", invalid="ignore"):
                zJ = np.abs(J.response - Jm) / J.std
                zS = np.abs(S.response - Sm) / S.std
            z = np.concatenate([zJ.reshape(zJ.shape[0], -1), zS.reshape(zS.shape[0], -1)], axis=1)
            keep = J.bins > 0
            zl = np.nanmax(np.where(np.isfinite(z), z, np.nan)[keep], axis=1)
            thr_l = _threshold(alpha, int(np.isfinite(z[keep]).sum()), dof)
            loop = (J.bins[keep] * rec.fs_high / N, zl, thr_l, zl > thr_l)
    with np.errstate(divide="ignore", invalid="ignore"):
        zP = np.abs(P_hat - P_model) / P_std
    zP = np.where(np.isfinite(zP), zP, np.nan)
    z = np.nanmax(zP.reshape(zP.shape[0], -1), axis=1) if zP.size else np.zeros(0)
    thr = _threshold(alpha, int(np.isfinite(zP).sum()), dof)
    return Evidence(np.asarray(f, float), P_hat, P_std, P_model, z, thr, z > thr,
                    loop[0], loop[1], loop[2], loop[3], dof)


# --------------------------------------------------------------------------- causes


@dataclass(frozen=True)
class CauseFit:
    """One cause fitted to the data.

    Attributes
    ----------
    cause : str
    parameters : dict
        Named as in :data:`CAUSE_PARAMETERS`.
    score : float
        BIC (lower is better).
    rss : dict
        Residual sum of squares of y (and u in closed loop).
    model : Model
        The model extended by this cause.
    applicable : bool
        False when the cause cannot occur in this loop (e.g. sampling_offset without a
        controller or with F = 1); then ``score`` is inf.
    """

    cause: str
    parameters: dict[str, float]
    score: float
    rss: dict[str, float]
    model: Model
    applicable: bool = True


def noise_spectrum(rec: Record, model: Model, *, n: int = 8, degree: int = 2,
                   ident: Identification | None = None) -> NDArray[np.float64]:
    """Noise variance of y on the bins of ``rfft(y[skip:], norm="ortho")``, shape (n_bins, n_y).

    Independent of any model: from the LPM noise covariance of the r -> y fit (the part of
    y that r does not explain: in closed loop the noise as the loop shapes it), or, for
    periodic data, from the spread of y over periods (interpolated to the record's bins).
    Smoothed by a running median over 33 bins, corrected to a mean, so that a single
    sinusoid does not mask itself. ``ident``: :func:`identify_record` of ``rec``, computed
    when not given.
    """
    _, u, y = _centred(rec, model)
    if rec.period is not None:
        Pn = rec.period
        n_per = rec.n_samples // Pn - 1
        Y = np.fft.rfft(y[Pn:].reshape(n_per, Pn, -1), axis=1, norm="ortho")
        var = np.var(Y, axis=0, ddof=1).real if n_per > 1 else np.abs(Y[0]) ** 2    # (Pn//2+1, n_y)
        n_bins = (rec.n_samples - Pn) // 2 + 1
        line = np.rint(np.arange(n_bins) * Pn / (rec.n_samples - Pn)).astype(int)
        S = var[np.minimum(line, var.shape[0] - 1)]
        dof = 2 * (n_per - 1)
    else:
        ident = ident or identify_record(rec, model, n=n, degree=degree)
        assert ident is not None
        J = ident.lifted_J
        assert J is not None
        F, N, ny = rec.ratio, rec.n_samples, y.shape[1]
        M = N // F
        cv = np.real(np.diagonal(J.row_cov, axis1=1, axis2=2)).reshape(-1, F, ny)   # (K, F, n_y)
        S = np.full((N // 2 + 1, ny), np.nan)
        kappa = J.bins[:, None] + M * np.arange(F)[None, :]
        kappa = np.minimum(kappa, N - kappa)
        S[kappa.ravel()] = cv.reshape(-1, ny)
        dof = 2 * (2 * n + 1 - (degree + 1) * (rec.u.shape[1] * F + 1))
    S = np.where(np.isfinite(S) & (S > 0), S, np.nan)
    fill = np.nanmedian(S, axis=0) if np.any(np.isfinite(S)) else np.ones(S.shape[1])
    S = np.where(np.isnan(S), fill, S)
    med = scipy.ndimage.median_filter(S, size=(33, 1), mode="nearest")
    S = med * dof / scipy.stats.chi2.median(dof)
    return np.maximum(S, 1e-30 * max(float(S.max()), 1e-300))


class _Objective:
    """Whitened residuals of a model family on the estimation record.

    The spectrum ``E(k)`` of y - ŷ (``rfft``, orthonormal) is divided by the noise std
    of :func:`noise_spectrum`, so that the bins are independent with unit variance when
    the model is right: least squares is then efficient and
    ``-2 log L = 2 sum |E|^2 / S`` enters the BIC with the number of bins as the sample
    size. Only y - ŷ enters: in closed loop u - û is the same noise filtered by the loop
    (one noise source), so counting it too would double the evidence, noise included.
    """

    def __init__(self, rec: Record, base: Model, noise: NDArray[np.float64],
                 plant: tuple[NDArray, NDArray] | None = None):
        self.rec = rec
        self.base = base
        self.plant = plant            # (frequency, P̂) of the record, for starting guesses
        _, u, y = _centred(rec, base)
        self.u, self.y = u, y
        self.skip = rec.period or 0
        self.closed = base.controller is not None
        if self._raw(base) is None:
            raise DataError("the model cannot be simulated on this data (the loop is not stable)")
        self.weight = 1.0 / np.sqrt(noise)
        self.n_bins = int(self.weight.size)

    def _raw(self, model: Model) -> list[NDArray] | None:
        with warnings.catch_warnings():
            warnings.simplefilter("error")          # unstable or defective candidates are rejected
            try:
                pred = predict(model, self.rec)
            except (ArithmeticError, ValueError, RuntimeWarning, np.linalg.LinAlgError):
                return None
        s = self.skip
        parts = [self.y[s:] - pred.y[s:], self.u[s:] - pred.u[s:]]
        if not all(np.all(np.isfinite(p_)) for p_ in parts):
            return None
        return parts

    def residuals(self, model: Model) -> NDArray[np.float64]:
        return self._whiten(self._raw(model))

    def _whiten(self, raw: list[NDArray] | None) -> NDArray[np.float64]:
        if raw is None:
            return np.full(2 * self.n_bins, 1e3)
        with np.errstate(all="ignore"):
            E = np.fft.rfft(raw[0], axis=0, norm="ortho") * self.weight
        res = np.concatenate([E.real.ravel(), E.imag.ravel()])
        ok = np.all(np.isfinite(res)) and float(np.max(np.abs(res), initial=0.0)) < 1e100
        return res if ok else np.full(2 * self.n_bins, 1e3)

    def evaluate(self, model: Model, p: int) -> tuple[float, dict[str, float]]:
        """BIC ``2 sum |E|^2 / S + p ln(n_bins)`` and the residual sums of squares of y
        (and u in closed loop), from one simulation."""
        raw = self._raw(model)
        bic = 2.0 * float(np.sum(self._whiten(raw) ** 2)) + p * math.log(self.n_bins)
        if raw is None:
            return bic, {"y": math.inf} | ({"u": math.inf} if self.closed else {})
        rss = {"y": float(np.sum(raw[0] ** 2))}
        if self.closed:
            rss["u"] = float(np.sum(raw[1] ** 2))
        return bic, rss


def _least_squares(obj: _Objective, build: Callable[[NDArray], Model], starts: list[list[float]],
                   lower: list[float], upper: list[float], scale: list[float]) -> tuple[NDArray, Model]:
    """Bounded least squares from several starts; the best end point and its model."""
    best: tuple[float, NDArray, Model] | None = None
    for x0 in starts:
        x0 = np.clip(np.asarray(x0, float), lower, upper)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                res = scipy.optimize.least_squares(lambda x: obj.residuals(build(x)), x0, bounds=(lower, upper),
                                                   x_scale=np.asarray(scale, float), max_nfev=100,
                                                   ftol=1e-10, xtol=1e-10, diff_step=1e-5)
            except (ValueError, np.linalg.LinAlgError):   # a start where the loop is unstable
                continue
        cost = float(res.cost)
        if best is None or cost < best[0]:
            best = (cost, res.x, build(res.x))
    if best is None:
        x0 = np.clip(np.asarray(starts[0], float), lower, upper)
        return x0, build(x0)
    return best[1], best[2]


def _modes(plant: TransferMatrix) -> list[tuple[float, float]]:
    """Lightly damped complex pole pairs of a continuous plant: (frequency_hz, damping)."""
    if plant.dt is not None:
        return []
    out = []
    for p in np.unique(np.round(plant.poles(), 9)):
        if p.imag > 0:
            w = abs(p)
            z = -p.real / w
            if z < 0.7:
                out.append((w / (2 * np.pi), z))
    return sorted(out)


def _shift_mode(model: Model, f0: float, z0: float, f: float, z: float) -> Model:
    """Move the plant's pole pair (f0, z0) to (f, z); numerators unchanged (so the high-frequency
    asymptote, e.g. the mass line, is kept)."""
    w0 = 2 * np.pi * f0
    target = -z0 * w0 + 1j * w0 * math.sqrt(max(1 - z0 * z0, 0.0))
    w = 2 * np.pi * f
    new = -z * w + 1j * w * math.sqrt(max(1 - z * z, 0.0))
    dens = []
    for row in model.plant.den:
        drow = []
        for a in row:
            roots = np.roots(a)
            hit = np.nonzero(np.abs(roots - target) < 1e-6 * max(abs(target), 1.0))[0]
            hitc = np.nonzero(np.abs(roots - np.conj(target)) < 1e-6 * max(abs(target), 1.0))[0]
            if hit.size and hitc.size:
                roots = roots.copy()
                roots[hit[0]], roots[hitc[0]] = new, np.conj(new)
                drow.append(tuple(float(c) for c in np.real(a[0] * np.poly(roots))))
            else:
                drow.append(tuple(a))
        dens.append(tuple(drow))
    return replace(model, plant=TransferMatrix(model.plant.num, tuple(dens), None))


def _residual_peak(obj: _Objective, base: Model) -> list[tuple[float, int, float]]:
    """Candidate disturbance frequencies: the largest peaks of the y residual's spectrum."""
    pred = predict(base, obj.rec)
    s = obj.skip
    e = obj.y[s:] - pred.y[s:]
    n = e.shape[0]
    nfft = 4 * n
    E = np.abs(np.fft.rfft(e * np.hanning(n)[:, None], n=nfft, axis=0))
    f = np.fft.rfftfreq(nfft, 1.0 / obj.rec.fs_high)
    out = []
    for o in range(E.shape[1]):
        k = int(np.argmax(E[1:, o])) + 1
        amp = 2.0 * E[k, o] / np.hanning(n).sum()
        out.append((float(f[k]), o, float(amp)))
    return out


def fit_cause(cause: str, rec: Record, base: Model, noise: NDArray[np.float64], *,
              ident: Identification | None = None) -> CauseFit:
    """Fit one cause of :data:`CAUSES` on ``rec``, extending ``base``; ``noise`` from
    :func:`noise_spectrum`, ``ident`` (optional) from :func:`identify_record` for
    starting guesses."""
    if cause not in CAUSES:
        raise ConfigError(f"cause must be one of {', '.join(CAUSES)}; got {cause!r}")
    return _fit_cause(cause, _objective(rec, base, noise, ident))


def _objective(rec: Record, base: Model, noise: NDArray[np.float64], ident: Identification | None) -> _Objective:
    plant = (ident.plant.frequency, ident.plant.response) if ident is not None else None
    return _Objective(rec, base, noise, plant)


def _fit_cause(cause: str, obj: _Objective) -> CauseFit:
    rec, base = obj.rec, obj.base
    fs, F = base.fs_high, base.ratio
    h = 1.0 / fs
    na = CauseFit(cause, {}, math.inf, {}, base, applicable=False)
    params: dict[str, float] = {}
    if cause == "none":
        model = base
    elif cause == "gain_error":
        x, model = _least_squares(obj, lambda x: replace(base, plant_gain=base.plant_gain * float(x[0])),
                                  [[1.0], [0.7], [1.4]], [0.05], [20.0], [0.1])
        params = {"gain": float(x[0])}
    elif cause == "input_delay":
        if base.plant.dt is not None:
            return na
        def build(x: NDArray) -> Model:
            return replace(base, input_delay=base.input_delay + float(x[0]))
        grid = [[k * h] for k in (0.25, 0.75, 1.5, 3.0, 6.0)]
        x, model = _least_squares(obj, build, _best_starts(obj, build, grid, 2), [0.0], [20 * h], [0.2 * h])
        params = {"delay_s": float(x[0])}
    elif cause in ("extra_resonance", "resonance_shift"):
        if base.plant.dt is not None:
            return na
        if cause == "extra_resonance":
            def build(x: NDArray) -> Model:
                return replace(base, extra_modes=base.extra_modes + ((float(x[0]), float(x[1])),))
            fgrid = np.geomspace(fs / 200, 0.45 * fs, 12)
            starts = [[f0, z0] for f0 in fgrid for z0 in (0.05, 1.0)]
            if obj.plant is not None and obj.plant[0].size:
                f_id, P_id = obj.plant
                ratio = np.abs(P_id / base.plant_discrete().freqresp(f_id)).reshape(f_id.size, -1).max(axis=1)
                k = int(np.nanargmax(ratio))
                starts = [[float(f_id[k]), float(np.clip(0.5 / max(ratio[k], 1.0), 0.005, 0.5))]] + starts
            x, model = _least_squares(obj, build, _best_starts(obj, build, starts, 3), [fs / 1000, 0.002],
                                      [0.499 * fs, 5.0], [fs / 1000, 0.01])
            params = {"frequency_hz": float(x[0]), "damping": float(x[1])}
        else:
            modes = _modes(base.plant)
            if not modes:
                return na
            best: tuple[float, NDArray, Model] | None = None
            for f0, z0 in modes:
                def build(x: NDArray, f0: float = f0, z0: float = z0) -> Model:
                    return _shift_mode(base, f0, z0, float(x[0]), float(x[1]))
                starts = [[f0 * s, z0] for s in (0.8, 0.9, 1.0, 1.1, 1.25)]
                x, m = _least_squares(obj, build, _best_starts(obj, build, starts, 2),
                                      [0.4 * f0, 0.001], [min(2.5 * f0, 0.499 * fs), 0.9], [0.01 * f0, 0.01])
                with np.errstate(over="ignore"):
                    cost = float(np.sum(obj.residuals(m) ** 2))
                if best is None or cost < best[0]:
                    best = (cost, x, m)
            assert best is not None
            x, model = best[1], best[2]
            params = {"frequency_hz": float(x[0]), "damping": float(x[1])}
    elif cause in ("sampling_offset", "control_delay"):
        if base.controller is None or (cause == "sampling_offset" and F == 1):
            return na
        cands = ([(o, replace(base, sample_phase=base.sample_phase + o))
                  for o in range(-base.sample_phase, F - base.sample_phase) if o != 0]
                 if cause == "sampling_offset" else
                 [(d, replace(base, control_delay=base.control_delay + d)) for d in range(1, 2 * F + 1)])
        scored = []
        for v, m in cands:
            with np.errstate(over="ignore"):
                scored.append((float(np.sum(obj.residuals(m) ** 2)), v, m))
        if not scored:
            return na
        _, v, model = min(scored, key=lambda t: t[0])
        params = {"offset_samples" if cause == "sampling_offset" else "delay_samples": float(v)}
    else:  # periodic_disturbance
        best_d: tuple[float, NDArray, Model, int] | None = None
        for f0, o, amp in _residual_peak(obj, base):
            def build(x: NDArray, o: int = o) -> Model:
                return replace(base, disturbances=base.disturbances + (
                    (float(x[0]), float(math.hypot(x[1], x[2])), float(math.atan2(x[2], x[1])), o),))
            df = fs / rec.n_samples
            x, m = _least_squares(obj, build, [[f0, amp, 0.0], [f0, 0.0, amp]],
                                  [max(f0 - 2 * df, 1e-6), -np.inf, -np.inf], [min(f0 + 2 * df, fs / 2), np.inf, np.inf],
                                  [0.1 * df, max(amp, 1e-12), max(amp, 1e-12)])
            with np.errstate(over="ignore"):
                cost = float(np.sum(obj.residuals(m) ** 2))
            if best_d is None or cost < best_d[0]:
                best_d = (cost, x, m, o)
        assert best_d is not None
        x, model = best_d[1], best_d[2]
        params = {"frequency_hz": float(x[0]), "amplitude": float(math.hypot(x[1], x[2]))}
    score, rss = obj.evaluate(model, _N_FREE[cause])
    return CauseFit(cause, params, score, rss, model)


def _best_starts(obj: _Objective, build: Callable[[NDArray], Model], starts: list[list[float]],
                 keep: int) -> list[list[float]]:
    """The ``keep`` starts with the smallest residual (a cheap grid before least squares)."""
    costs = []
    for x in starts:
        with np.errstate(over="ignore"):
            costs.append((float(np.sum(obj.residuals(build(np.asarray(x, float))) ** 2)), x))
    return [x for _, x in sorted(costs, key=lambda t: t[0])[:keep]] or starts[:1]


def rank_causes(rec: Record, base: Model, noise: NDArray[np.float64],
                causes: tuple[str, ...] = CAUSES, *, ident: Identification | None = None) -> list[CauseFit]:
    """Fit every cause and rank them by BIC (lowest first; inapplicable ones last)."""
    for c in causes:
        if c not in CAUSES:
            raise ConfigError(f"cause must be one of {', '.join(CAUSES)}; got {c!r}")
    obj = _objective(rec, base, noise, ident)
    fits = [_fit_cause(c, obj) for c in causes]
    return sorted(fits, key=lambda c: (not c.applicable, c.score))


# --------------------------------------------------------------------------- diagnosis


@dataclass(frozen=True)
class Diagnosis:
    """Everything :func:`diagnose` found.

    Attributes
    ----------
    cause : str
        The first accepted cause, or ``"none"``.
    parameters : dict
        Its fitted parameters.
    ranking : list of CauseFit
        All causes fitted against the nominal model, best first.
    applied : list of CauseFit
        The causes applied in turn (greedy), each fitted on top of the previous ones.
    extended : Model
        The nominal model with every applied cause.
    evidence_before : Evidence
        Nominal model against the estimation data.
    evidence_after : Evidence
        Extended model against the validation data.
    evidence_validation_before : Evidence
        Nominal model against the validation data.
    fit_before, fit_after : TimeFit
        On the validation data.
    estimation, validation : str
        Which data were used for what.
    """

    cause: str
    parameters: dict[str, float]
    ranking: list[CauseFit]
    applied: list[CauseFit]
    extended: Model
    evidence_before: Evidence
    evidence_validation_before: Evidence
    evidence_after: Evidence
    fit_before: TimeFit
    fit_after: TimeFit
    estimation: str
    validation: str
    traces: dict[str, Any] = field(default_factory=dict)


def diagnose(model: Model, data: Record, validation: Record | None = None, *, n: int = 8, degree: int = 2,
             alpha: float = 0.01, max_causes: int = 3, holdout: float = 0.3,
             names: tuple[str, str] = ("data", "validation data")) -> Diagnosis:
    """Where and why ``model`` disagrees with ``data``, the extended model, and its gain.

    Parameters
    ----------
    model : Model
        Nominal model.
    data : Record
        Measured data for estimation (and, without ``validation``, its last
        ``holdout`` fraction is held out for validation).
    validation : Record, optional
        Independent validation data.
    n, degree : int
        LPM window half-width and degree for the frequency-domain evidence.
    alpha : float
        Family-wise false-alarm level of the per-bin test (default 0.01).
    max_causes : int
        Most causes applied in turn.
    names : (str, str)
        What to call ``data`` and ``validation`` in error messages (e.g. their files).

    Raises
    ------
    DataError
        Model and data disagree on rates or channels, or the data are too short.
    """
    if not 0.0 < alpha < 1.0:
        raise ConfigError(f"alpha must be in (0, 1), got {alpha!r}")
    if not 0.05 <= holdout <= 0.5:
        raise ConfigError(f"holdout must be in [0.05, 0.5], got {holdout!r}")
    check_record(model, data, n=n, what=names[0])
    if validation is not None:
        check_record(model, validation, n=n, what=names[1])
        est, val, val_start = data, validation, 0
        est_desc = f"all of DATA ({data.n_samples} samples)"
        val_desc = f"the validation data ({validation.n_samples} samples)"
    else:
        cut = split(data, 1.0 - holdout)
        est = data.part(0, cut)
        val, val_start = data, cut
        check_record(model, est, n=n, what=f"the estimation part of {names[0]}")
        est_desc = f"samples 0..{cut - 1} of DATA (the first {100 * (1 - holdout):.0f} %)"
        val_desc = (f"samples {cut}..{data.n_samples - 1} of DATA (the last {100 * holdout:.0f} %, held out; "
                    f"simulated over the whole record so the state carries over)")
    if val_start and val.period is None and val.n_samples - val_start < 4 * (2 * n + 1) * model.ratio:
        raise DataError(f"the held-out part of {names[0]} ({val.n_samples - val_start} samples) "
                        "is too short for the LPM window")
    ident = identify_record(est, model, n=n, degree=degree)
    ev_before = frf_evidence(model, est, n=n, degree=degree, alpha=alpha, ident=ident)
    noise = noise_spectrum(est, model, n=n, degree=degree, ident=ident)
    ranking = rank_causes(est, model, noise, ident=ident)
    none_score = next(c.score for c in ranking if c.cause == "none")
    applied: list[CauseFit] = []
    current, current_score = model, none_score
    step = ranking
    repeatable = ("extra_resonance", "periodic_disturbance")
    for _ in range(max_causes):
        done = {c.cause for c in applied}
        best = next((c for c in step if c.applicable and c.cause != "none"
                     and (c.cause not in done or c.cause in repeatable)), None)
        if best is None or not best.score < current_score:
            break
        applied.append(best)
        current = best.model
        step = rank_causes(est, current, noise, ident=ident)
        current_score = next(c.score for c in step if c.cause == "none")
    val_part = val.part(val_start, val.n_samples) if val_start else val
    pred_b, pred_a = predict(model, val), predict(current, val)
    fit_before = time_fit(model, val, val_start, pred_b)
    fit_after = time_fit(current, val, val_start, pred_a)
    ident_val = identify_record(val_part, model, n=n, degree=degree)
    ev_val_before = frf_evidence(model, val_part, n=n, degree=degree, alpha=alpha, ident=ident_val)
    ev_after = frf_evidence(current, val_part, n=n, degree=degree, alpha=alpha, ident=ident_val)
    _, _, y_meas = _centred(val, model)
    traces = {"start": max(val_start, pred_b.skip), "y": y_meas, "y_before": pred_b.y, "y_after": pred_a.y,
              "fs_high": val.fs_high}
    first = applied[0] if applied else None
    return Diagnosis(first.cause if first else "none", dict(first.parameters) if first else {},
                     ranking, applied, current, ev_before, ev_val_before, ev_after, fit_before, fit_after,
                     est_desc, val_desc, traces)
