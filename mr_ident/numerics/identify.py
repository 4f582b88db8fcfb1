# SPDX-License-Identifier: Apache-2.0
"""Identification of the high-rate plant of a multirate loop from r_h, u_h, y_h.

:func:`identify` checks its input, runs one method of the table
:data:`~mr_ident.numerics.lifted.methods.METHODS` (``freq-lifted``, ``time-lifted``, ``lpm``,
``structured``, ``etfe``: see :mod:`mr_ident.numerics.lifted.methods`) and, given the
controller, adds the PFG.
:func:`check_options` and :func:`min_samples` are the option and record-length rules,
shared with the node's configuration.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError, DataError, DimensionError
from .arrays import ComplexArray, FloatArray, IntArray
from .lifted.methods import METHODS, FitRequest, PlantFit
from .lifted.missing import check_share, estimate_missing
from .lifted.options import check_options, default_n, method_of, min_samples, missing_rules
from .lifted.pfg import pfg_from_plant
from .lifted.pfg_data import fit_data_pfg
from .lifted.setpoint import (
    check_setpoint_shapes,
    held_over_blocks,
    hold_zero_bins,
    hold_zone,
    setpoint_regressor,
)
from .lifted.spectra import Spectra
from .lifting import check_ratio, check_sample_of_period
from .local.bandwidth import (
    SPAN,
    candidates,
    centre_bins,
    choose_widths,
    probe_runs,
    setpoint_span,
)
from .local.segments import Run, runs_of
from .missing_r import RecoveredR, recover_r
from .results import FRF, PFG, Identification
from .signals import y_at_low_rate
from .structure import INJECTIONS
from .threads import one_blas_thread, resolve_workers, thread_map

__all__ = [
    "AUTO",
    "METHODS",
    "check_options",
    "default_n",
    "identify",
    "method_of",
    "min_samples",
]

#: The value of ``n`` that chooses the window per frequency from the data.
AUTO = "auto"


def _check_signals(
    r: ArrayLike, u: ArrayLike, y: ArrayLike, ratio: int, setpoint: bool = False
) -> tuple[FloatArray, FloatArray, FloatArray]:
    arrays = []
    for name, x in (("r", r), ("u", u), ("y", y)):
        a = np.asarray(x, dtype=float)
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2:
            raise DimensionError(
                f"{name} must have shape (n_samples,) or (n_samples, n_channels), got {a.shape}"
            )
        if np.isinf(a).any():
            bad = np.argwhere(np.isinf(a))[0]
            raise DataError(
                f"{name} contains inf (a missing sample is NaN); first at sample {bad[0]}, "
                f"channel {bad[1]}"
            )
        arrays.append(a)
    ra, ua, ya = arrays
    if setpoint:  # r is the controller's reference: one per output, at either rate
        check_setpoint_shapes(ra, ua, ya, ratio)
        return ra, ua, ya
    if ra.shape[0] != ua.shape[0]:
        raise DimensionError(
            f"r and u must have equal lengths (the high rate), got {ra.shape[0]}, {ua.shape[0]}"
        )
    y_at_low_rate(ra.shape[0], ya.shape[0], ratio)
    if ra.shape[1] != ua.shape[1]:
        raise DimensionError(
            f"r and u must have the same number of channels (r excites u), got {ra.shape[1]} "
            f"and {ua.shape[1]}"
        )
    if ra.shape[0] % ratio:
        raise DimensionError(
            f"the record has {ra.shape[0]} samples, not a multiple of ratio F={ratio}; "
            f"trim it to {ra.shape[0] - ra.shape[0] % ratio} samples"
        )
    return ra, ua, ya


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
    F = check_ratio(ratio)
    if not (
        isinstance(fs_high, (int, float, np.floating)) and np.isfinite(fs_high) and fs_high > 0
    ):
        raise ConfigError(f"fs_high must be a positive number of Hz, got {fs_high!r}")
    if injection not in INJECTIONS:
        raise ConfigError(f"injection must be one of {', '.join(INJECTIONS)}, got {injection!r}")
    setpoint = injection == "setpoint"
    m = method_of(method)
    n_workers = resolve_workers(workers)
    ra, ua, ya = _check_signals(r, u, y, F, setpoint)
    r_found = RecoveredR(ra)
    if np.isnan(ra).any():  # r's missing samples: recovered where the loop determines them
        q = check_sample_of_period("phase", phase, F)
        r_found = recover_r(ra, ua, ya, ratio=F, injection=injection, phase=q)
        ra = r_found.r
    if setpoint:  # the sampled setpoint r↑, and its estimator
        ra = setpoint_regressor(ra, F, phase, method, ua.shape[0])
    # a regressor held or sampled per block (a low-rate y keeps the lifted fit: its aliased sum)
    high = setpoint or (ya.shape[0] == ra.shape[0] and held_over_blocks(ra, F, method))
    if high:
        method, m = "lpm", method_of("lpm")
    F_fit = 1 if high else F  # the fit is LTI at the high rate
    N = ra.shape[0]
    ny, nu = ya.shape[1], ua.shape[1]
    slow = ya.shape[0] != N  # y at the low rate
    if slow and method != "freq-lifted":
        raise ConfigError(
            f"y at the low rate ({ya.shape[0]} = N/F samples) is identified by freq-lifted "
            f"only; got method {method!r}"
        )
    check_sample_of_period("y_phase", y_phase, F)
    n_min = default_n(method, degree, F_fit, ra.shape[1], max(ny, nu), local)
    auto = isinstance(n, str)
    if auto and n != AUTO:
        raise ConfigError(f'n must be an integer >= 1, None or "{AUTO}", got {n!r}')
    n0 = n_min if n is None or isinstance(n, str) else n
    check_options(method, n0, degree, F_fit, ra.shape[1], max(ny, nu), local)
    if m.uses_lpm and N < m.min_samples(n0, F_fit):
        raise DataError(
            f"too few samples for the LPM window: {method} needs {2 * (2 * n0 + 1)} independent "
            "bins "
            f"(2 x (2n+1), n={n0}) per period, i.e. N >= {m.min_samples(n0, F_fit)} samples; "
            f"got N = {N}"
        )
    ns: tuple[int, ...] = (n0,)
    if auto and m.uses_lpm:
        span = setpoint_span(n0, N / float(fs_high)) if high else SPAN
        ns = candidates(n0, (N // (2 * m.lift(F_fit)) - 1) // 2, span)

    n_missing = np.concatenate([np.isnan(ya).sum(axis=0), np.isnan(ua).sum(axis=0)])
    share = None
    if n_missing.any():
        ua, ya, share = _fill(ra, ua, ya, method, F_fit, n0, degree, local, n_missing, len(ns) > 1)
    spectra = Spectra(ra, ua, ya, n_workers)

    def fit_with(
        nj: int, keep: bool, data_pfg: bool, runs: tuple[Run, ...] | None, workers: int
    ) -> PlantFit:
        qj = check_options(method, nj, degree, F_fit, ra.shape[1], max(ny, nu), local)
        return m.fit(
            FitRequest(
                ra,
                ua,
                ya,
                F_fit,
                nj,
                degree,
                qj,
                keep,
                workers,
                local,
                data_pfg,
                int(y_phase),
                runs,
                spectra,
                share,
            )
        )

    n_used = np.full(N // 2 + 1, ns[0] if m.uses_lpm else 0, dtype=np.int64)
    with one_blas_thread():
        runs = None
        if len(ns) > 1:  # the automatic window: candidates on a probe, then one fit
            centre_of = centre_bins(N, m.lift(F_fit))
            widths, offsets = _choose_widths(
                ns, centre_of, fit_with, n_workers, strided=m.strides and local == "polynomial"
            )
            runs = runs_of(widths, offsets)
            n_used = widths[centre_of]
        fit = fit_with(n0, keep_lifted, True, runs, n_workers)
        pfg_data = (
            None
            if slow or high
            else _data_pfg(fit, ra, ua, ya, F, n0, degree, local, n_workers, float(fs_high), share)
        )
    undetermined = None
    if high:  # P_h is not determined at the hold's zeros: NaN there
        undetermined = hold_zone(N, F, n_used[1:])
        fit.P_half[hold_zero_bins(N, F)] = np.nan
        fit.var_half[hold_zero_bins(N, F)] = np.nan
    std_half = np.sqrt(np.maximum(fit.var_half, 0.0))
    freq = np.arange(1, N // 2 + 1) * fs_high / N
    for a in (freq, fit.P_half, std_half):  # handed over to the result: not copied
        a.flags.writeable = False
    plant = FRF(freq, fit.P_half[1:], std_half[1:], method)
    pfg: PFG | None = None
    if controller_low is not None:
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
            P_std_half=None if method == "etfe" else std_half,
            phase=phase,
            delay=delay,
            fs_high=float(fs_high),
            workers=n_workers,
        )
        gain, std = g.gain[1:], g.std[1:]
        if undetermined is not None:  # every alias of such a bin is near a zero too
            gain, std = (np.where(undetermined, np.nan, x) for x in (gain, std))
        pfg = PFG(g.frequency[1:], gain, std, f"plant:{method}")
    return Identification(
        plant=plant,
        pfg=pfg,
        lifted_J=fit.lifted_J,
        lifted_S=fit.lifted_S,
        fs_high=float(fs_high),
        ratio=F,
        n_used=n_used[1:],
        local=local,
        pfg_data=pfg_data,
        n_missing=n_missing,
        injection=injection,
        undetermined=undetermined,
        r_recovered=r_found.recovered,
        r_unknown=r_found.unknown,
    )


def _fill(
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    method: str,
    ratio: int,
    n: int,
    degree: int,
    local: str,
    counts: IntArray,
    auto: bool = False,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The u and y with their missing (NaN) samples estimated; each channel's missing share.

    :func:`~mr_ident.numerics.lifted.missing.estimate_missing` on the lifted polynomial
    fit r -> [y; u] with the window ``n`` of a lifted method, else freq-lifted's default
    window (at least ``n``); with the automatic window (``auto``) twice that, as the record
    allows (at the base window the narrowest candidate absorbs the estimates' errors and
    the rule picks narrow windows: 1.46x the error with 1 % missing, against 1.00x at
    twice the base, paper's loop); DataError beyond the
    share of missing samples the windows carry
    (:func:`~mr_ident.numerics.lifted.missing.check_share`), for a low-rate y, or for a
    record too short for the lifted fit.
    """
    N, nr, ny, nu = r.shape[0], r.shape[1], y.shape[1], u.shape[1]
    n_out = max(ny, nu)
    if y.shape[0] != N:
        raise DataError(
            "y at the low rate has NaN samples; missing samples are estimated for a "
            "high-rate y (N samples) only"
        )
    rules = missing_rules(method, n, degree, ratio, nr, n_out, local, N, auto)
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
    fit: PlantFit,
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    ratio: int,
    n: int,
    degree: int,
    local: str,
    workers: int,
    fs_high: float,
    share: FloatArray | None = None,
) -> PFG | None:
    """The PFG from freq-lifted's fit r -> [y; u]: the method's own, else that fit once more.

    freq-lifted's own fit has the method's windows (the chosen widths with ``n="auto"``).
    The extra fit has the method's local model and takes the larger of the method's window
    ``n`` (the base window with ``n="auto"``) and freq-lifted's default for that model
    (:func:`default_n`), so every method gives freq-lifted's PFG from data; None (with a
    warning) when the record is too short for it.
    """
    N, nr, n_out = r.shape[0], r.shape[1], max(y.shape[1], u.shape[1])
    gain, var = fit.pfg_half, fit.pfg_var_half
    if gain is None or var is None:
        lifted = METHODS["freq-lifted"]
        n_pfg = max(n, default_n("freq-lifted", degree, ratio, nr, n_out, local))
        if N < lifted.min_samples(n_pfg, ratio):
            warnings.warn(
                f"no PFG from data: the lifted fit r -> y needs N >= "
                f"{lifted.min_samples(n_pfg, ratio)} samples (n = {n_pfg}), got {N}",
                stacklevel=3,
            )
            return None
        check_options("freq-lifted", n_pfg, degree, ratio, nr, n_out, local)
        gain, var = fit_data_pfg(r, u, y, ratio, n_pfg, degree, local, workers, share)
    freq = np.arange(1, N // 2 + 1) * fs_high / N
    return PFG(freq, gain[1:], np.sqrt(np.maximum(var[1:], 0.0)), DATA_PFG_SOURCE)
