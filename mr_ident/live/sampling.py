# SPDX-License-Identifier: Apache-2.0
"""Stamps to samples: per-message values on the high-rate grid, as blocks for the aligner.

Rules (README, "How stamps become samples"), the same for the node and for replay:

* The stamp is ``header.stamp``; for a type without header, the time the message was sent
  (the DDS source timestamp live; in a bag its publish time, else its log time).
  One grid serves r, u and y: its origin t0 is the earliest stamp of the first batch,
  moved by the median sub-sample offset of that batch's stamps (so that jitter of the
  first stamp does not shift the grid). A message at t is sample
  ``index = round((t - t0) fs_high)``.
* A stamp more than ``tolerance`` sample times off its grid point (default 0.25 h_h) is
  an anomaly: the sample is dropped (a gap) and counted. A message where the path matched
  nothing (a joint not listed, an index out of range) is a gap too.
* A held source (``.@hold``: a controller output published once per low-rate period)
  covers F samples from its index.
* Consecutive indices become one :class:`~mr_ident.io.blocks.Block`; a missing index
  ends a block, so the aligner sees a hole and never estimates across it. Repeated or
  out-of-order samples reach the aligner as the block contract's do.
* Several sources for one signal (MIMO, one channel each) are joined by index
  (:class:`Joiner`); an index where a channel is missing is a hole.
* :func:`grid_stamps` is the inverse, for a publisher: the stamp (ns) of sample index i
  on a grid starting at t0 is ``t0 + round(i 1e9 / fs_high)``, exact in integers (no
  drift however long it runs).
* :func:`infer_rate` reads fs_high (or h_l for a held source) off the stamps, for the
  check against the configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..io.blocks import Block
from ..numerics.arrays import BoolArray, FloatArray, IntArray

#: Stamps further than this fraction of h_h from their grid point are anomalies (default).
TOLERANCE = 0.25


@dataclass
class SourceStats:
    """Counters of one source."""

    messages: int = 0
    samples: int = 0
    off_grid: int = 0  # stamps beyond the tolerance (dropped)
    unmatched: int = 0  # messages where the path gave no value (dropped)
    worst_offset: float = 0.0  # largest |stamp - grid| seen, in sample times
    backwards: int = 0  # stamps earlier than the one before (in arrival order)
    last_stamp: int = -1

    def as_dict(self) -> dict[str, float]:
        """Every counter by name."""
        return dict(self.__dict__)


class Sampler:
    """Stamps (ns) to sample indices on the high-rate grid, with one t0 for every source."""

    def __init__(self, fs_high: float, tolerance: float = TOLERANCE, t0: int | None = None):
        self.fs_high = float(fs_high)
        self.tolerance = float(tolerance)
        self.t0 = t0

    def indices(
        self, stamps: IntArray, stats: SourceStats | None = None
    ) -> tuple[IntArray, BoolArray]:
        """Sample index of each stamp, and whether it is on the grid (within the tolerance)."""
        if self.t0 is None and stamps.size:
            self.t0 = int(stamps[stamps >= 0].min(initial=int(stamps.max())))
        t0 = 0 if self.t0 is None else self.t0
        x = (stamps - t0).astype(np.float64) * (self.fs_high * 1e-9)
        idx = np.rint(x).astype(np.int64)
        off = np.abs(x - idx)
        ok = (off <= self.tolerance) & (idx >= 0) & (stamps >= 0)
        if stats is not None:
            seq = np.concatenate([[stats.last_stamp], stamps]) if stats.last_stamp >= 0 else stamps
            stats.backwards += int((np.diff(seq) < 0).sum())
            if stamps.size:
                stats.last_stamp = int(stamps[-1])
            stats.off_grid += int((~ok).sum())
            if off.size:
                stats.worst_offset = max(stats.worst_offset, float(off.max()))
        return idx, ok


def grid_stamps(t0: int, first: int, n: int, fs_high: float) -> IntArray:
    """Stamps (ns) of sample indices ``first .. first + n - 1`` on the grid from ``t0`` (ns).

    ``t0 + round(i 1e9 / fs_high)`` in integer arithmetic (fs_high taken as a fraction
    of denominator at most 1000), so a publisher's stamps come from the sample index and
    never drift. Shape (n,), int64.
    """
    from fractions import Fraction

    q = Fraction(fs_high).limit_denominator(1000)
    num, den = q.numerator, q.denominator
    scale = 1_000_000_000 * den  # stamp(i) = t0 + round(i scale / num)
    base, rem = divmod(int(first) * scale, num)
    j = np.arange(int(n), dtype=np.int64)
    if n and (int(n) * scale + num) >= 2**62:
        raise ValueError(f"n must be below {2**62 // scale} samples per call, got {n}")
    out: IntArray = int(t0) + base + (2 * (rem + j * scale) + num) // (2 * num)
    return out


def runs(index: IntArray, values: FloatArray, hold: int = 1) -> list[Block]:
    """Blocks of consecutive indices; ``values`` (n, c).

    ``hold`` > 1: each value covers ``hold`` samples from its index. Sorted by index
    (stable: repeats keep their order).
    """
    if index.size == 0:
        return []
    if hold > 1:
        index = (index[:, None] + np.arange(hold)[None, :]).ravel()
        values = np.repeat(values, hold, axis=0)
    order = np.argsort(index, kind="stable")
    index, values = index[order], values[order]
    cuts = np.flatnonzero(np.diff(index) != 1) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts, [index.size]])
    return [Block(int(index[a]), values[a:b]) for a, b in zip(starts, ends, strict=True)]


@dataclass
class Joiner:
    """Channels of one signal from several sources, joined by sample index.

    :meth:`offer` takes one source's indices and values; :meth:`take` returns the indices
    every source has (values (n, channels)), keeping the rest until they are complete or
    fall behind by more than ``keep`` samples (then they are dropped: a hole).
    """

    channels: int
    keep: int = 1 << 20
    _idx: list[IntArray] = field(default_factory=list)
    _val: list[FloatArray] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._idx = [np.zeros(0, np.int64) for _ in range(self.channels)]
        self._val = [np.zeros(0) for _ in range(self.channels)]

    def offer(self, channel: int, index: IntArray, values: FloatArray) -> None:
        """Add samples of one channel (a later value for an index replaces an earlier one)."""
        idx = np.concatenate([self._idx[channel], index])
        val = np.concatenate([self._val[channel], values])
        last = idx.size - 1 - np.unique(idx[::-1], return_index=True)[1]
        self._idx[channel], self._val[channel] = idx[last], val[last]

    def take(self) -> tuple[IntArray, FloatArray]:
        """Indices complete in every channel (sorted) and their values (n, channels)."""
        common = self._idx[0]
        for i in self._idx[1:]:
            common = np.intersect1d(common, i, assume_unique=True)
        out = np.empty((common.size, self.channels))
        top = int(max((i.max(initial=-1) for i in self._idx), default=-1))
        for c in range(self.channels):
            pos = np.searchsorted(self._idx[c], common)
            out[:, c] = self._val[c][pos]
            rest = ~np.isin(self._idx[c], common) & (self._idx[c] > top - self.keep)
            self._idx[c], self._val[c] = self._idx[c][rest], self._val[c][rest]
        return common, out


def infer_rate(stamps: IntArray) -> float | None:
    """The rate (Hz) of evenly spaced stamps (ns); None below 3 stamps.

    Each stamp gets its grid number from the median spacing (so missing samples count),
    then the spacing is the least-squares slope of stamp against number: exact for
    stamps rounded to ns, unbiased under jitter.
    """
    s = np.unique(stamps[stamps >= 0])
    if s.size < 3:
        return None
    d = float(np.median(np.diff(s)))
    k = np.rint((s - s[0]) / d)
    x = (s - s[0]).astype(np.float64)
    kc = k - k.mean()
    slope = float(np.dot(kc, x - x.mean()) / np.dot(kc, kc))
    return 1e9 / slope
