# SPDX-License-Identifier: Apache-2.0
"""A stable MIMO model of an identified FRF: :func:`fit_frf` and :class:`FitResult`.

The cost is ``V = Σ |P̂ - G(θ)|² / σ²`` over the bins and entries (the ML cost for the
LPM's circular Gaussian errors); poles common to every entry; started by vector fitting
(:mod:`.start`), refined by variable projection (:mod:`.refine`). The expected cost at the
true order, N complex terms and p real parameters, errors independent with known σ:
``2V ~ χ²(2N - p)``, so ``E{V} = N - p/2``, ``sd{V} = sqrt(N - p/2)``. With the LPM's σ̂
estimated from q residual dof, ``E{1/σ̂²} = q/(q-1) / σ²`` scales both; the LPM's
neighbouring bins share their windows, which multiplies the variance by the correlation
length ``L = Σ_l ρ(l)²`` (:func:`lpm_kernel`, :func:`correlation_length`), and widens the
parameters' covariance the same way (a sandwich). The order chosen is the smallest whose
V lies within ``E{V} + 2 sd{V}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal, NamedTuple

import numpy as np

from ...errors import ConfigError, DataError
from ..arrays import ComplexArray, FloatArray
from ..results import FRF
from ..systems.modal import ModalPlant
from ..threads import one_blas_thread
from .basis import DOMAINS, columns, from_params, n_states, residues_of
from .refine import Problem, Solution, covariance
from .strategy import fit_order


@dataclass(frozen=True)
class OrderReport:
    """One order tried: its cost, the expected band, AIC, MDL and the delay found."""

    order: int
    cost: float
    expected: float
    sd: float
    aic: float
    mdl: float
    delay: float
    stable: bool

    @property
    def in_band(self) -> bool:
        """Whether the cost lies within ``expected ± 2 sd``."""
        return abs(self.cost - self.expected) <= 2.0 * self.sd


@dataclass(frozen=True)
class FitOptions:
    """The options of :func:`fit_frf` (its keywords, as given: checked by the fit)."""

    fs: float
    order: int | Literal["auto"] = "auto"
    domain: str = "continuous"
    delay: float | Literal["auto"] = 0.0
    band: tuple[float, float] | None = None
    direct: bool = False
    max_order: int = 20
    max_delay: float | None = None
    noise_dof: float | None = None
    noise_kernel: FloatArray | None = None


class _Candidate(NamedTuple):
    """One order fitted: its report, its solution and the condition of its start."""

    report: OrderReport
    solution: Solution
    start_cond: float


@dataclass(frozen=True)
class FitResult:
    """A fitted model of P_h with its uncertainty.

    Attributes
    ----------
    plant : ModalPlant
        Continuous (``domain`` "continuous": behind a ZOH at ``1/fs``) or discrete.
    delay : float
        Input delay in s (whole samples when discrete).
    domain : str
    fs : float
    frequency : ndarray, shape (K,)
        The bins fitted.
    residual : ndarray, shape (K, n_out, n_in), complex
        ``(P̂ - G) / σ`` on those bins.
    cost, expected, expected_sd : float
        V, E{V}, sd{V} at the fitted order.
    n_data, n_params : int
        Complex residual terms N and real parameters p.
    pole_std : ndarray, shape (n_p, 2)
        Std of Re and Im of each pole (in s or z).
    frequency_std, damping_std : ndarray, shape (n_p,)
        Std of each pole's natural frequency (Hz) and damping (of s = ln(z) fs if discrete).
    residue_std : ndarray, shape (n_p, n_out, n_in, 2)
        Std of Re and Im of each residue.
    c1_std, c0_std : ndarray, shape (n_p, n_out, n_in)
        Std of the modal numerator ``c1 x + c0`` of each pair (NaN for a real pole).
    delay_std : float
        0 when the delay was given. When ``delay_determined`` is False: the std the free
        delay had (the range it is not pinned within).
    orders : tuple of OrderReport
        Every order tried (one when the order was given).
    max_condition : float
        The largest condition number of the fit's linear least-squares steps: the
        residues' at the solution and every pole relocation of its starts (vector
        fitting's), each of the weighted columns scaled to unit norm (the square root of
        the scaled Gram's condition number). Above about 1e8 the linear steps lose digits.
    delay_determined : bool
        False when ``delay="auto"`` left the delay free but the data do not pin it: its std
        exceeded one sample and fixing it at 0 costs less than 2 sd{V}. The delay is then 0
        and the other parameters are those of that fit. (A plant whose response falls as
        1/s² or faster: ``d/dτ e^{-sτ} G = -s G e^{-sτ}`` is a change of the residues
        alone, so a small delay trades with them.)
    """

    plant: ModalPlant
    delay: float
    domain: str
    fs: float
    frequency: FloatArray
    residual: ComplexArray
    cost: float
    expected: float
    expected_sd: float
    n_data: int
    n_params: int
    pole_std: FloatArray
    frequency_std: FloatArray
    damping_std: FloatArray
    residue_std: FloatArray
    c1_std: FloatArray
    c0_std: FloatArray
    delay_std: float
    orders: tuple[OrderReport, ...]
    max_condition: float = 1.0
    delay_determined: bool = True

    @property
    def order(self) -> int:
        """States per input."""
        return self.plant.order

    @property
    def in_band(self) -> bool:
        """Whether the cost lies within ``expected ± 2 expected_sd``."""
        return abs(self.cost - self.expected) <= 2.0 * self.expected_sd

    @property
    def dof(self) -> int:
        """Real residual degrees of freedom ``2N - p``."""
        return 2 * self.n_data - self.n_params

    def response(self, frequency: FloatArray) -> ComplexArray:
        """The model's P_h (hold and delay included) at ``frequency`` Hz, (K, n_out, n_in)."""
        return hold_response(self.plant, self.delay, self.domain, self.fs, frequency)


