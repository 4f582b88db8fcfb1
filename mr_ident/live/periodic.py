# SPDX-License-Identifier: Apache-2.0
"""A periodic excitation's record cut into realizations x whole periods, and its BLA.

The one path from a periodic record to the best linear approximation, for ``identify
--period`` (an NPZ of realizations, or a bag), ``replay`` and the node:

- by the labels that came with the samples (:func:`cut_by_labels`, the record's
  :attr:`~mr_ident.numerics.signals.LoopData.labels`): the period read off the labels (or
  checked against them), and :func:`~mr_ident.numerics.excitation.schedule.realizations_of` keeps
  the whole periods of every realization after the first ``transient`` of each run;
- without labels (:func:`cut_by_count`): the realizations as rows (an NPZ, or one row: a
  record from its first sample), periods counted from each row's first sample, the first
  ``transient`` dropped;

then :func:`periodic_bla` (:func:`~mr_ident.numerics.excitation.bla.best_linear_approximation` of
the cut, the noise from the spread over periods, the nonlinear part from the spread over
realizations) and :func:`bla_identification` (the BLA as P_h on the excited lines, what
the node publishes like any estimate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DataError, DataFieldError, FieldError
from ..numerics.arrays import FloatArray
from ..numerics.excitation.bla import BLA, LINE_PFG_SOURCE, best_linear_approximation
from ..numerics.excitation.schedule import labelled_period, realizations_of
from ..numerics.results import FRF, PFG, Identification
from ..numerics.signals import LoopData


@dataclass(frozen=True)
class Periods:
    """r, u, y cut into M realizations of P whole periods of N samples.

    Attributes
    ----------
    r, u, y : ndarray, shape (M, P·N)
        One channel each, the arrays of
        :func:`~mr_ident.numerics.excitation.bla.best_linear_approximation`.
    period : int
        N.
    by : {"labels", "count"}
        How the periods were found.
    unused : int
        Samples of the record in no kept period (transients, partial periods).
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    period: int
    by: str
    unused: int = 0

    @property
    def realizations(self) -> int:
        """M."""
        return int(self.r.shape[0])

    @property
    def periods(self) -> int:
        """P."""
        return int(self.r.shape[1] // self.period)

    def describe(self) -> str:
        """What was cut, in words (for a log line or the diagnostics)."""
        return (
            f"{self.realizations} realization(s) x {self.periods} period(s) of "
            f"{self.period} samples by {self.by}; {self.unused} samples left out"
        )


def _enough(M: int, P: int, period: int, transient: int, by: str) -> None:
    if M * P < 2:
        raise DataError(
            f"the {by} show {M} realization(s) x {P} whole period(s) of {period} samples after "
            f"the first {transient} of each run (transient periods): the BLA needs at least 2 "
            "whole periods"
        )


def _siso(data: LoopData) -> None:
    shapes = (data.r.shape[1], data.u.shape[1], data.y.shape[1])
    if shapes != (1, 1, 1):
        raise DataError(
            f"the BLA is of one input and one output; the record has r, u, y of {shapes} channels"
        )


def cut_by_labels(data: LoopData, period: int | None, transient: int) -> Periods:
    """The whole periods of every realization in ``data``, by its labels.

    Parameters
    ----------
    data : LoopData
        A gap-free record with :attr:`~mr_ident.numerics.signals.LoopData.labels`; one
        channel each.
    period : int or None
        N; None: read off the labels
        (:func:`~mr_ident.numerics.excitation.schedule.labelled_period`),
        else checked against them.
    transient : int
        Leading whole periods dropped from every run of one realization.

    Raises
    ------
    DataError
        No labels, more than one channel, a period that disagrees with the labels, no whole
        period, or fewer than 2 whole periods in all.
    """
    if data.labels is None:
        raise DataError("the record carries no excitation labels (realization, period, sample)")
    _siso(data)
    N = labelled_period(data.labels, period)
    pos = realizations_of(data.labels, N, transient)
    M, P = pos.shape[0], pos.shape[1] // N
    _enough(M, P, N, transient, "labels")
    r, u, y = (x[:, 0][pos] for x in (data.r, data.u, data.y))
    return Periods(r, u, y, N, "labels", data.n_samples - pos.size)


def cut_by_count(
    r: FloatArray, u: FloatArray, y: FloatArray, period: int, transient: int
) -> Periods:
    """Realizations as rows of ``r, u, y`` (M, n), periods counted from each row's start.

    Raises
    ------
    ConfigError
        ``period`` does not divide n, or nothing is left after the transient.
    DataError
        Fewer than 2 whole periods in all.
    """
    M, n = r.shape
    skip = transient * period
    if n % period:
        raise FieldError(
            f"{{period}} = {period} does not divide the {n} samples of each realization",
            "period",
        )
    if n - skip < period:
        raise FieldError(
            f"{n // period} period(s) per realization, {transient} dropped as transient "
            "({transient_periods}): nothing left",
            "transient_periods",
        )
    _enough(M, (n - skip) // period, period, transient, "sample counts")
    return Periods(r[:, skip:], u[:, skip:], y[:, skip:], period, "count", M * skip)


def record_by_count(data: LoopData, period: int, transient: int) -> Periods:
    """A record without labels as one realization: whole periods from its first sample.

    The samples after the last whole period are left out (:attr:`Periods.unused`).
    """
    _siso(data)
    n = data.n_samples // period * period
    if n < period:
        raise DataError(
            f"the record has {data.n_samples} samples, less than one period of {period}"
        )
    r, u, y = (x[None, :n, 0] for x in (data.r, data.u, data.y))
    cut = cut_by_count(r, u, y, period, transient)
    return Periods(cut.r, cut.u, cut.y, period, "count", cut.unused + data.n_samples - n)


def periodic_bla(cut: Periods, ratio: int = 1) -> BLA:
    """The BLA of what was cut (``ratio`` F: the odd/even levels of a multirate loop).

    DataError when u or y miss samples (NaN) in the kept periods: the periods' average
    needs every sample (missing samples are estimated by the LPM methods).
    """
    lost = np.isnan(cut.u) | np.isnan(cut.y)
    if lost.any():
        m, k = np.argwhere(lost)[0]
        raise DataFieldError(
            f"u or y miss {int(lost.sum())} samples (NaN) in the periods kept, the first at "
            f"sample {int(k)} of realization {int(m)}; the periodic average ({{period}}, the "
            "excitation's labels) needs every sample: identify without {period} estimates "
            "missing samples",
            "period",
        )
    return best_linear_approximation(cut.r, cut.u, cut.y, cut.period, ratio=ratio)


def bla_identification(bla: BLA, period: int, fs_high: float, ratio: int) -> Identification:
    """The BLA as an identification: P_h at the excited lines (Hz), its total std.

    With the PFG from data where the design measured it (a lifted design's lines,
    :func:`~mr_ident.numerics.excitation.bla.lifted_line_pfg`; nan at the others), no model PFG.
    """
    f = bla.lines * fs_high / period
    plant = FRF(f, bla.response[:, None, None], bla.std[:, None, None], "bla")
    pfg = None
    if bla.pfg is not None and bla.pfg_std is not None and np.isfinite(bla.pfg).any():
        pfg = PFG(f, bla.pfg, bla.pfg_std, LINE_PFG_SOURCE)
    return Identification(plant, None, None, None, float(fs_high), int(ratio), pfg_data=pfg)


def nl_to_noise(bla: BLA) -> float:
    """Median nonlinear std over the median noise std (nan without both parts)."""
    if bla.realizations < 2 or bla.periods < 2:
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.median(bla.nl_std) / np.median(bla.noise_std))
