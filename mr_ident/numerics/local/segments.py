# SPDX-License-Identifier: Apache-2.0
"""Which centre bins a method fits, and with which window: runs, gathered into padded segments.

A method fits its local model at centre bins k = 0..K-1 of its spectrum (the low-rate
bins 0..M//2 of a lifted method, 0..N//2 of ``lpm``). Usually every bin with one half-width
n; the automatic window (:mod:`mr_ident.numerics.local.bandwidth`) asks for a few candidate
widths on a sample of bins, then for every bin with its own width. Both are *runs*
``(start, stop, n)``: consecutive centre bins and their half-width.

The engines fit every centre of a contiguous padded spectrum. Runs of one width are
therefore gathered into :class:`Segments`: each run with ``pad`` bins of context each side
(``n``, or ``2n`` for the two stages of ``structured``), the pieces laid end to end as one
spectrum. Between two runs lie ``2 pad`` centres whose windows straddle both: the engine
is asked for the runs' centres only (``keep``), so it forms its windowed sums over the
whole stretch but solves at those alone. One engine call per segment, whatever the number
of runs in it, so a sparse sample of bins costs one call per width, not one per run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError
from ..arrays import BoolArray, ComplexArray, IntArray

#: A run of centre bins ``start .. stop-1`` fitted with half-width ``n``; a fourth element
#: h > 0: its windows solved every ``2h + 1`` bins (:mod:`mr_ident.numerics.local.strided`).
Run = tuple[int, ...]


def run_offsets(run: Run) -> int:
    """The offset h of a run (0 when it has none: every window solved at its centre)."""
    return run[3] if len(run) > 3 else 0


@dataclass(frozen=True)
class Segments:
    """Runs of one half-width laid end to end for one engine call.

    Attributes
    ----------
    n : int
        The half-width.
    pad : int
        Context bins each side of every run.
    window : ndarray of int, shape (W,)
        The spectrum's bins to gather, in order (may reach below 0 or past K: the callers'
        gathers are periodic); ``W = sum(len(run) + 2 pad)``.
    keep : ndarray of int, shape (n_bins,)
        Positions in the engine's output (``W - 2 pad`` centres) that are the runs' centres.
    bins : ndarray of int, shape (n_bins,)
        The centre bins at ``keep``, increasing.
    offsets : int
        h of the runs (0: every window solved at its centre).
    """

    n: int
    pad: int
    window: IntArray
    keep: IntArray
    bins: IntArray
    offsets: int = 0

    @property
    def whole(self) -> bool:
        """One run: every centre of the engine's output is kept (no selection needed)."""
        return self.keep.size == self.window.size - 2 * self.pad

    @property
    def span(self) -> range | None:
        """The run as a range when :attr:`whole`, else None."""
        if not self.whole:
            return None
        return range(int(self.bins[0]), int(self.bins[-1]) + 1)


def full_run(n_bins: int, n: int) -> tuple[Run, ...]:
    """Every centre bin 0..n_bins-1 with half-width n."""
    return ((0, n_bins, n),)


def runs_of(widths: IntArray, offsets: IntArray | None = None) -> tuple[Run, ...]:
    """Run-length code of a half-width per centre bin: ``(start, stop, n)`` in bin order.

    With ``offsets`` (one h per bin), ``(start, stop, n, h)`` where h > 0.
    """
    w = np.asarray(widths, dtype=np.int64)
    if w.ndim != 1 or w.size == 0:
        raise ConfigError(f"widths must be a non-empty 1-D array, got shape {w.shape}")
    h = np.zeros_like(w) if offsets is None else np.asarray(offsets, dtype=np.int64)
    edges = np.flatnonzero((np.diff(w) != 0) | (np.diff(h) != 0)) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [w.size]])
    return tuple(
        (int(a), int(b), int(w[a])) + ((int(h[a]),) if h[a] else ())
        for a, b in zip(starts, stops, strict=True)
    )


def check_runs(runs: Sequence[Run], n_bins: int) -> None:
    """ConfigError unless the runs are non-empty, inside 0..n_bins-1 and do not overlap."""
    last = 0
    for run in sorted(runs):
        a, b, n = run[:3]
        if not (0 <= a < b <= n_bins) or n < 1 or a < last or run_offsets(run) < 0:
            raise ConfigError(
                f"runs must be non-overlapping (start, stop, n) with 0 <= start < stop <= "
                f"{n_bins} and n >= 1; got {tuple(runs)!r}"
            )
        last = b


def segments(runs: Sequence[Run], pad_per_n: int, max_bins: int) -> list[Segments]:
    """Group runs by half-width into segments of at most ``max_bins`` centre bins each.

    Runs longer than ``max_bins`` are split; short runs of one width (and offset) share a
    segment. ``pad = pad_per_n * n`` context bins each side of every piece.
    """
    if max_bins < 1:
        raise ConfigError(f"max_bins must be >= 1, got {max_bins}")
    by_n: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for run in sorted(runs):
        a, b, n = run[:3]
        for s in range(a, b, max_bins):
            by_n.setdefault((n, run_offsets(run)), []).append((s, min(s + max_bins, b)))
    out: list[Segments] = []
    for (n, h), pieces in sorted(by_n.items()):
        pad = pad_per_n * n
        group: list[tuple[int, int]] = []
        count = 0
        for a, b in pieces + [(0, 0)]:  # a sentinel flushes the last group
            if group and (b == a or count + (b - a) > max_bins):
                out.append(_gather(group, n, pad, h))
                group, count = [], 0
            if b > a:
                group.append((a, b))
                count += b - a
    return out


def _gather(pieces: list[tuple[int, int]], n: int, pad: int, h: int) -> Segments:
    window = np.concatenate([np.arange(a - pad, b + pad) for a, b in pieces])
    offsets = np.cumsum([0] + [b - a + 2 * pad for a, b in pieces[:-1]])
    keep = np.concatenate(
        [o + np.arange(b - a) for o, (a, b) in zip(offsets, pieces, strict=True)]
    )
    bins = np.concatenate([np.arange(a, b) for a, b in pieces])
    for arr in (window, keep, bins):
        arr.flags.writeable = False
    return Segments(n, pad, window, keep, bins, h)


def covers(plan: tuple[Run, ...], n_bins: int) -> bool:
    """The runs fit every centre bin 0..n_bins-1."""
    return n_centres(plan) == n_bins


def n_centres(plan: tuple[Run, ...]) -> int:
    """How many centre bins the runs cover."""
    return sum(run[1] - run[0] for run in plan)


def in_bin_order(segs: list[Segments], parts: list[ComplexArray], n_bins: int) -> ComplexArray:
    """Bins-first arrays of the segments (each (len(seg.bins), ...)) put in bin order.

    Shape (n_bins, ...); bins no segment fits are left uninitialised (callers keep the
    lifted maps only when the runs cover every bin).
    """
    if len(parts) == 1 and segs[0].bins.size == n_bins:  # one run over every bin
        return parts[0]
    out = np.empty((n_bins,) + parts[0].shape[1:], dtype=parts[0].dtype)
    for seg, part in zip(segs, parts, strict=True):
        out[seg.bins] = part
    return out


def fitted_mask(segs: list[Segments], n_bins: int) -> BoolArray:
    """True at the centre bins the segments fit."""
    mask = np.zeros(n_bins, dtype=bool)
    for seg in segs:
        mask[seg.bins] = True
    return mask
