# SPDX-License-Identifier: Apache-2.0
"""Identification of the high-rate plant of a multirate loop from r_h, u_h, y_h.

:func:`identify` checks its input (:mod:`~mr_ident.numerics.identify_plan`), runs one
method of the table :data:`~mr_ident.numerics.lifted.methods.METHODS` (``freq-lifted``,
``time-lifted``, ``lpm``, ``structured``, ``etfe``: see
:mod:`mr_ident.numerics.lifted.methods`) and, given the
controller, adds the PFG.
:func:`check_options` and :func:`min_samples` are the option and record-length rules,
shared with the node's configuration.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DataError, DimensionError
from .arrays import BoolArray, ComplexArray, FloatArray, IntArray
from .identify_plan import AUTO, Plan, plan
from .lifted.methods import METHODS, FitRequest, PlantFit
from .lifted.missing import check_share, estimate_missing
from .lifted.options import check_options, default_n, method_of, min_samples, missing_rules
from .lifted.pfg import pfg_from_plant
from .lifted.pfg_data import fit_data_pfg
from .lifted.setpoint import (
    hold_zero_bins,
    hold_zone,
)
from .lifted.spectra import Spectra
from .local.bandwidth import (
    centre_bins,
    choose_widths,
    probe_runs,
)
from .local.segments import Run, runs_of
from .results import FRF, PFG, Identification
from .threads import one_blas_thread, thread_map

__all__ = [
    "AUTO",
    "METHODS",
    "check_options",
    "default_n",
    "identify",
    "method_of",
    "min_samples",
]


def identify(
    r: ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    fs_high: float,
    ratio: int,
    method: str = "freq-lifted",
    n: int | str | None = AUTO,
    degree: int = 2,
    local: str = "polynomial",
    controller_low: ArrayLike | None = None,
    phase: int = 0,
    delay: int = 0,
    keep_lifted: bool = True,
    workers: int | None = None,
    y_phase: int = 0,
    injection: str = "plant_input",
) -> Identification:
    """Identify the high-rate plant P_h (and the PFG) from closed-loop data.

    In five steps: the input checked and what fits it (:func:`~.identify_plan.plan`: r's
    missing samples recovered, the regressor, the method, the windows); u's and y's missing
    samples estimated; the method's fit (the automatic window chosen on a probe first) and
    the PFG from data; P_h with its std; the PFG of P_h under ``controller_low``.

    Parameters
    ----------
    r, u, y : array_like, shape (N,) or (N, channels)
        Reference, plant input and plant output at the high rate; N a multiple of F. ``y``
        may instead hold N/F samples: the output at the low rate only, ``y_h[m F + q]``
        (``freq-lifted`` only; P_h still on every bin: see the README, "Outputs at the low
        rate"). A NaN of u or of a high-rate y is a missing sample: estimated as an unknown
        of the lifted fit r -> [y; u]
        (:func:`~mr_ident.numerics.lifted.missing.estimate_missing`), the method then fits
        the whole record with its std corrected (``Identification.n_missing`` counts them;
        the method page, "Missing samples"). A NaN of r is recovered where the loop
        determines it (u - r held, r held, a setpoint's controller equation), else guessed
        and counted as noise (:func:`~mr_ident.numerics.missing_r.recover_r`;
        ``Identification.r_recovered``, ``r_unknown``).
    fs_high : float
        High sample rate in Hz.
    ratio : int
        F = h_l / h_h.
    method : {"freq-lifted", "time-lifted", "lpm", "structured", "etfe"}
    n : int, "auto" or None, default "auto"
        LPM window half-width. ``"auto"``: per centre bin (a low-rate bin of a lifted
        method: one window for its F aliases), the candidate of least estimated
        mean-squared error among :func:`~mr_ident.numerics.local.bandwidth.candidates` from
        :func:`default_n` up to 4 times that (as the record allows), the candidates fitted
        on a probe of about 2 % of the bins (at least 6 segments of 2h + 1 bins), then one
        fit with the chosen widths; see :mod:`mr_ident.numerics.local.bandwidth`. None:
        :func:`default_n` (8 for a SISO loop up to F = 3). The n used per bin is
        ``Identification.n_used``.
    degree : int
        Polynomial degree R (default 2); with ``local="rational"`` the order of the
        numerator, the transient and the common denominator.
    local : {"polynomial", "rational"}
        The local model of every window (:mod:`mr_ident.numerics.local.fit`): the LPM, or the
        local rational model (:mod:`mr_ident.numerics.local.lrm`: a common denominator per
        window, for lightly damped modes; slower, and its default window is wider by the
        denominator's degrees of freedom).
    controller_low : array_like, shape (M, n_u, n_y), optional
        Controller frequency response on all low-rate bins ``z = exp(2j pi k/M)``,
        k = 0..M-1; when given, the PFG is computed from P_h and it.
    phase, delay : int
        Controller sampling phase and computation delay in high-rate samples.
    keep_lifted : bool, default True
        Keep the lifted J and S with their covariance in the result (lifted methods);
        False saves memory (about 0.6 kB per low-rate bin for SISO, F = 3).
    workers : int, optional
        Threads over blocks of bins (default: every CPU available to the process;
        1 runs serially). The result does not depend on it; while they run,
        OpenBLAS is limited to one thread per caller.
    y_phase : int, default 0
        q: the high-rate sample (0..F-1) of each low-rate period at which a low-rate ``y``
        was taken.
    injection : {"plant_input", "setpoint"}, default "plant_input"
        Where r entered: added to the plant input (the seed paper's loop), or as the
        controller's setpoint, sampled with y at ``phase``
        (:mod:`~mr_ident.numerics.lifted.setpoint`). A setpoint r has one channel per
        output, N samples or N/F (the controller's rate); the loop is square and y at the
        high rate. Its estimator is the high-rate local fit of the sampled setpoint to
        [y; u] and the indirect step (``method`` "freq-lifted", the default, or "lpm": one
        estimator here); ``Identification.undetermined`` flags the bins whose window
        reaches a zero of the hold (multiples of fs_high/F), where P_h is not determined
        (NaN at the zeros themselves); no PFG from data. An r at the plant input held over
        blocks of F (published at the controller's rate) has a lifted regressor of rank one
        per block: it takes the same estimator, on r itself.

    Returns
    -------
    Identification
        ``plant``: P_h on the bins (0, fs_high/2], shape (N//2, n_y, n_u), with its std;
        ``pfg_data``: the PFG from data alone (the lifted r -> y fit: freq-lifted's own,
        with its windows; for the other methods a lifted fit at the base window; None for
        a low-rate y), ``pfg``: the PFG from P_h and
        ``controller_low`` when given.

    Raises
    ------
    DimensionError, DataError, ConfigError
        Bad shapes, more than 0.1 % of r's read samples neither received nor determined,
        inf anywhere, more missing samples than the windows carry,
        N not a multiple of F, too little data, bad options.

    Examples
    --------
    A first-order plant under a proportional controller at half its rate, 40 s of
    white-noise reference, no noise: the estimate equals the exact plant up to the local
    polynomial's bias (median relative error about 3e-8 here).

    >>> import numpy as np
    >>> from mr_ident import identify, simulate
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [10.0], "den": [1.0, 10.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> sim = simulate(model, duration=40.0, rng=np.random.default_rng(0))
    >>> res = identify(sim.r, sim.u, sim.y, fs_high=100.0, ratio=2)
    >>> res.plant.response.shape                 # N//2 bins on (0, 50] Hz, n_y, n_u
    (2000, 1, 1)
    >>> exact = model.plant_frf(sim.n_samples)[1:]
    >>> bool(np.median(np.abs(res.plant.response - exact) / np.abs(exact)) < 1e-6)
    True
    """
    p = plan(  # step 1
        r, u, y, fs_high=fs_high, ratio=ratio, method=method, n=n, degree=degree, local=local,
        phase=phase, y_phase=y_phase, injection=injection, workers=workers,
    )  # fmt: skip
    u_fit, y_fit, n_missing, share = _missing_filled(p, degree, local)
    fit, n_used, pfg_data = _fitted(
        p, u_fit, y_fit, share, degree=degree, local=local, keep_lifted=keep_lifted
    )
    plant, std_half, undetermined = _plant_of(p, fit, n_used)
    pfg = None
    if controller_low is not None:
        pfg = _pfg_of(p, fit, std_half, undetermined, controller_low, phase=phase, delay=delay)
    return Identification(
        plant=plant,
        pfg=pfg,
        lifted_J=fit.lifted_J,
        lifted_S=fit.lifted_S,
        fs_high=p.fs_high,
        ratio=p.ratio,
        n_used=n_used[1:],
        local=local,
        pfg_data=pfg_data,
        n_missing=n_missing,
        injection=injection,
        undetermined=undetermined,
        r_recovered=p.r_found.recovered,
        r_unknown=p.r_found.unknown,
    )


def _missing_filled(
    p: Plan, degree: int, local: str
) -> tuple[FloatArray, FloatArray, IntArray, FloatArray | None]:
    """Step 2: u and y with their missing samples estimated, the counts and shares."""
    n_missing = np.concatenate([np.isnan(p.y).sum(axis=0), np.isnan(p.u).sum(axis=0)])
    if not n_missing.any():
        return p.u, p.y, n_missing, None
    u, y, share = _fill(p, degree=degree, local=local, counts=n_missing)
    return u, y, n_missing, share


def _fitted(
    p: Plan,
    u: FloatArray,
    y: FloatArray,
    share: FloatArray | None,
    *,
    degree: int,
    local: str,
    keep_lifted: bool,
) -> tuple[PlantFit, IntArray, PFG | None]:
    """Step 3: the method's fit, n per bin, and the PFG from data where it is defined.

    The automatic window's widths are chosen first, on a probe (:func:`_choose_widths`).
    """
    ra, m, F_fit, N = p.r, method_of(p.method), p.fit_ratio, p.r.shape[0]
    spectra = Spectra(ra, u, y, p.workers)
    n_out = max(y.shape[1], u.shape[1])

    def fit_with(
        nj: int, keep: bool, data_pfg: bool, runs: tuple[Run, ...] | None, workers: int
    ) -> PlantFit:
        qj = check_options(p.method, nj, degree, F_fit, ra.shape[1], n_out, local=local)
        return m.fit(
            FitRequest(
                ra,
                u,
                y,
                F_fit,
                nj,
                degree,
                qj,
                keep,
                workers,
                local,
                data_pfg,
                int(p.y_phase),
                runs,
                spectra,
                share,
            )  # fmt: skip
        )

    n_used = np.full(N // 2 + 1, p.widths[0] if m.uses_lpm else 0, dtype=np.int64)
    with one_blas_thread():
        runs = None
        if len(p.widths) > 1:  # the automatic window: candidates on a probe, then one fit
            centre_of = centre_bins(N, m.lift(F_fit))
            widths, offsets = _choose_widths(
                p.widths, centre_of, fit_with, p.workers,
                strided=m.strides and local == "polynomial",
            )  # fmt: skip
            runs = runs_of(widths, offsets)
            n_used = widths[centre_of]
        fit = fit_with(p.n0, keep_lifted, True, runs, p.workers)
        pfg_data = (
            None
            if p.slow or p.high
            else _data_pfg(p, fit, u, y, degree=degree, local=local, share=share)
        )
    return fit, n_used, pfg_data


def _plant_of(
    p: Plan, fit: PlantFit, n_used: IntArray
) -> tuple[FRF, FloatArray, BoolArray | None]:
    """Step 4: P_h with its std on (0, fs_high/2].

    NaN at the hold's zeros where the fit is the high-rate one (the bins whose windows reach
    them flagged ``undetermined``).
    """
    N, F = p.r.shape[0], p.ratio
    undetermined = None
    if p.high:  # P_h is not determined at the hold's zeros: NaN there
        undetermined = hold_zone(N, F, n_used[1:])
        fit.P_half[hold_zero_bins(N, F)] = np.nan
        fit.var_half[hold_zero_bins(N, F)] = np.nan
    std_half = np.sqrt(np.maximum(fit.var_half, 0.0))
    freq = np.arange(1, N // 2 + 1) * p.fs_high / N
    for a in (freq, fit.P_half, std_half):  # handed over to the result: not copied
        a.flags.writeable = False
    return FRF(freq, fit.P_half[1:], std_half[1:], p.method), std_half, undetermined


def _pfg_of(
    p: Plan,
    fit: PlantFit,
    std_half: FloatArray,
    undetermined: BoolArray | None,
    controller_low: ArrayLike,
    *,
    phase: int,
    delay: int,
) -> PFG:
    """Step 5: the PFG of P_h under the controller ``controller_low``.

    NaN where P_h is not determined (every alias of such a bin is near a zero too).
    """
    N, F = p.r.shape[0], p.ratio
    ny, nu = p.y.shape[1], p.u.shape[1]
    Kl = np.asarray(controller_low, dtype=complex)
    if Kl.shape != (N // F, nu, ny):
        raise DimensionError(
            f"controller_low must have shape (M={N // F}, n_u={nu}, n_y={ny}), got {Kl.shape}"
        )
    g = pfg_from_plant(
        fit.P_half,
        Kl,
        F,
        N,
        P_std_half=None if p.method == "etfe" else std_half,
        phase=phase,
        delay=delay,
        fs_high=p.fs_high,
        workers=p.workers,
    )
    gain, std = g.gain[1:], g.std[1:]
    if undetermined is not None:
        gain, std = (np.where(undetermined, np.nan, x) for x in (gain, std))
    return PFG(g.frequency[1:], gain, std, f"plant:{p.method}")


def _fill(
    p: Plan, *, degree: int, local: str, counts: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The u and y with their missing (NaN) samples estimated; each channel's missing share.

    ``counts``: the missing samples of each channel of y, then of u.
    :func:`~mr_ident.numerics.lifted.missing.estimate_missing` on the lifted polynomial
    fit r -> [y; u] (at the fit's F) with the base window ``p.n0`` of a lifted method, else
    freq-lifted's default window (at least ``p.n0``); with the automatic window twice that,
    as the record allows (at the base window the narrowest candidate absorbs the
    estimates' errors and the rule picks narrow windows: 1.46x the error with 1 % missing,
    against 1.00x at twice the base, paper's loop); DataError beyond the share of missing
    samples the windows carry (:func:`~mr_ident.numerics.lifted.missing.check_share`), for
    a low-rate y, or for a record too short for the lifted fit.
    """
    r, u, y, ratio = p.r, p.u, p.y, p.fit_ratio
    N, nr, ny, nu = r.shape[0], r.shape[1], y.shape[1], u.shape[1]
    n_out = max(ny, nu)
    if y.shape[0] != N:
        raise DataError(
            "y at the low rate has NaN samples; missing samples are estimated for a "
            "high-rate y (N samples) only"
        )
    auto = len(p.widths) > 1
    rules = missing_rules(
        p.method, p.n0, degree, ratio, nr, n_out, local=local, n_samples=N, auto=auto
    )
    n_theta = rules[0][1]
    lifted = METHODS["freq-lifted"]
    if N < lifted.min_samples(n_theta, ratio):
        raise DataError(
            f"missing samples are estimated by the lifted fit, which needs N >= "
            f"{lifted.min_samples(n_theta, ratio)} samples (n = {n_theta}); got N = {N}"
        )
    names = [f"y channel {j}" for j in range(ny)] + [f"u channel {j}" for j in range(nu)]
    check_share(counts, N, names, rules)
    fill = estimate_missing(r, u, y, ratio, n_theta, degree)
    return fill.u, fill.y, counts / N


def _choose_widths(
    ns: tuple[int, ...],
    centre_of: IntArray,
    fit_with: Callable[[int, bool, bool, tuple[Run, ...] | None, int], PlantFit],
    workers: int,
    strided: bool,
) -> tuple[IntArray, IntArray]:
    """The half-width of every centre bin and its offsets: the candidates on a probe, the rule.

    ``centre_of``: the centre bin of every high-rate bin 0..N//2
    (:func:`~mr_ident.numerics.local.bandwidth.centre_bins`).

    :func:`~mr_ident.numerics.local.bandwidth.probe_runs` and
    :func:`~mr_ident.numerics.local.bandwidth.choose_widths`; only the probed bins of each
    candidate are kept meanwhile. The candidates run side by side on ``workers`` threads (each
    fit serially: a probe is one engine call per candidate, which threads cannot split).
    """
    n_centres = int(centre_of.max()) + 1  # every centre bin 0..K-1 has its high-rate bins
    probe = probe_runs(n_centres, ns[-1])
    inside = np.zeros(n_centres, dtype=bool)
    for a, b in probe:
        inside[a:b] = True
    rows = np.flatnonzero(inside[centre_of])  # the high-rate bins the probe fits

    def probed_fit(nj: int) -> tuple[ComplexArray, FloatArray]:
        fit = fit_with(nj, False, False, tuple((a, b, nj) for a, b in probe), 1)
        return fit.P_half[rows], fit.var_half[rows]  # the whole-spectrum arrays freed here

    with warnings.catch_warnings():  # the final fit says it for the bins it keeps
        warnings.filterwarnings("ignore", "LPM: .* rank-deficient", RuntimeWarning)
        fits = thread_map(probed_fit, ns, workers)
    ok = np.isfinite(fits[0][0]).all(axis=(1, 2))  # NaN: no excitation in the window
    return choose_widths(
        ns,
        np.stack([P[ok] for P, _ in fits]),
        np.stack([v[ok] for _, v in fits]),
        centre_of[rows[ok]],
        n_centres,
        halfwidth=ns[-1],
        strided=strided,
    )


#: The source of the PFG identified from data alone (:attr:`Identification.pfg_data`).
DATA_PFG_SOURCE = "data:lifted r->y"


def _data_pfg(
    p: Plan,
    fit: PlantFit,
    u: FloatArray,
    y: FloatArray,
    *,
    degree: int,
    local: str,
    share: FloatArray | None,
) -> PFG | None:
    """The PFG from freq-lifted's fit r -> [y; u]: the method's own, else that fit once more.

    freq-lifted's own fit has the method's windows (the chosen widths with ``n="auto"``).
    The extra fit has the method's local model and takes the larger of the method's window
    (the base window ``p.n0`` with ``n="auto"``) and freq-lifted's default for that model
    (:func:`default_n`), so every method gives freq-lifted's PFG from data; None (with a
    warning) when the record is too short for it. ``u``, ``y``: with their missing samples
    estimated (``share``: each channel's missing share).
    """
    r, ratio, n, fs_high = p.r, p.ratio, p.n0, p.fs_high
    N, nr, n_out = r.shape[0], r.shape[1], max(y.shape[1], u.shape[1])
    gain, var = fit.pfg_half, fit.pfg_var_half
    if gain is None or var is None:
        lifted = METHODS["freq-lifted"]
        n_pfg = max(n, default_n("freq-lifted", degree, ratio, nr, n_out, local))
        if N < lifted.min_samples(n_pfg, ratio):
            warnings.warn(
                f"no PFG from data: the lifted fit r -> y needs N >= "
                f"{lifted.min_samples(n_pfg, ratio)} samples (n = {n_pfg}), got {N}",
                stacklevel=4,
            )
            return None
        check_options("freq-lifted", n_pfg, degree, ratio, nr, n_out, local=local)
        gain, var = fit_data_pfg(
            r, u, y, ratio, n_pfg, degree, local=local, workers=p.workers, missing=share
        )
    freq = np.arange(1, N // 2 + 1) * fs_high / N
    return PFG(freq, gain[1:], np.sqrt(np.maximum(var[1:], 0.0)), DATA_PFG_SOURCE)
