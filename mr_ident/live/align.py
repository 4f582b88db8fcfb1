# SPDX-License-Identifier: Apache-2.0
"""Alignment of three sample streams (r, u, y) by sample index: :class:`Aligner`.

Blocks (:class:`~mr_ident.io.blocks.Block`) are put together by sample index, never by
arrival. Each stream is kept contiguous: a sample of u or y that never arrives (a gap, a
block with NaN/inf) is a **missing sample**, NaN in the window, up to the limits of
:mod:`mr_ident.live.gaps`; a longer hole, or any hole of r (or of the labels),
**restarts** that stream after it, so the aligned window - the indices all streams hold -
restarts too and never spans it. Pure Python/numpy; the node and the offline replay share
it through :class:`~mr_ident.live.ingest.Ingest`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from ..io.blocks import LABELS_STREAM, STREAMS, Block
from ..numerics.arrays import FloatArray
from ..numerics.signals import LoopData
from .gaps import NOT_BRIDGED, BridgeRule, Bridging, Holes, stream_bridging, union_count
from .streams import SIGNALS, Stream


@dataclass
class StreamStats:
    """Counters of one stream (all monotone)."""

    blocks: int = 0  # accepted blocks
    samples: int = 0  # accepted samples
    gaps: int = 0  # holes declared (samples never arrived)
    gap_samples: int = 0  # samples in those holes
    bridged: int = 0  # holes kept in the window as missing samples (r, u, y)
    bridged_samples: int = 0  # samples in those holes
    duplicates: int = 0  # blocks wholly received before
    overlaps: int = 0  # blocks partly received before (the new tail is kept)
    late: int = 0  # blocks from before the retained start, not contiguous with it (dropped)
    reordered: int = (
        0  # blocks that arrived ahead of a missing one (later filled or declared a gap)
    )
    malformed: int = 0  # blocks breaking the layout contract
    nonfinite: int = 0  # blocks with NaN/inf (dropped: a hole)
    restarts: int = 0  # index jumped back (publisher restarted)
    end: int = -1  # next expected index (-1: nothing yet)

    def as_dict(self) -> dict[str, int]:
        """Every counter by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass
class _Stream:
    stats: StreamStats = field(default_factory=StreamStats)
    chunks: deque = field(default_factory=deque)  # (first, array) contiguous from start to end
    start: int = -1
    end: int = -1
    channels: int = 0
    pending: dict = field(default_factory=dict)  # first -> array, arrived ahead of end
    pending_since: float | None = None  # caller's clock when pending became non-empty
    origin: int = -1  # where the stream (re)started; start == origin until trimmed
    before: dict = field(
        default_factory=dict
    )  # first -> array, arrived before origin (start-up reordering)
    past: list | None = None  # with history: the chunks of every earlier contiguous run
    holes: Holes = field(default_factory=Holes)  # the bridged holes (NaN chunks) held

    def reset(self, at: int) -> None:
        if self.past is not None and self.chunks:
            self.past.append(list(self.chunks))
        self.chunks = deque()
        self.holes = Holes()
        self.start = self.end = self.origin = at
        self.before = {}
        self.pending = {k: v for k, v in self.pending.items() if k >= at}

    def append(self, first: int, x: FloatArray) -> None:
        self.chunks.append((first, x))
        self.end = first + x.shape[0]
        self.stats.end = self.end
        self.stats.blocks += 1
        self.stats.samples += x.shape[0]


