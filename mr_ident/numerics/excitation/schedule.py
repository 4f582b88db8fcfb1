# SPDX-License-Identifier: Apache-2.0
"""A periodic excitation played in a loop: its samples and the labels of every index.

A design of M realizations of P periods of N samples (``mr-ident excite``) is played
realization after realization and looped. Sample index i, counted from the first sample
played, is sample ``s = i mod N`` of period ``p = (i // N) mod P`` of realization
``m = (i // (P N)) mod M``. This module holds that rule once: the publisher
(``mr-ident excite --publish``) and the simulator play by it, and
:func:`realizations_of` cuts a record back into realizations and periods by the labels
that travelled with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, DataError
from ..arrays import FloatArray, IntArray

#: The labels of a sample, in this order (channels of the index stream).
LABELS = ("realization", "period", "sample")


@dataclass(frozen=True)
class Schedule:
    """M realizations of P periods of N samples, played in turn and looped.

    Attributes
    ----------
    period : int
        N, samples per period.
    periods : int
        P, periods per realization.
    realizations : int
        M.
    """

    period: int
    periods: int
    realizations: int

    def __post_init__(self) -> None:
        for name in ("period", "periods", "realizations"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")

    @classmethod
    def of(cls, r: FloatArray, period: int) -> Schedule:
        """The schedule of a design's signals ``r`` (M, P·N, n_in) with period N."""
        if r.ndim != 3 or r.shape[1] % period:
            raise ConfigError(
                f"r must be (M, P*N, n_in) with P*N a multiple of period = {period}, "
                f"got shape {r.shape}"
            )
        return cls(int(period), r.shape[1] // period, r.shape[0])

    @property
    def cycle(self) -> int:
        """Samples until the schedule repeats: M·P·N."""
        return self.period * self.periods * self.realizations

    def labels(self, first: int, n: int) -> IntArray:
        """(realization, period, sample) of indices ``first .. first + n - 1``, shape (n, 3)."""
        i = (int(first) + np.arange(int(n), dtype=np.int64)) % self.cycle
        N, P = self.period, self.periods
        out: IntArray = np.stack([i // (P * N), (i // N) % P, i % N], axis=1)
        return out

    def take(self, r: FloatArray, first: int, n: int) -> FloatArray:
        """Samples ``first .. first + n - 1`` of the design ``r`` (M, P·N, n_in): (n, n_in)."""
        flat = r.reshape(self.cycle, r.shape[-1])
        out: FloatArray = flat[(int(first) + np.arange(int(n))) % self.cycle]
        return out


def realizations_of(labels: IntArray, period: int, transient: int = 1) -> IntArray:
    """Positions of whole periods per realization in a record, by its labels.

    Parameters
    ----------
    labels : ndarray of int, shape (n, 3)
        (realization, period, sample) of each sample of a gap-free record, as published
        with it (:data:`LABELS`).
    period : int
        N.
    transient : int
        Leading whole periods dropped from every run of one realization (the loop's
        transient after the switch from the previous one).

    Returns
    -------
    ndarray of int, shape (M', P'·N)
        Row j: positions in the record of P' whole periods of the j-th realization found
        (in order of their label), P' the least number any of them has; the periods of
        two runs of one realization (a looped design) are joined. Index the record's r,
        u, y with it to get the (M', P'·N) arrays of :func:`mr_ident.numerics.excitation.bla.bla`.

    Raises
    ------
    DataError
        No realization holds a whole period after its transient.
    """
    lab = np.asarray(labels, dtype=np.int64)
    if lab.ndim != 2 or lab.shape[1] != 3:
        raise DataError(f"labels must be (n, 3) (realization, period, sample), got {lab.shape}")
    n = lab.shape[0]
    # a whole period: sample 0 .. N-1 of one (realization, period) on consecutive positions
    starts = np.flatnonzero(lab[:, 2] == 0)
    starts = starts[starts + period <= n]
    if starts.size:
        seg = starts[:, None] + np.arange(period)
        whole = (
            (lab[seg, 2] == np.arange(period)).all(axis=1)
            & (lab[seg, 0] == lab[starts, 0][:, None]).all(axis=1)
            & (lab[seg, 1] == lab[starts, 1][:, None]).all(axis=1)
        )
        starts = starts[whole]
    real = lab[starts, 0]
    # a new run where the realization changes or the periods are not back to back
    new_run = np.ones(starts.size, bool)
    new_run[1:] = (real[1:] != real[:-1]) | (np.diff(starts) != period)
    run = np.cumsum(new_run) - 1
    first_of_run = np.flatnonzero(new_run)
    keep = np.arange(starts.size) - first_of_run[run] >= transient
    starts, real = starts[keep], real[keep]
    found = np.unique(real)
    if found.size == 0:
        raise DataError(
            f"no realization holds a whole period of {period} samples after its first "
            f"{transient} (the record has {n} samples)"
        )
    per = [starts[real == m] for m in found]
    P = min(s.size for s in per)
    rows = np.stack([s[:P] for s in per])  # (M', P') period starts
    out: IntArray = (rows[:, :, None] + np.arange(period)).reshape(found.size, P * period)
    return out


def labelled_period(labels: IntArray, period: int | None = None) -> int:
    """N as the labels tell it: one more than the largest sample-of-period label.

    Parameters
    ----------
    labels : ndarray of int, shape (n, 3)
        As :func:`realizations_of`; a record holding a whole period holds every sample
        label 0 .. N-1.
    period : int or None
        The period the caller expects: checked against the labels.

    Raises
    ------
    DataError
        No labels, negative ones, or ``period`` disagreeing with them: a sample label at
        or past ``period``, or sample labels that start again from 0 before reaching
        ``period - 1`` (a shorter period).
    """
    lab = np.asarray(labels, dtype=np.int64)
    if lab.ndim != 2 or lab.shape[1] != 3 or lab.shape[0] == 0:
        raise DataError(
            f"labels must be (n >= 1, 3) (realization, period, sample), got {lab.shape}"
        )
    if lab.min() < 0:
        raise DataError(f"labels must be >= 0, got {int(lab.min())} ({', '.join(LABELS)})")
    n = int(lab[:, 2].max()) + 1
    if period is None:
        return n
    wraps = bool(np.any(np.diff(lab[:, 2]) < 0))
    if n > period or (n < period and wraps):
        raise DataError(
            f"period = {period} disagrees with the labels: their periods have {n} samples "
            f"(sample labels 0..{n - 1})"
        )
    return int(period)
