# SPDX-License-Identifier: Apache-2.0
"""Per-sample sources into the aligned window: the one path for the node and for replay.

Both hand :class:`SourceFeed` the stamps and values their sources gave - replay for a
whole bag at once (:func:`mr_ident.io.sources.extract`), the node for each short batch
of received messages - and it does the rest the same way: stamps to indices
(:class:`~mr_ident.live.sampling.Sampler`), held sources spread over F samples, MIMO
channels joined, runs of consecutive samples as blocks through
:class:`~mr_ident.live.ingest.Ingest`. So replay of a bag equals what the node estimated
from the same messages.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, DataError, DataFieldError
from ..io.bags import Bag
from ..io.blocks import LABELS_STREAM, STREAMS
from ..io.sources import Resolved, Samples
from .ingest import Ingest
from .sampling import TOLERANCE, Joiner, Sampler, SourceStats, infer_rate, runs

#: The signals by stream number (the labels: an excitation's, :mod:`mr_ident.io.labels`).
SIGNALS = ("r", "u", "y", "labels")


@dataclass(frozen=True)
class SignalSources:
    """The resolved sources of r, u and y (one or more each: one channel per source).

    ``labels``: none, or the three sources of an excitation's labels (realization, period,
    sample), stream 3.
    """

    r: tuple[Resolved, ...]
    u: tuple[Resolved, ...]
    y: tuple[Resolved, ...]
    labels: tuple[Resolved, ...] = ()

    @property
    def groups(self) -> tuple[tuple[Resolved, ...], ...]:
        """The sources per stream: r, u, y (and the labels, where given)."""
        return (self.r, self.u, self.y) + ((self.labels,) if self.labels else ())

    @property
    def names(self) -> tuple[str, ...]:
        """The streams' names, as the aligner's."""
        return STREAMS + ((LABELS_STREAM,) if self.labels else ())

    @property
    def all(self) -> list[tuple[int, int, Resolved]]:
        """``(stream, channel, source)`` for every source, stream 0 r, 1 u, 2 y, 3 labels."""
        return [(s, c, src) for s, group in enumerate(self.groups) for c, src in enumerate(group)]

    @property
    def topics(self) -> set[str]:
        """The topics to read (the names topics of the introspection included)."""
        return {src.topic for _, _, src in self.all} | {
            src.names_topic for _, _, src in self.all if src.names_topic
        }

    def check(self) -> None:
        """The block contract cannot be mixed with per-sample sources.

        And r and u need the same number of channels.
        """
        kinds = {src.kind == "blocks" for _, _, src in self.all}
        if kinds == {True, False}:
            raise ConfigError(
                "the block contract (a bare Float64MultiArray topic) cannot be mixed with "
                "per-sample sources: its indices come from the publisher, theirs from stamps"
            )
        if len(self.r) != len(self.u):
            raise ConfigError(
                f"r and u need the same number of sources (r excites u): {len(self.r)} and "
                f"{len(self.u)}"
            )
        if self.labels and len(self.labels) != 3:
            raise ConfigError(
                f"the excitation's labels need 3 sources (realization, period, sample), got "
                f"{len(self.labels)}"
            )


class SourceFeed:
    """Stamps and values of every source -> blocks into ``ingest`` (module docstring)."""

    def __init__(
        self,
        sources: SignalSources,
        ingest: Ingest,
        *,
        fs_high: float,
        ratio: int,
        tolerance: float = TOLERANCE,
    ):
        sources.check()
        self.sources = sources
        self.ingest = ingest
        self.ratio = int(ratio)
        self.sampler = Sampler(fs_high, tolerance)
        self.stats = [SourceStats() for _ in sources.all]
        groups = sources.groups
        self._joiners = [Joiner(len(g)) if len(g) > 1 else None for g in groups]

    def push(self, samples: Sequence[Samples | None], now: float = 0.0) -> list[str]:
        """One batch: ``samples[i]`` for source i of :attr:`SignalSources.all` (None: no message).

        Returns the notes of the aligner (gaps, restarts) for a log line.
        """
        if self.sampler.t0 is None:
            firsts = [
                int(s.stamps[s.stamps >= 0].min())
                for s in samples
                if s is not None and (s.stamps >= 0).any()
            ]
            if firsts:
                self.sampler.t0 = min(firsts)
        notes: list[str] = []
        for (stream, channel, src), smp, st in zip(
            self.sources.all, samples, self.stats, strict=True
        ):
            if smp is None or smp.stamps.size == 0:
                continue
            idx, on_grid = self.sampler.indices(smp.stamps, st)
            st.messages += int(smp.stamps.size)
            st.unmatched += int((~smp.valid).sum())
            good = on_grid & smp.valid
            idx, val = idx[good], smp.values[good]
            hold = self.ratio if src.spec.hold else 1
            st.samples += int(idx.size) * hold
            joiner = self._joiners[stream]
            if joiner is None:
                blocks = runs(idx, val[:, None], hold)
            else:
                if hold > 1:
                    idx = (idx[:, None] + np.arange(hold)[None, :]).ravel()
                    val = np.repeat(val, hold)
                joiner.offer(channel, idx, val)
                continue
            for b in blocks:
                note = self.ingest.offer(stream, b, now)
                if note:
                    notes.append(note)
        for stream, joiner in enumerate(self._joiners):
            if joiner is not None:
                idx, val = joiner.take()
                for b in runs(idx, val):
                    note = self.ingest.offer(stream, b, now)
                    if note:
                        notes.append(note)
        return notes

    def anomalies(self) -> list[str]:
        """One line per source with dropped samples (off the grid, no match)."""
        out = []
        for (stream, _, src), st in zip(self.sources.all, self.stats, strict=True):
            if st.backwards:
                out.append(
                    f"{self.sources.names[stream]} source {src.spec.text} (topic {src.topic}): "
                    "stamps go "
                    "back "
                    f"{st.backwards} times"
                )
            if st.off_grid or st.unmatched:
                out.append(
                    f"{self.sources.names[stream]} source {src.spec.text}: {st.off_grid} stamps "
                    "off the "
                    "grid by more "
                    f"than {self.sampler.tolerance:g} sample times (worst {st.worst_offset:.2f}), "
                    f"{st.unmatched} messages without a value"
                )
        return out


#: Messages a source's topic must hold: the rate and the grid are read off three stamps.
MIN_MESSAGES = 3


def enough_messages(
    bag: Bag, sources: SignalSources, samples: Sequence[Samples], *, what: str
) -> None:
    """Every source has at least :data:`MIN_MESSAGES` messages, and values in them.

    Raises
    ------
    DataError
        A topic with nothing on it, too few messages, or a path that matched in none.
    """
    topics = bag.topics

    def listing() -> str:
        read = bag.read
        return ", ".join(f"{t} ({read.get(t, topics[t].messages)})" for t in sorted(topics))

    for (_, _, src), smp in zip(sources.all, samples, strict=True):
        n = int(smp.stamps.size)
        where = f"source {src.spec.text} (topic {src.topic})"
        if n == 0:
            raise DataError(
                f"{what}: topic {src.topic} has no messages ({where}); the bag's topics and "
                f"their messages: {listing()}"
            )
        if n < MIN_MESSAGES:
            raise DataError(
                f"{what}: too few messages: topic {src.topic} holds {n} ({where}); at least "
                f"{MIN_MESSAGES} are needed to read the rate off the stamps, and an "
                "identification needs many periods of the excitation"
            )
        if not smp.valid.any():
            raise DataError(
                f"{what}: {where} gave no value in any of its {n} messages (the path matched "
                "nothing: a name or index that is not in them?)"
            )


def check_rate(
    samples: Sequence[Samples],
    sources: SignalSources,
    fs_high: float | None,
    ratio: int | None,
    *,
    what: str,
) -> tuple[float, int]:
    """fs_high and F read off the stamps.

    Checked against the configured ones (1 % for fs_high, exact for F); a value not
    configured (None) is taken from the stamps.

    Raises
    ------
    DataError
        The stamps disagree with the configuration.
    DataFieldError
        A rate the stamps cannot tell and none given: naming ``{fs_high}`` or ``{ratio}``.
    """
    fast = [
        infer_rate(s.stamps)
        for (_, _, src), s in zip(sources.all, samples, strict=True)
        if not src.spec.hold
    ]
    slow = [
        infer_rate(s.stamps)
        for (_, _, src), s in zip(sources.all, samples, strict=True)
        if src.spec.hold
    ]
    fs_est = next((f for f in fast if f), None)
    if fs_high is None:
        if fs_est is None:
            raise DataFieldError(
                f"{what}: fs_high cannot be told from the stamps (fewer than 3); give {{fs_high}}",
                "fs_high",
            )
        fs_high = fs_est
    elif fs_est is not None and abs(fs_est / fs_high - 1.0) > 0.01:
        raise DataError(
            f"{what}: the stamps say fs_high = {fs_est:.6g} Hz (median spacing), the "
            "configuration "
            f"{fs_high:g} Hz; give the rate the loop runs at"
        )
    f_low = next((f for f in slow if f), None)
    if f_low is not None:
        F_est = int(round(fs_high / f_low))
        if ratio is None:
            ratio = F_est
        elif F_est != ratio:
            raise DataError(
                f"{what}: the held source's stamps say F = {fs_high / f_low:.3g} "
                f"(low rate {f_low:.6g} Hz), the configuration F = {ratio}"
            )
    if ratio is None:
        raise DataFieldError(
            f"{what}: the ratio F cannot be told without a held (.@hold) low-rate source; give "
            "{ratio}",
            "ratio",
        )
    return float(fs_high), int(ratio)