def hold_response(
    plant: ModalPlant, delay: float, domain: str, fs: float, frequency: FloatArray
) -> ComplexArray:
    """P_h of a modal plant with input delay (ZOH at 1/fs when continuous)."""
    h = 1.0 / fs
    z = np.exp(2j * np.pi * np.asarray(frequency, dtype=float) * h)
    Phi = columns(plant.poles, z, domain, h, delay, direct=True)
    no, ni = plant.shape
    coef = []
    for p, R in zip(plant.poles, plant.residues, strict=True):
        coef += [R.real, R.imag] if p.imag > 0 else [R.real]
    coef.append(plant.direct)
    C = np.array(coef).reshape(len(coef), no * ni)
    return np.asarray((Phi @ C).reshape(z.size, no, ni), dtype=complex)


def lpm_kernel(n: int, degree: int = 2) -> FloatArray:
    """Correlation ``ρ(l)``, l = 0..2n, of LPM estimates l bins apart (window 2n+1, degree R).

    The centre value of a local polynomial is a weighted sum of the window's bins (the
    Savitzky–Golay weights a); neighbouring estimates share bins: ``ρ(l) = Σ a_r a_{r+l} /
    Σ a_r²``. ``[1]`` for n = 0 (independent bins).
    """
    if n <= 0:
        return np.ones(1)
    r = np.arange(-n, n + 1, dtype=float)
    a = np.linalg.pinv(np.vander(r / n, degree + 1, increasing=True))[0]
    rho = np.correlate(a, a, mode="full") / np.dot(a, a)
    return np.asarray(rho[2 * n :], dtype=float)


def correlation_length(kernel: FloatArray | None) -> float:
    """``Σ_l ρ(l)²`` over both signs of l: the variance factor of a sum of |errors|²."""
    if kernel is None:
        return 1.0
    k = np.asarray(kernel, dtype=float)
    return float(k[0] ** 2 + 2.0 * np.sum(k[1:] ** 2))


