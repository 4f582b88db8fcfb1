# SPDX-License-Identifier: Apache-2.0
"""What a record must be for diagnose (rates, channels, length) and its split."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ...errors import ConfigError, DataError, DataFieldError, FieldError
from ...numerics.identify import min_samples
from ...numerics.missing_r import recover_r
from ...numerics.signals import LoopData
from ...numerics.structure import read_structure, settle_structure
from ...numerics.systems.model import Model
from .holes import check_missing


def min_record(n: int, ratio: int) -> int:
    """The shortest record diagnose takes.

    Twice what ``freq-lifted`` identification needs
    (:func:`~mr_ident.numerics.identify.min_samples`), i.e. 4 (2n+1) F, so that the noise
    spectrum, smoothed over 33 bins, rests on enough bins.
    """
    return 2 * min_samples("freq-lifted", n, ratio)


def with_injection(model: Model, data: LoopData, injection: str | None) -> Model:
    """``model`` with r entering where the data show it (and ``injection`` and the model agree).

    F and where r enters are read from the record
    (:func:`~mr_ident.numerics.structure.settle_structure`: ConfigError where the data
    contradict the model's ratio, its ``injection`` or the given ``injection``); the
    controller's phase is not checked here: a sampling offset is one of the causes diagnose
    looks for. Every diagnosis of data goes through it (a recording's, a live window's).
    A model that states nothing keeps stating nothing for r at the plant input.
    """
    try:
        settled = settle_structure(
            read_structure(data.r, data.u, data.y),
            ratios=[("the model", model.ratio)],
            injections=[
                (who, v)
                for who, v in (("{injection}", injection), ("the model", model.injection))
                if v is not None
            ],
            phases=[],
        )
    except FieldError:
        raise
    except ConfigError as err:  # the given named as the request's field
        raise FieldError(str(err), "injection") from err
    if settled.injection == "plant_input" and model.injection is None:
        return model
    return replace(model, injection=settled.injection)


def with_r(model: Model, rec: LoopData, what: str = "data") -> LoopData:
    """``rec`` with r's missing samples recovered where the loop determines them.

    The model's loop is simulated from r: its holes are filled as identification fills
    them (:func:`~mr_ident.numerics.missing_r.recover_r`, r where the model, settled by
    :func:`with_injection`, says it enters). DataError, naming the record, where more of r is
    undetermined than a fit takes.
    """
    if not np.isnan(rec.r).any():
        return rec
    try:
        found = recover_r(
            rec.r,
            rec.u,
            rec.y,
            ratio=model.ratio,
            injection=model.injection or "plant_input",
            phase=model.sample_phase,
        )
    except DataError as e:
        raise DataError(f"{what}: {e}") from None
    return replace(rec, r=found.r)


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
            raise DataFieldError(
                f"{what}: {{period}} {rec.period} must divide N = {rec.n_samples} into at "
                "least 4 periods (the first is dropped as transient)",
                "period",
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


@dataclass(frozen=True, eq=False)
class Records:
    """Which data estimate and which validate (:func:`plan`).

    ``est`` the estimation record; ``val`` the record simulated for validation (the whole
    of DATA when part of it is held out), ``val_part`` its validated part, ``cut`` where
    that part begins in ``val`` (0 for separate data); ``est_desc``, ``val_desc`` in words.
    """

    est: LoopData
    val: LoopData
    val_part: LoopData
    cut: int
    est_desc: str
    val_desc: str


def plan(
    model: Model,
    data: LoopData,
    validation: LoopData | None,
    *,
    n: int,
    holdout: float,
    names: tuple[str, str],
    more: Sequence[LoopData] = (),
) -> Records:
    """Check the other records against ``model`` and split off the validation part.

    ``data`` is checked already (:func:`check_record`, before ``model`` took the injection
    the data show: :func:`with_injection`). Without ``validation`` the last ``holdout`` of
    ``data`` (:func:`split`) is held out; periodic data need at least 3 held-out periods.
    DataError naming the record otherwise.
    """
    if validation is not None:
        check_record(model, validation, n=n, what=names[1])
        with_injection(model, validation, None)  # the same loop there (else refused)
        validation = with_r(model, validation, names[1])
        est, val, cut = data, validation, 0
        est_desc = f"all of DATA ({data.n_samples} samples)"
        val_desc = f"the validation data ({validation.n_samples} samples)"
    else:
        cut = split(data, 1.0 - holdout)
        est, val = data.part(0, cut), data
        check_record(model, est, n=n, what=f"the estimation part of {names[0]}")
        if data.period is not None and (data.n_samples - cut) // data.period < 3:
            raise DataError(
                f"the held-out part of {names[0]} is {(data.n_samples - cut) // data.period} "
                "periods; validating on it drops the first as transient and needs two more for "
                "the noise: record more periods (7 with 30 % held out), or give validation data"
            )
        est_desc = f"samples 0..{cut - 1} of DATA (the first {100 * (1 - holdout):.0f} %)"
        val_desc = (
            f"samples {cut}..{data.n_samples - 1} of DATA (the last {100 * holdout:.0f} %, held "
            "out; simulated over the whole record so the state carries over)"
        )
    for j, other in enumerate(more):
        check_record(model, other, n=n, what=f"record {j + 3}")
    if cut and val.period is None and val.n_samples - cut < min_record(n, model.ratio):
        raise DataError(
            f"the held-out part of {names[0]} ({val.n_samples - cut} samples) "
            "is too short for the LPM window"
        )
    val_part = val.part(cut, val.n_samples) if cut else val
    return Records(est, val, val_part, cut, est_desc, val_desc)
