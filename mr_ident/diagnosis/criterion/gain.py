# SPDX-License-Identifier: Apache-2.0
"""The gain of an extended model: the nominal and the extended model on the validation data.

Fit of y and u (MATLAB ``compare``'s percentage, :func:`~.prediction.time_fit`) and the
FRF evidence (:func:`~.evidence.frf_evidence`) of both, and the traces the report draws.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ...numerics.results import Identification
from ...numerics.systems.model import Model
from .evidence import Evidence, frf_evidence
from .prediction import Prediction, TimeFit, centred, predict, time_fit
from .records import Records


@dataclass(frozen=True, eq=False)
class Gain:
    """The nominal and the extended model on the validation data (:func:`gain_on`)."""

    start: int
    pred_before: Prediction
    pred_after: Prediction
    fit_before: TimeFit
    fit_after: TimeFit
    evidence_before: Evidence
    evidence_after: Evidence
    traces: dict[str, Any]


def gain_on(
    model: Model,
    current: Model,
    recs: Records,
    start: int,
    ident_val: Identification | None,
    *,
    n: int,
    degree: int,
    alpha: float,
) -> Gain:
    """Fit of y and u (from ``start``) and the FRF evidence, before and after.

    On the validation data ``recs``: the fits on ``recs.val`` from sample ``start``, the
    evidence on ``recs.val_part`` (its identification ``ident_val``).
    """
    val = recs.val
    pred_b, pred_a = predict(model, val), predict(current, val)
    _, _, y_meas = centred(val, model)
    opts = {"n": n, "degree": degree, "alpha": alpha, "ident": ident_val}
    return Gain(
        start=start,
        pred_before=pred_b,
        pred_after=pred_a,
        fit_before=time_fit(model, val, start, pred_b),
        fit_after=time_fit(current, val, start, pred_a),
        evidence_before=frf_evidence(model, recs.val_part, **opts),  # type: ignore[arg-type]
        evidence_after=frf_evidence(current, recs.val_part, **opts),  # type: ignore[arg-type]
        traces={
            "start": max(start, pred_b.skip),
            "y": y_meas,
            "y_before": pred_b.y,
            "y_after": pred_a.y,
            "fs_high": val.fs_high,
        },
    )