def expected_band(
    n_data: int, n_params: int, noise_dof: float | None, correlation: float
) -> tuple[float, float]:
    """``(E{V}, sd{V})`` (module docstring)."""
    k = 1.0 if noise_dof is None or noise_dof <= 1 else noise_dof / (noise_dof - 1.0)
    nu = max(n_data - n_params / 2.0, 1.0)
    return k * nu, k * math.sqrt(nu * max(correlation, 1.0))


def _select(
    frf: FRF, band: tuple[float, float] | None
) -> tuple[FloatArray, ComplexArray, FloatArray]:
    f, P, S = frf.frequency, frf.response, frf.std
    ok = (f > 0) & np.all(np.isfinite(P) & np.isfinite(S) & (S > 0), axis=(1, 2))
    if band is not None:
        lo, hi = band
        if not (0 <= lo < hi):
            raise ConfigError(f"band must be LO,HI with 0 <= LO < HI (Hz), got {band!r}")
        ok &= (f >= lo) & (f <= hi)
    if ok.sum() < 4:
        raise DataError(
            f"the FRF has {int(ok.sum())} bins with a positive finite std"
            f"{' in the band ' + repr(band) if band else ''}; a fit needs at least 4"
        )
    no, ni = P.shape[1:]
    return f[ok], P[ok].reshape(-1, no * ni), S[ok].reshape(-1, no * ni)


def fit_frf(
    frf: FRF,
    *,
    fs: float,
    order: int | Literal["auto"] = "auto",
    domain: str = "continuous",
    delay: float | Literal["auto"] = 0.0,
    band: tuple[float, float] | None = None,
    direct: bool = False,
    max_order: int = 20,
    max_delay: float | None = None,
    noise_dof: float | None = None,
    noise_kernel: FloatArray | None = None,
) -> FitResult:
    """Fit ``G(θ)`` (stable, common poles) to ``frf`` weighted by its std.

    Parameters
    ----------
    frf : FRF
        P_h on (0, fs/2], response and std (n_freq, n_out, n_in); bins without a
        positive finite std are left out.
    fs : float
        The FRF's sample rate (Hz): the hold (continuous) or z (discrete).
    order : int or "auto"
        States per input (a pair counts two); "auto": the smallest order in
        1..``max_order`` whose cost is within its expected band.
    domain : "continuous" or "discrete"
    delay : float or "auto"
        Input delay in s (whole samples when discrete); "auto": a grid of half samples
        (whole when discrete) up to ``max_delay`` (default 4 samples), then refined.
    band : (lo, hi) or None
        Hz; the bins fitted.
    direct : bool
        Fit a direct term D (default: strictly proper).
    max_order : int
        The highest order "auto" tries.
    max_delay : float or None
        The end of the "auto" delay grid in s (None: 4 samples of 1/fs).
    noise_dof : float or None
        The LPM's residual dof q (scales the expected cost by q/(q-1)).
    noise_kernel : array or None
        ρ(l) of the errors of bins l apart (:func:`lpm_kernel`): widens the cost band and
        the parameters' covariance (a sandwich); None: independent bins.

    Returns
    -------
    FitResult
        The model of the order chosen, its parameters' std and every order tried.

    Raises
    ------
    ConfigError
        An option out of range: ``domain``, ``fs``, ``order``, ``delay`` or ``band``.
    DataError
        Fewer than 4 bins with a positive finite std (in ``band``).
    """
    with one_blas_thread(with_scipy=True):  # small least-squares problems: threads compete
        options = FitOptions(
            fs=fs,
            order=order,
            domain=domain,
            delay=delay,
            band=band,
            direct=direct,
            max_order=max_order,
            max_delay=max_delay,
            noise_dof=noise_dof,
            noise_kernel=noise_kernel,
        )
        return _fit(frf, options)


