# SPDX-License-Identifier: Apache-2.0
"""The model simulated on measured data, and how well it fits in time.

With a controller, the loop is simulated from the measured r_h; without one (open loop),
the plant is driven by the measured u_h. In open loop the means of u and y are removed
first (a linear model describes deviations from the operating point; a constant current
that balances friction is not modelled).

Missing samples (NaN in u or y): in closed loop the prediction is driven by r, which is
never missing, and a missing sample is only left out where prediction and measurement
are compared. In open loop the measured u drives the plant: its missing samples are
replaced by their least-squares estimates from the lifted local fit
(:func:`~mr_ident.numerics.lifted.missing.estimate_missing`, as identification makes them),
once per record (:func:`driving_input`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.lti import StateSpace
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import LoopStream


@dataclass(frozen=True)
class Prediction:
    """Simulated (u, y) for a record, and the samples compared (from ``skip`` on).

    ``free``: in closed loop when asked for, the DFT of the free responses of y from sample
    ``start`` on, shape ((N - start) // 2 + 1, n_y, k)
    (:meth:`~mr_ident.numerics.systems.simulate.LoopStream.free_y_spectrum`).
    """

    u: FloatArray
    y: FloatArray
    skip: int
    free: ComplexArray | None = None


def centred(rec: LoopData, model: Model) -> tuple[FloatArray, FloatArray, FloatArray]:
    """r, u, y as the comparison uses them: in open loop each without its mean.

    r too: identified against the centred y, an r that kept its mean would put an
    equation at DC that no plant satisfies (y's DC is 0, r's is not), and the LPM windows
    holding DC would read it as noise (measured: the noise level 3-4x too high at the
    lowest bins, which the criterion then weighed too little).
    """
    if model.controller is None:
        r, u, y = (x - np.nanmean(x, axis=0) for x in (rec.r, rec.u, rec.y))
        return r, u, y
    return rec.r, rec.u, rec.y


#: The open-loop inputs estimated lately: (the record's u, with NaN; its estimate).
_DRIVEN: list[tuple[FloatArray, FloatArray]] = []


def driving_input(rec: LoopData, model: Model) -> FloatArray:
    """The centred u that drives the plant in open loop, its missing samples estimated.

    By :func:`~mr_ident.numerics.lifted.missing.estimate_missing` on the lifted fit of
    r -> [y; u] with ``freq-lifted``'s default window; kept for the last few records (a
    criterion predicts on one record many times).
    """
    r, u, y = centred(rec, model)
    if not np.isnan(u).any():
        return u
    for src, est in _DRIVEN:
        if src is rec.u:
            return est
    from ...numerics.lifted.missing import estimate_missing
    from ...numerics.lifted.options import default_n

    F = rec.ratio or model.ratio
    n = default_n("freq-lifted", 2, F, r.shape[1], max(u.shape[1], y.shape[1]))
    est = estimate_missing(r, u, y, F, n, 2).u
    _DRIVEN.append((rec.u, est))
    del _DRIVEN[:-4]
    return est


def predict(model: Model, rec: LoopData, *, free_from: int | None = None) -> Prediction:
    """Simulate ``model`` on the measured excitation of ``rec`` (see the module docstring).

    ``free_from``: also the spectrum of the closed loop's free responses of y from that
    sample on.
    """
    r, u, _ = centred(rec, model)
    stream = LoopStream(model)
    free = None
    if model.controller is None:
        u = driving_input(rec, model)
        _, y_hat = stream.next(u)
        u_hat = u
    else:
        u_hat, y_hat = stream.next(r)
        if free_from is not None:
            free = stream.free_y_spectrum(rec.n_samples, free_from)
    return Prediction(u_hat, y_hat, rec.period or 0, free)


def fit_percent(measured: FloatArray, simulated: FloatArray) -> float:
    """MATLAB ``compare`` fit: ``100 (1 - |y - y_hat| / |y - mean y|)``, averaged over channels.

    Over the samples measured (a missing one, NaN, is left out of both norms).
    """
    miss = np.isnan(measured)
    x = np.where(miss, 0.0, measured)
    e = np.linalg.norm(np.where(miss, 0.0, x - simulated), axis=0)
    d = np.linalg.norm(np.where(miss, 0.0, x - np.nanmean(measured, axis=0)), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.mean(100.0 * (1.0 - e / d)))


@dataclass(frozen=True)
class TimeFit:
    """Fit % of y and u (u is None in open loop, where the measured u drives the model)."""

    y: float
    u: float | None


def time_fit(
    model: Model, rec: LoopData, start: int = 0, pred: Prediction | None = None
) -> TimeFit:
    """Fit % of the model's simulated y (and u) against ``rec`` from sample ``start`` on.

    ``pred``: the model's :func:`predict` on ``rec`` when already at hand.
    """
    pred = pred or predict(model, rec)
    _, u, y = centred(rec, model)
    s = max(start, pred.skip)
    fy = fit_percent(y[s:], pred.y[s:])
    fu = None if model.controller is None else fit_percent(u[s:], pred.u[s:])
    return TimeFit(fy, fu)


#: A discrete plant pole this far outside the unit circle is unstable: its output from the
#: measured u grows beyond the numbers' reach.
UNSTABLE = 1e-9


def grows(P: StateSpace) -> bool:
    """``P`` (discrete) has a pole outside the unit circle by more than :data:`UNSTABLE`."""
    return bool(np.max(np.abs(P.poles()), initial=0.0) > 1.0 + UNSTABLE)
