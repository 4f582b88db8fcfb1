# SPDX-License-Identifier: Apache-2.0
"""What a record must be for diagnose (rates, channels, length) and its split."""

from __future__ import annotations

import math

from ...errors import DataError
from ...numerics.identify import min_samples
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .holes import check_missing


def min_record(n: int, ratio: int) -> int:
    """The shortest record diagnose takes.

    Twice what ``freq-lifted`` identification needs
    (:func:`~mr_ident.numerics.identify.min_samples`), i.e. 4 (2n+1) F, so that the noise
    spectrum, smoothed over 33 bins, rests on enough bins.
    """
    return 2 * min_samples("freq-lifted", n, ratio)


def check_record(model: Model, rec: LoopData, *, n: int = 8, what: str = "data") -> None:
    """Model and data must agree on rates and channels, and the data must be long enough.

    Raises
    ------
    DataError
    """
    if rec.fs_high is None or rec.ratio is None:
        raise DataError(
            f"{what}: fs_high and ratio must be known (got {rec.fs_high}, {rec.ratio})"
        )
    if not math.isclose(rec.fs_high, model.fs_high, rel_tol=1e-9):
        raise DataError(
            f"{what}: fs_high is {rec.fs_high:g} Hz but the model says {model.fs_high:g} Hz"
        )
    if rec.ratio != model.ratio:
        raise DataError(f"{what}: the ratio F is {rec.ratio} but the model says {model.ratio}")
    if rec.y_step != 1:
        raise DataError(
            f"{what}: y has {rec.y.shape[0]} samples, the low rate; diagnose simulates y at the "
            f"high rate and needs all N = {rec.n_samples} (identify takes a low-rate y)"
        )
    check_missing(rec, n, what)  # holes of u and y: within the limits (criterion.holes)
    if rec.u.shape[1] != model.n_u or rec.y.shape[1] != model.n_y:
        raise DataError(
            f"{what} has {rec.u.shape[1]} input and {rec.y.shape[1]} output channels; "
            f"the model has n_u={model.n_u}, n_y={model.n_y}"
        )
    if rec.period is not None:
        if rec.period < 2 or rec.n_samples % rec.period or rec.n_samples // rec.period < 4:
            raise DataError(
                f"{what}: period {rec.period} must divide N = {rec.n_samples} into at least "
                f"4 periods (the first is dropped as transient)"
            )
        return
    need = min_record(n, model.ratio)
    if rec.n_samples < need:
        raise DataError(
            f"{what} is too short for the LPM window: N = {rec.n_samples} samples, "
            f"need at least {need} (4 x (2n+1) x F with n = {n})"
        )


def split(rec: LoopData, fraction: float = 0.7) -> int:
    """Sample index where the estimation part ends and the held-out part begins.

    The first ``fraction`` of the record, rounded down to whole periods (periodic data)
    or to a multiple of F.
    """
    unit = rec.period or rec.ratio or 1
    return int(rec.n_samples * fraction) // unit * unit