def _delays(options: FitOptions) -> tuple[list[float], bool, float]:
    """The options checked (ConfigError): the delays tried, whether refined, their bound."""
    fs, order, domain, delay = options.fs, options.order, options.domain, options.delay
    if domain not in DOMAINS:
        raise ConfigError(f'domain must be "continuous" or "discrete", got {domain!r}')
    if not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
        raise ConfigError(f"fs must be a positive number (Hz), got {fs!r}")
    h = 1.0 / fs
    max_delay = 4.0 * h if options.max_delay is None else float(options.max_delay)
    if order != "auto" and (isinstance(order, bool) or not isinstance(order, int) or order < 1):
        raise ConfigError(f'order must be "auto" or an integer >= 1, got {order!r}')
    if delay == "auto":
        step = h if domain == "discrete" else h / 2
        grid = [float(t) for t in np.arange(0.0, max_delay + 1e-12 * h, step)]
        return grid, domain == "continuous", max_delay
    if isinstance(delay, bool) or not isinstance(delay, (int, float)) or not delay >= 0:
        raise ConfigError(f'delay must be "auto" or a number of seconds >= 0, got {delay!r}')
    if domain == "discrete" and abs(delay * fs - round(delay * fs)) > 1e-9:
        raise ConfigError(f"a discrete fit's delay must be whole samples of 1/fs, got {delay!r} s")
    return [float(delay)], False, max_delay


def _fit(frf: FRF, options: FitOptions) -> FitResult:
    fs, order, domain = options.fs, options.order, options.domain
    direct, noise_dof = options.direct, options.noise_dof
    delays, free_delay, max_delay = _delays(options)
    h = 1.0 / fs
    f, P, S = _select(frf, options.band)
    no, ni = frf.response.shape[1:]
    prob = Problem(np.exp(2j * np.pi * f * h), P, 1.0 / S, domain, h, 2.0 * np.pi * f[-1], direct)
    N = P.size
    orders = range(1, options.max_order + 1) if order == "auto" else [order]
    reports: list[OrderReport] = []
    # only two solutions are kept (each holds K x E residuals): the first order inside the
    # band (the choice) and, until there is one, the least MDL so far (the fallback)
    chosen: _Candidate | None = None
    fallback: _Candidate | None = None
    corr = correlation_length(options.noise_kernel)

    def n_params(n: int, free: bool) -> int:
        return int(n * (1 + no * ni) + (no * ni if direct else 0) + (1 if free else 0))

    def fit_at(n: int, at: list[float], free: bool) -> _Candidate:
        """Order n fitted (delays ``at``, free or not) with its report."""
        p = n_params(n, free)

        def bound(n_terms: int) -> tuple[float, float]:
            return expected_band(n_terms, p, noise_dof, corr)

        sol, start_cond = fit_order(
            prob, f, n, fs, delays=at, free_delay=free, max_delay=max_delay, bound=bound
        )
        poles, v = sol.poles, sol.cost
        e, sd = expected_band(N, p, noise_dof, corr)
        stable = bool(
            np.all(poles.real < 0) if domain == "continuous" else np.all(np.abs(poles) < 1)
        )
        aic, mdl = 2 * v + 2 * p, 2 * v + p * math.log(2 * N)
        report = OrderReport(
            order=n, cost=v, expected=e, sd=sd, aic=aic, mdl=mdl, delay=sol.delay, stable=stable
        )
        return _Candidate(report=report, solution=sol, start_cond=start_cond)

    for n in orders:
        candidate = fit_at(n, delays, free_delay)
        report = candidate.report
        e, sd, v = report.expected, report.sd, report.cost
        reports.append(report)
        if chosen is None:
            if order == "auto" and v <= e + 2.0 * sd:
                chosen, fallback = candidate, None
            elif fallback is None or report.mdl < fallback.report.mdl:
                fallback = candidate
        elif n >= chosen.report.order + 2:
            break
    kept = chosen if chosen is not None else fallback
    assert kept is not None
    shape = frf.response.shape[1:]
    out = _result(
        prob, kept, f, shape, free_delay=free_delay, reports=tuple(reports), options=options
    )
    if free_delay and out.delay_std > h:
        # the data do not pin the delay: the fit with it fixed at 0, unless that costs more
        fixed = fit_at(kept.report.order, [0.0], False)
        if fixed.solution.cost <= kept.solution.cost + 2.0 * kept.report.sd:
            zero = _result(
                prob, fixed, f, shape, free_delay=False, reports=tuple(reports), options=options
            )
            out = replace(zero, delay_std=out.delay_std, delay_determined=False)
    return out


