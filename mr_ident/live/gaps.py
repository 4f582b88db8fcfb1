# SPDX-License-Identifier: Apache-2.0
"""Which holes of u and y the aligned window bridges as missing samples: :class:`Bridging`.

A sample of u or y that never came (a dropped message, a block of NaN) is a missing sample
of the fit (:func:`~mr_ident.numerics.identify.identify` estimates it), so the
:class:`~mr_ident.live.align.Aligner` puts NaN there and the window goes on - up to the
limits of :func:`~mr_ident.numerics.lifted.options.missing_limits`: a hole longer than
``gap`` samples, or one that would make the window miss more than ``share`` of a signal,
splits the stream instead (the window restarts after it). A hole of r (the excitation, known
at every sample) or of the excitation's labels always splits. The method page ("Missing
samples", "The limit") derives the limits.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from ..errors import MrIdentError
from ..io.config import IdentConfig
from ..numerics.lifted.options import default_n, missing_limits

#: The streams whose holes may be bridged: r (0), u (1) and y (2).
BRIDGED = (0, 1, 2)
#: Why the others' never are (the excitation's labels).
NOT_BRIDGED = {3: "the labels are never estimated"}
#: The longest hole of r bridged, in blocks of F samples: a block's r is recovered from
#: its u - r or the controller's equation with its neighbours received; longer runs of
#: lost blocks are not (their r would be guessed).
R_GAP_BLOCKS = 1


@dataclass(frozen=True)
class Bridging:
    """The holes a stream of u or y bridges.

    Attributes
    ----------
    gap : int
        The longest hole (consecutive missing samples) bridged.
    share : float
        The largest share of a window's samples missing; the window a hole falls in is
        the last ``window`` samples of the stream ending with it, and at least
        ``min_samples`` long (the shortest window identified). Checked at every hole, this
        holds for every window of ``window`` samples or fewer (down to ``min_samples``)
        that starts after the stream's last restart.
    min_samples : int
        The shortest window identified.
    window : int
        The longest window identified (a whole recording: its length).
    gap_reason : str
        Why ``gap`` is the limit, where another rule than the fit's sets it ("": the fit).
    """

    gap: int
    share: float
    min_samples: int
    window: int
    gap_reason: str = ""

    def refuses(self, holes: Holes, lo: int, hi: int, origin: int) -> str:
        """Why the hole [lo, hi) cannot be bridged, or "" (it can).

        ``holes``: the stream's bridged holes; ``origin``: where it (re)started.
        """
        if hi - holes.run_from(lo) > self.gap:
            return f"longer than {self.gap} samples{self.gap_reason}"
        base = max(origin, hi - self.window)
        missing = holes.count(base, lo) + hi - lo
        length = max(hi - base, self.min_samples)
        if missing > self.share * length:
            return (
                f"{missing} of the window's {length} samples would be missing, more than "
                f"{100 * self.share:.1f} %"
            )
        return ""

    def describe(self) -> str:
        """The limits in words, for a message."""
        return f"at most {self.gap} samples a hole, {100 * self.share:.1f} % of a window"


def stream_bridging(b: Bridging | None, stream: int, ratio: int) -> Bridging | None:
    """The limits for one stream's holes (None: every hole splits).

    ``b`` for u and y; for r at most :data:`R_GAP_BLOCKS` blocks a hole; None for the labels.
    """
    if b is None or stream not in BRIDGED:
        return None
    if stream != 0 or b.gap <= R_GAP_BLOCKS * ratio:
        return b
    why = ": r is recovered within a block, from its neighbours"
    return replace(b, gap=R_GAP_BLOCKS * ratio, gap_reason=why)


#: ``(n_in, n_out) -> Bridging`` (the channel counts known once the streams came), or None.
BridgeRule = Callable[[int, int], Bridging | None]


def bridging(
    n_samples: int,
    min_samples: int,
    *,
    ratio: int,
    method: str = "freq-lifted",
    n: int = 0,
    degree: int = 2,
    local: str = "polynomial",
) -> BridgeRule:
    """The bridging rule for windows of ``n_samples`` (none shorter than ``min_samples``).

    For the fit ``method`` with window ``n`` (0: automatic), ``degree`` and ``local``; the
    defaults are ``identify``'s. The node and replay: ``config.window_samples`` and
    ``config.min_samples`` (:func:`config_bridging`); a whole recording: its length, both.
    None (nothing bridged) where the fits carry no missing sample.
    """

    def rule(n_in: int, n_out: int) -> Bridging | None:
        try:
            nj = n or default_n(method, degree, ratio, n_in, n_out, local)
            lim = missing_limits(
                method,
                nj,
                degree,
                ratio,
                n_in,
                n_out,
                local=local,
                n_samples=n_samples,
                auto=n == 0,
            )
        except MrIdentError:  # options these channels cannot have: identify will say so
            return None
        if lim.gap < 1 or lim.share <= 0.0:
            return None
        return Bridging(lim.gap, lim.share, int(min_samples), int(n_samples))

    return rule


def config_bridging(
    config: IdentConfig, n_samples: int | None = None, min_samples: int | None = None
) -> BridgeRule | None:
    """:func:`bridging` with the options of ``config``; its window unless given.

    None for a y at the low rate (its holes are not estimated: every hole restarts) and
    with an excitation's labels (the periodic average needs every sample).
    """
    if config.y_rate == "low" or config.excitation_index_topic:
        return None
    return bridging(
        config.window_samples if n_samples is None else n_samples,
        config.min_samples if min_samples is None else min_samples,
        ratio=config.ratio,
        method=config.method,
        n=config.n,
        degree=config.degree,
        local=config.local,
    )


def _never(n_in: int, n_out: int) -> Bridging | None:
    return None


#: The rule that bridges nothing (every hole splits).
NO_BRIDGING: BridgeRule = _never


class Holes:
    """The bridged holes of one stream: runs ``[lo, hi)`` in index order."""

    def __init__(self) -> None:
        self.runs: deque[tuple[int, int]] = deque()

    def clear(self) -> None:
        """No hole any more (the stream restarted)."""
        self.runs.clear()

    def add(self, lo: int, hi: int) -> None:
        """Samples [lo, hi) missing (after every run held), joined to a run ending at lo."""
        if self.runs and self.runs[-1][1] == lo:
            lo = self.runs.pop()[0]
        self.runs.append((lo, hi))

    def run_from(self, lo: int) -> int:
        """Where the hole that would start at ``lo`` begins (a run ending at lo joins it)."""
        return self.runs[-1][0] if self.runs and self.runs[-1][1] == lo else lo

    def count(self, lo: int, hi: int) -> int:
        """Missing samples in [lo, hi)."""
        return sum(max(0, min(b, hi) - max(a, lo)) for a, b in self.runs if b > lo and a < hi)

    def first_end(self, lo: int, hi: int) -> int | None:
        """The end of the first run that reaches into [lo, hi), or None."""
        return next((b for a, b in self.runs if b > lo and a < hi), None)

    def trim(self, keep_from: int) -> None:
        """Forget the runs wholly before ``keep_from``."""
        while self.runs and self.runs[0][1] <= keep_from:
            self.runs.popleft()


def union_count(holes: list[Holes], lo: int, hi: int) -> int:
    """Indices in [lo, hi) where any of ``holes`` misses a sample."""
    runs = sorted((max(a, lo), min(b, hi)) for h in holes for a, b in h.runs if b > lo and a < hi)
    total, end = 0, lo
    for a, b in runs:
        if b > end:
            total += b - max(a, end)
            end = b
    return total
