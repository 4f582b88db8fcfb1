# SPDX-License-Identifier: Apache-2.0
"""What :func:`~mr_ident.numerics.identify.identify` fits: its first step, a :class:`Plan`.

The signals checked (shapes, inf; r's missing samples recovered where the loop determines
them: :mod:`~mr_ident.numerics.missing_r`), the regressor (r, or the setpoint's samples
the controller takes, or a held r: then the high-rate fit), the method that fits it, and
the window half-widths (one, or the automatic window's candidates). Every option is
checked here, before anything is computed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError, DataError, DimensionError
from .arrays import FloatArray
from .lifted.options import check_options, default_n, method_of
from .lifted.setpoint import check_setpoint_shapes, held_over_blocks, setpoint_regressor
from .lifting import check_ratio, check_sample_of_period
from .local.bandwidth import SPAN, candidates, setpoint_span
from .missing_r import RecoveredR, recover_r
from .signals import y_at_low_rate
from .structure import INJECTIONS
from .threads import resolve_workers

#: The value of ``n`` that chooses the window per frequency from the data.
AUTO = "auto"


@dataclass(frozen=True)
class Plan:
    """One identification's checked input and what fits it.

    Attributes
    ----------
    r, u, y : ndarray, shapes (N, n_r), (N, n_u), (N or N/F, n_y)
        The regressor (r; the setpoint's taken samples r↑, zeros between; a held r) and
        the signals as given (NaN: missing samples of u and y).
    ratio : int
        F.
    fit_ratio : int
        F of the fit: 1 where the loop is LTI at the high rate from the regressor (r at
        the setpoint, or held over blocks).
    method : str
        The method that fits it (``lpm`` for the high-rate fit).
    n0 : int
        The base window half-width.
    widths : tuple of int
        The candidates of the automatic window, or ``(n0,)``.
    fs_high : float
    workers : int
    y_phase : int
    slow : bool
        y at the low rate.
    high : bool
        The high-rate fit (P_h undetermined at the hold's zeros).
    r_found : RecoveredR
        How r's missing samples were recovered.
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    ratio: int
    fit_ratio: int
    method: str
    n0: int
    widths: tuple[int, ...]
    fs_high: float
    workers: int
    y_phase: int
    slow: bool
    high: bool
    r_found: RecoveredR


def plan(
    r: ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    fs_high: float,
    ratio: int,
    method: str,
    n: int | str | None,
    degree: int,
    local: str,
    phase: int,
    y_phase: int,
    injection: str,
    workers: int | None,
) -> Plan:
    """The :class:`Plan` of an identification, every option checked.

    The arguments are :func:`~mr_ident.numerics.identify.identify`'s, documented there.

    Raises
    ------
    ConfigError, DataError, DimensionError
        As :func:`~mr_ident.numerics.identify.identify` documents.
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
    check_options(method, n0, degree, F_fit, ra.shape[1], max(ny, nu), local=local)
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
    return Plan(
        r=ra,
        u=ua,
        y=ya,
        ratio=F,
        fit_ratio=F_fit,
        method=method,
        n0=n0,
        widths=ns,
        fs_high=float(fs_high),
        workers=n_workers,
        y_phase=int(y_phase),
        slow=slow,
        high=high,
        r_found=r_found,
    )


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