def _result(
    prob: Problem,
    kept: _Candidate,
    f: FloatArray,
    shape: tuple[int, ...],
    *,
    free_delay: bool,
    reports: tuple[OrderReport, ...],
    options: FitOptions,
) -> FitResult:
    """The :class:`FitResult` of one order; ``jac``: the natural parameters' Jacobian in x."""
    sol, rep, fs = kept.solution, kept.report, options.fs
    no, ni = int(shape[0]), int(shape[1])
    poles, tau, coef, res = sol.poles, sol.delay, sol.coef, sol.residual
    R, D = residues_of(coef.reshape(-1, no, ni), poles, no, ni, direct=prob.direct)
    plant = ModalPlant(poles, R, D, None if prob.domain == "continuous" else prob.h)
    x, cov, _ = covariance(
        prob, poles, tau, free_delay=free_delay, kernel=options.noise_kernel, known=sol
    )
    n_nonlinear = x.size - coef.size  # x: the poles' and the delay's, then the linear ones
    E = no * ni
    pair = [bool(p.imag > 0) for p in poles]

    def natural(xx: FloatArray) -> FloatArray:
        nq = sum(2 if q else 1 for q in pair)
        pp = from_params(xx[:nq], pair, prob.domain, prob.h, prob.w_ref)
        cc = xx[n_nonlinear:].reshape(E, -1).T.reshape(-1, no, ni)
        RR, _ = residues_of(cc, pp, no, ni, direct=prob.direct)
        s = pp if prob.domain == "continuous" else np.log(pp.astype(complex)) * fs
        w = np.abs(s)
        c1 = 2.0 * RR.real
        c0 = -2.0 * (RR * np.conj(pp)[:, None, None]).real
        return np.concatenate(
            [
                pp.real,
                pp.imag,
                w / (2 * np.pi),
                -s.real / w,
                RR.real.ravel(),
                RR.imag.ravel(),
                c1.ravel(),
                c0.ravel(),
            ]
        )

    q0 = natural(x)
    jac = np.empty((q0.size, x.size))
    linear_scale = 1e-3 * np.max(np.abs(x[n_nonlinear:]), initial=1.0)
    for j in range(x.size):
        step = 1e-7 * max(abs(x[j]), linear_scale if j >= n_nonlinear else 1.0)
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        jac[:, j] = (natural(xp) - natural(xm)) / (2 * step)
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0))
    n_p = poles.size
    parts = np.split(std, np.cumsum([n_p, n_p, n_p, n_p, n_p * E, n_p * E, n_p * E]))
    real = ~np.array(pair, dtype=bool)
    c1s, c0s = parts[6].reshape(n_p, no, ni), parts[7].reshape(n_p, no, ni)
    c1s[real], c0s[real] = np.nan, np.nan
    delay_std = (
        float(np.sqrt(max(cov[n_nonlinear - 1, n_nonlinear - 1], 0.0))) if free_delay else 0.0
    )
    return FitResult(
        plant=plant,
        delay=float(tau),
        domain=prob.domain,
        fs=float(fs),
        frequency=f,
        residual=(res / 1.0).reshape(-1, no, ni),
        cost=rep.cost,
        expected=rep.expected,
        expected_sd=rep.sd,
        n_data=int(prob.P.size),
        n_params=n_states(poles) * (1 + E) + (E if prob.direct else 0) + (1 if free_delay else 0),
        pole_std=np.column_stack([parts[0], parts[1]]),
        frequency_std=parts[2],
        damping_std=parts[3],
        residue_std=np.stack(
            [parts[4].reshape(n_p, no, ni), parts[5].reshape(n_p, no, ni)], axis=-1
        ),
        c1_std=c1s,
        c0_std=c0s,
        delay_std=delay_std,
        orders=reports,
        max_condition=max(sol.condition, kept.start_cond),
    )
