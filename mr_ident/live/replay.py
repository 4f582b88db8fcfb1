"""Offline replay: a recording through the node's own steps, without a ROS graph.

:func:`replay` reads the block messages of a recording
(:func:`~mr_ident.io.recording.read_blocks`),
offers them to the node's :class:`~mr_ident.live.ingest.Ingest` and
:class:`~mr_ident.live.align.Aligner`, and runs :func:`~mr_ident.live.estimate.estimate` on
the window the node would have identified. :func:`recorded_signals` gives the latest
clean stretch as data (for ``diagnose``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError
from ..io.blocks import Block, BlockError
from ..io.config import IdentConfig
from ..io.recording import RecordingInfo, read_blocks
from ..numerics.signals import LoopData
from .align import Aligner, StreamStats
from .estimate import Estimate, estimate
from .ingest import Ingest


def _feed(
    al: Aligner, items: Sequence[tuple[int, int, Block | BlockError]], stop: int | None = None
) -> list[str]:
    """Offer the decoded items (those starting before ``stop``) to ``al``; return the notes.

    Through the node's own :class:`~mr_ident.live.ingest.Ingest`; at the end what never
    came is expired.
    """
    ingest = Ingest(al)
    notes = []
    for stream, _, item in items:
        first = item.first if isinstance(item, Block) else (item.span[0] if item.span else None)
        if stop is not None and first is not None and first >= stop:
            continue
        note = ingest.offer(stream, item)
        if note:
            notes.append(note)
    notes += ingest.expire(float("inf"), 0.0)  # what is still missing at the end never came
    return notes


@dataclass(frozen=True)
class ReplayResult:
    """Outcome of :func:`replay`."""

    estimate: Estimate
    stats: dict[str, StreamStats]
    info: RecordingInfo
    anomalies: tuple[str, ...]


def replay(
    path: str | Path,
    config: IdentConfig,
    *,
    topics: Sequence[str] | None = None,
    stop: int | None = None,
) -> ReplayResult:
    """Run a recording through the node's alignment and identification, offline.

    The estimate is computed from the last aligned window (``config.window_s``)
    ending at or before sample index ``stop`` (default: the end of the data) -
    the window the live node identified last when it saw the same blocks.
    """
    items, info, _ = read_blocks(path, topics)
    al = Aligner(config.window_samples, config.ratio, config.reorder_blocks)
    notes = _feed(al, items, stop)
    w = al.window(config.min_samples, stop=stop)
    if w is None:
        lo, hi = al.span(stop)
        raise DataError(
            f"{path}: the recording holds no gap-free aligned window of at least "
            f"{config.min_samples} samples (min_window_s = {config.min_window_s:g} s); "
            f"aligned span at the end: {max(0, hi - lo)} samples" + _what_broke(al, notes, info)
        )
    return ReplayResult(estimate(w, config), al.stats, info, tuple(notes))


def _what_broke(al: Aligner, notes: Sequence[str], info: RecordingInfo | None = None) -> str:
    """Why a recording gives less aligned data than it should: "" or ".

    <parts>" to append to a message (the truncation too when ``info`` is given).
    """
    parts = []
    if info is not None and info.truncated:
        parts.append(
            f"cut short: recovered {sum(info.messages.values())} messages, {info.bytes_read} of "
            f"{info.file_bytes} bytes ({info.reason})"
        )
    kinds = ("gaps", "restarts", "late", "malformed", "nonfinite")
    for name, st in al.stats.items():
        counts = [f"{getattr(st, k)} {k}" for k in kinds if getattr(st, k)]
        if counts:
            parts.append(f"{name}: {', '.join(counts)}")
    if notes:
        parts.append(f"first: {notes[0]}")
    return "; " + "; ".join(parts) if parts else ""


def recorded_signals(
    path: str | Path, ratio: int, *, topics: Sequence[str] | None = None
) -> tuple[LoopData, RecordingInfo]:
    """r, u, y of the latest gap-free aligned span of a recording (all of it when clean).

    ``first`` is the span's first sample index.

    Raises
    ------
    DataError
        As :func:`read_blocks`, or when no aligned sample exists.
    """
    items, info, _ = read_blocks(path, topics)
    total = sum(item.samples.shape[0] for _, _, item in items if isinstance(item, Block))
    al = Aligner(max(total, ratio), ratio, reorder_blocks=8)
    notes = _feed(al, items)
    w = al.window(ratio)
    if w is None:
        raise DataError(
            f"{path}: the recording holds no aligned samples of r, u and y"
            + _what_broke(al, notes, info)
        )
    info.span = (w.first, w.end)
    if al.restarts:
        info.broken = _what_broke(al, notes).removeprefix("; ")
    return w, info