class Aligner:
    """Align three block streams by sample index into a bounded, gap-free window.

    Parameters
    ----------
    capacity : int
        Window length in samples (the sliding window; older samples are dropped).
    ratio : int
        F; windows start at an index that is a multiple of F and hold whole periods.
    reorder_blocks : int
        Blocks that may wait ahead of a missing one; one more (or waiting longer
        than the caller's limit, :meth:`expire`) and the missing samples are
        declared a gap (the stream restarts after it).
    channels : sequence of 3 ints, optional
        Expected channel counts of r, u, y; otherwise fixed by each stream's first block.
    history : bool
        Keep every contiguous run of each stream, not only the latest (for a recording,
        whose spans are all wanted: :meth:`spans`, :meth:`extract`).
    labels : bool
        A fourth stream, ``Stream.LABELS`` (``LABELS_STREAM``): an excitation's labels
        (realization, period, sample) at the same indices, aligned as the others; windows
        carry them (:attr:`~mr_ident.numerics.signals.LoopData.labels`).
    bridge : callable, optional
        ``(n_in, n_out) -> Bridging | None`` (:func:`~mr_ident.live.gaps.bridging`): the
        holes of r, u and y kept as missing samples (NaN) in the window (r's up to a block:
        :func:`~mr_ident.live.gaps.stream_bridging`); None: every hole restarts.

    Policy: a hole of r, u or y within the bridging limits is kept as missing samples; any
    other hole restarts the stream after it (so the window restarts). A block
    that starts before the stream's end must repeat the samples held for the
    indices they share: then it is a duplicate (wholly behind the end; ignored)
    or an overlap (its new tail is kept). A block that ends where the held
    samples start is prepended (the first blocks arrived out of order); one
    otherwise before the retained start, within a window of the end, is late
    (dropped). Anything else - an index that went back to other samples - means
    the publisher restarted its index, or the block is wrong: the stream restarts
    after that block (which is not used). So a window never holds two different
    samples for one index, nor the block that disagreed.
    """

    def __init__(
        self,
        capacity: int,
        ratio: int,
        reorder_blocks: int = 8,
        *,
        channels: Sequence[int] | None = None,
        history: bool = False,
        labels: bool = False,
        bridge: BridgeRule | None = None,
    ):
        self.capacity = int(capacity)
        self._rule = bridge
        self._bridging: dict[tuple[int, int], Bridging | None] = {}
        #: Why the streams restarted at holes they could not bridge (the latest 64).
        self.breaks: deque[str] = deque(maxlen=64)
        self.ratio = int(ratio)
        self.reorder_blocks = int(reorder_blocks)
        #: The streams' names: r, u, y (and the labels).
        self.names = STREAMS + ((LABELS_STREAM,) if labels else ())
        self._s = [_Stream(past=[] if history else None) for _ in self.names]
        if channels is not None:
            for s, c in zip(self._s, channels, strict=False):
                s.channels = int(c)
        if labels:
            self._s[Stream.LABELS].channels = 3
        self.restarts = 0  # times the aligned window had to start again

    @property
    def stats(self) -> dict[str, StreamStats]:
        """Counters per stream, by name (reference, input, output, and excitation_index)."""
        return {name: s.stats for name, s in zip(self.names, self._s, strict=True)}

    @property
    def labels(self) -> bool:
        """Whether the labels are a fourth stream."""
        return len(self._s) > len(STREAMS)

    def count(self, stream: int, kind: str) -> None:
        """Count a rejected block (kind "malformed" or "nonfinite") of ``stream``."""
        setattr(self._s[stream].stats, kind, getattr(self._s[stream].stats, kind) + 1)

    def push(self, stream: int, block: Block, now: float = 0.0) -> str | None:
        """Add one decoded block of ``stream`` (a :class:`~.streams.Stream`, or its index).

        ``now`` is the caller's clock (for :meth:`expire`).

        Returns None, or a short description of an anomaly (for a log line).
        """
        s = self._s[stream]
        x, first = block.samples, block.first
        n = x.shape[0]
        if s.channels and x.shape[1] != s.channels:
            s.stats.malformed += 1
            return (
                f"{self.names[stream]}: block at {first} has {x.shape[1]} channels, "
                f"expected {s.channels}"
            )
        s.channels = x.shape[1]
        if s.end < 0:
            s.reset(first)
        if first == s.end:
            s.append(first, x)
            note = self._drain(stream)
            if not s.pending:
                s.pending_since = None
        elif first > s.end:
            if not s.pending:
                s.pending_since = now
            s.pending[first] = x
            s.stats.reordered += 1
            note = self._declare_gap(stream, now) if len(s.pending) > self.reorder_blocks else None
        elif first + n > s.end and self._agrees(s, first, x):
            s.stats.overlaps += 1
            s.append(s.end, x[s.end - first :])
            note = self._drain(stream)
        elif first + n <= s.end and self._agrees(s, first, x):
            s.stats.duplicates += 1
            return f"{self.names[stream]}: block [{first}, {first + n}) received twice; ignored"
        elif (
            first < s.start and s.end - first <= self.capacity + self.ratio and s.start == s.origin
        ):
            # the stream's first blocks arrived out of order: put them in front
            s.stats.reordered += 1
            s.before[first] = x
            while s.before:
                k = next((k for k, v in s.before.items() if k + v.shape[0] == s.start), None)
                if k is None:
                    break
                v = s.before.pop(k)
                s.chunks.appendleft((k, v))
                s.start = s.origin = k
                s.stats.blocks += 1
                s.stats.samples += v.shape[0]
            return None
        elif first < s.start and s.end - first <= self.capacity + self.ratio:
            s.stats.late += 1  # before the retained start: too late to use
            return (
                f"{self.names[stream]}: block at {first} arrived too late "
                f"(stream starts at {s.start}); dropped"
            )
        else:
            note = self._restart(stream, first, x)
        self._trim(s)
        return note

    def _agrees(self, s: _Stream, first: int, x: FloatArray) -> bool:
        """Whether a block starting before the stream's end repeats the samples held there."""
        hi = min(s.end, first + x.shape[0])
        if hi <= first:
            return True
        if first < s.start:
            return False
        held = self._extract(s, first, hi)
        known = ~np.isnan(held)  # a bridged hole takes what comes late (it stays missing)
        return bool(np.array_equal(held[known], x[: hi - first][known]))

    def _restart(self, stream: int, first: int, x: FloatArray) -> str:
        """Index went back to samples that differ from those held: restart after the block.

        The publisher restarted, or the block is wrong: neither is trusted.
        """
        s = self._s[stream]
        s.stats.restarts += 1
        end = first + x.shape[0]
        note = (
            f"{self.names[stream]}: index went back from {s.end} to {first} with other samples; "
            f"stream restarts at {end}"
        )
        s.pending.clear()
        s.reset(end)
        s.stats.end = end
        self.restarts += 1
        return note

    def _drain(self, stream: int) -> str | None:
        """Append the pending blocks that have become contiguous with the stream's end."""
        s = self._s[stream]
        note = None
        while s.pending:
            k = min(s.pending)
            if k > s.end:
                break
            x = s.pending.pop(k)
            if x.size and np.isnan(x).all():  # a hole (a block of NaN) that waited
                if k + x.shape[0] > s.end:
                    note = self._bridge(stream, s.end, k + x.shape[0], "lost") or note
            elif not self._agrees(s, k, x):
                note = self._restart(stream, k, x)
            elif k + x.shape[0] <= s.end:
                s.stats.duplicates += 1
            else:
                s.stats.overlaps += 1
                s.append(s.end, x[s.end - k :])
        return note

    def _declare_gap(self, stream: int, now: float | None = None) -> str | None:
        """The samples before the first pending block will not come: bridge or restart.

        None when bridged, else the note of the restart. The blocks still waiting wait
        afresh from ``now``.
        """
        s = self._s[stream]
        k = min(s.pending)
        s.stats.gaps += 1
        s.stats.gap_samples += k - s.end
        note = self._bridge(stream, s.end, k, "gap")
        note = self._drain(stream) or note
        s.pending_since = now if s.pending else None
        self._trim(s)
        return note

    def expire(self, now: float, max_wait: float) -> list[str]:
        """Declare a gap where blocks waited ahead of a missing one longer than ``max_wait``.

        ``now`` and ``max_wait`` on the clock of :meth:`push`'s ``now``; returns the notes.
        ``now = inf`` declares every gap still pending (the end of a recording: what has not
        come never will).
        """
        notes = []
        for i, s in enumerate(self._s):
            while s.pending and s.pending_since is not None and now - s.pending_since > max_wait:
                note = self._declare_gap(i)
                if note:
                    notes.append(note)
                if s.pending:  # the blocks after the next hole wait afresh; at the end, not at all
                    s.pending_since = now if now != float("inf") else float("-inf")
        return notes

    def hole(self, stream: int, first: int, n: int, now: float = 0.0) -> str | None:
        """Samples [first, first+n) of ``stream`` are lost (e.g. a NaN block).

        Returns None (bridged, or before the stream's end), or why the stream restarts.
        """
        s = self._s[stream]
        if s.end >= 0 and first + n <= s.end:
            return None
        s.stats.gaps += 1
        s.stats.gap_samples += n
        if s.end >= 0 and s.channels and first > s.end:  # waits, as a block, for the gap
            if not s.pending:
                s.pending_since = now
            s.pending[first] = np.full((n, s.channels), np.nan)
            return self._declare_gap(stream, now) if len(s.pending) > self.reorder_blocks else None
        if s.end >= 0 and s.channels:
            note = self._bridge(stream, s.end, first + n, "lost")
            note = self._drain(stream) or note
            self._trim(s)
            return note
        s.reset(first + n)
        s.stats.end = s.end
        self.restarts += 1
        return (
            f"{self.names[stream]}: samples [{first}, {first + n}) lost; "
            f"window restarts at {first + n}"
        )

    def bridging(self) -> Bridging | None:
        """The bridging limits for the channels seen so far (None: every hole restarts)."""
        if self._rule is None:
            return None
        r, u, y = (max(self._s[i].channels, 1) for i in SIGNALS)
        key = (r, max(u, y))
        if key not in self._bridging:
            self._bridging[key] = self._rule(*key)
        return self._bridging[key]

    def _bridge(self, stream: int, lo: int, hi: int, how: str) -> str | None:
        """Samples [lo, hi) of ``stream`` (from its end) missing: NaN, or a restart at hi.

        None when bridged, else the note: the hole, the limit it broke, where the stream
        restarts (also kept in :attr:`breaks`).
        """
        s = self._s[stream]
        b = stream_bridging(self.bridging(), stream, self.ratio)
        why = ""
        if b is None:  # the labels are never bridged, nor anything without a rule
            told = self._rule is not None or stream == Stream.LABELS
            why = NOT_BRIDGED.get(stream, "") if told else ""
        else:
            why = b.refuses(s.holes, lo, hi, s.origin)
        if b is not None and not why:
            s.chunks.append((lo, np.full((hi - lo, s.channels), np.nan)))
            s.end = s.stats.end = hi
            s.holes.add(lo, hi)
            s.stats.bridged += 1
            s.stats.bridged_samples += hi - lo
            return None
        head = (
            f"gap of {hi - lo} samples at [{lo}, {hi})"
            if how == "gap"
            else f"samples [{lo}, {hi}) lost"
        )
        note = (
            f"{self.names[stream]}: {head}"
            + (f" ({why})" if why else "")
            + f"; window restarts at {hi}"
        )
        s.reset(hi)
        s.stats.end = hi
        self.restarts += 1
        self.breaks.append(note)
        return note

    def _trim(self, s: _Stream) -> None:
        # Keep what the aligned window (ending at the slowest stream's end) can still use,
        # so a stream running ahead of the others never shortens it; a stream more than
        # one window ahead keeps two windows (memory stays bounded if another stalls).
        hi = min(x.end for x in self._s if x.end >= 0)
        keep_from = max(hi, s.end - self.capacity) - self.capacity - self.ratio
        while s.chunks and s.chunks[0][0] + s.chunks[0][1].shape[0] <= keep_from:
            s.chunks.popleft()
        s.holes.trim(keep_from)
        s.start = s.chunks[0][0] if s.chunks else s.end

    def span(self, stop: int | None = None) -> tuple[int, int]:
        """Aligned [first, end) the next :meth:`window` would return (end <= first: none)."""
        if any(s.end < 0 for s in self._s):
            return 0, 0
        F = self.ratio
        hi = min(s.end for s in self._s)
        if stop is not None:
            hi = min(hi, stop)
        hi = hi // F * F  # whole periods, on the F grid at both ends
        lo = max(-(-max(s.start for s in self._s) // F) * F, hi - self.capacity)
        b = self.bridging()
        # a window later than the stream's own checks (another stream behind) stays
        # within the share: it starts after the holes that would break it
        for s in (self._s[i] for i in SIGNALS):
            while (
                b is not None
                and hi > lo
                and s.holes.count(lo, hi) > b.share * max(hi - lo, b.min_samples)
            ):
                lo = -(-(s.holes.first_end(lo, hi) or hi) // F) * F
        return lo, max(lo, hi)

    def missing(self, lo: int, hi: int) -> int:
        """Indices in [lo, hi) where r, u or y is missing (bridged holes of the held samples)."""
        return union_count([self._s[i].holes for i in SIGNALS], lo, hi)

    def window(self, min_samples: int = 1, stop: int | None = None) -> LoopData | None:
        """The latest aligned window, or None when it holds fewer than ``min_samples``.

        At most ``capacity`` samples, ending at or before ``stop``; ``first`` is its absolute
        index, ``ratio`` F.
        """
        lo, hi = self.span(stop)
        if hi - lo < max(min_samples, 1):
            return None
        return self._data([self._extract(s, lo, hi) for s in self._s], lo)

    def _data(self, x: list[FloatArray], first: int) -> LoopData:
        """r, u, y (and the labels, as integers) of one span."""
        labels = np.rint(x[Stream.LABELS]).astype(np.int64) if len(x) > Stream.LABELS else None
        r, u, y = (x[i] for i in SIGNALS)
        return LoopData(r, u, y, ratio=self.ratio, first=first, labels=labels)

    def _runs(self, s: _Stream) -> list[tuple[int, int, list[tuple[int, FloatArray]]]]:
        """A stream's contiguous runs (start, end, chunks), earlier and current.

        Where the index went back, a later run holds the indices it shares with an earlier one.
        """
        runs = [list(c) for c in (s.past or [])] + ([list(s.chunks)] if s.chunks else [])
        out: list[tuple[int, int, list[tuple[int, FloatArray]]]] = []
        for k, chunks in enumerate(runs):
            lo, hi = chunks[0][0], chunks[-1][0] + chunks[-1][1].shape[0]
            pieces = [(lo, hi)]
            for later in runs[k + 1 :]:
                a, b = later[0][0], later[-1][0] + later[-1][1].shape[0]
                pieces = [
                    q for x, y in pieces for q in ((x, min(y, a)), (max(x, b), y)) if q[1] > q[0]
                ]
            out += [(x, y, chunks) for x, y in pieces]
        return out

    def spans(self) -> list[tuple[int, int]]:
        """Every aligned span ``[first, end)`` (whole periods; split at holes not bridged).

        Needs ``history`` for more than the latest.
        """
        F = self.ratio
        common = [(lo, hi) for lo, hi, _ in self._runs(self._s[0])]
        for s in self._s[1:]:
            other = [(lo, hi) for lo, hi, _ in self._runs(s)]
            common = [
                (max(a, c), min(b, d))
                for a, b in common
                for c, d in other
                if min(b, d) > max(a, c)
            ]
        snapped = ((-(-lo // F) * F, hi // F * F) for lo, hi in common)
        return sorted((lo, hi) for lo, hi in snapped if hi > lo)

    def extract(self, lo: int, hi: int) -> LoopData:
        """r, u, y of the aligned span ``[lo, hi)`` (one of :meth:`spans`)."""
        out = []
        for s in self._s:
            run = next(c for a, b, c in reversed(self._runs(s)) if a <= lo and hi <= b)
            out.append(self._extract(_Stream(chunks=deque(run)), lo, hi))
        return self._data(out, lo)

    @staticmethod
    def _extract(s: _Stream, lo: int, hi: int) -> FloatArray:
        parts = []
        for first, x in s.chunks:
            end = first + x.shape[0]
            if end <= lo:
                continue
            if first >= hi:
                break
            parts.append(x[max(lo - first, 0) : min(hi, end) - first])
        out = np.concatenate(parts, axis=0)
        assert out.shape[0] == hi - lo
        return out
