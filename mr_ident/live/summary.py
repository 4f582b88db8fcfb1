# SPDX-License-Identifier: Apache-2.0
"""A few scalars per estimate, for plotting tools that take scalars (the node's ``~/summary``).

Plotting tools such as PlotJuggler and rqt_plot draw one number per message and field;
the estimate's arrays are too long for them (PlotJuggler drops arrays past its
``max_array_size``). :func:`summary` reduces one identification, and the drift against the
monitoring reference where there is one, to those numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..numerics.arrays import FloatArray
from ..numerics.results import PFG, Identification


@dataclass(frozen=True)
class Summary:
    """Scalars of one estimate (NaN where there is nothing to say).

    Attributes
    ----------
    pfg_peak, pfg_peak_frequency : float
        Largest PFG from P_h and the controller, and where (Hz).
    pfg_data_peak, pfg_data_peak_frequency : float
        Largest PFG from data alone, and where (Hz).
    median_relative_std : float
        Median over bins and entries of std / |P_h|.
    drift_max_sigma, drift_max_relative : float
        Largest σ-error and relative deviation against the reference, over the bins.
    """

    pfg_peak: float
    pfg_peak_frequency: float
    pfg_data_peak: float
    pfg_data_peak_frequency: float
    median_relative_std: float
    drift_max_sigma: float
    drift_max_relative: float


def _peak(g: PFG | None) -> tuple[float, float]:
    if g is None or not np.isfinite(g.gain).any():
        return math.nan, math.nan
    k = int(np.nanargmax(g.gain))
    return float(g.gain[k]), float(g.frequency[k])


def _largest(x: FloatArray | None) -> float:
    if x is None or not np.isfinite(x).any():
        return math.nan
    return float(np.nanmax(x))


def summary(
    ident: Identification,
    deviation: FloatArray | None = None,
    sigma_error: FloatArray | None = None,
) -> Summary:
    """The scalars of ``ident``; ``deviation``, ``sigma_error`` (K,): the drift, if any."""
    P = ident.plant
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = P.std / np.abs(P.response)
    finite = rel[np.isfinite(rel)]
    return Summary(
        *_peak(ident.pfg),
        *_peak(ident.pfg_data),
        float(np.median(finite)) if finite.size else math.nan,
        _largest(sigma_error),
        _largest(deviation),
    )
