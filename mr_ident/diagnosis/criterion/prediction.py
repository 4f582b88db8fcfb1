# SPDX-License-Identifier: Apache-2.0
"""The model simulated on measured data, and how well it fits in time.

With a controller, the loop is simulated from the measured r_h; without one (open loop),
the plant is driven by the measured u_h. In open loop the means of u and y are removed
first (a linear model describes deviations from the operating point; a constant current
that balances friction is not modelled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.signals import LoopData
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
        r, u, y = (x - x.mean(axis=0) for x in (rec.r, rec.u, rec.y))
        return r, u, y
    return rec.r, rec.u, rec.y


def predict(model: Model, rec: LoopData, *, free_from: int | None = None) -> Prediction:
    """Simulate ``model`` on the measured excitation of ``rec`` (see the module docstring).

    ``free_from``: also the spectrum of the closed loop's free responses of y from that
    sample on.
    """
    r, u, _ = centred(rec, model)
    stream = LoopStream(model)
    free = None
    if model.controller is None:
        _, y_hat = stream.next(u)
        u_hat = u
    else:
        u_hat, y_hat = stream.next(r)
        if free_from is not None:
            free = stream.free_y_spectrum(rec.n_samples, free_from)
    return Prediction(u_hat, y_hat, rec.period or 0, free)


def fit_percent(measured: FloatArray, simulated: FloatArray) -> float:
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
