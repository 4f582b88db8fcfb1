# SPDX-License-Identifier: Apache-2.0
"""Offline replay: a recording through the node's own steps, without a ROS graph.

:func:`replay` reads the block messages of a recording
(:func:`~mr_ident.io.recording.read_blocks`),
offers them to the node's :class:`~mr_ident.live.ingest.Ingest` and
:class:`~mr_ident.live.align.Aligner`, and runs :func:`~mr_ident.live.estimate.estimate` on
the window the node would have identified. :func:`recorded_signals` gives the latest
span as data (for ``identify`` and ``diagnose``; :mod:`mr_ident.live.spans`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import DataError, DataFieldError
from ..io.blocks import Block, BlockError
from ..io.config import IdentConfig
from ..io.recording import RecordingInfo, read_blocks
from ..numerics.signals import LoopData
from .align import Aligner, StreamStats
from .bagread import read_bag
from .estimate import Estimate, estimate
from .gaps import NO_BRIDGING, BridgeRule, bridging, config_bridging
from .ingest import Ingest
from .spans import DEFAULT_SPAN, check_span, choose
from .spans import describe as describe_spans


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
    """Outcome of :func:`replay` and :func:`replay_bag`.

    ``stats``: per stream, what the alignment met (gaps, restarts, ...); ``info``: what was
    read (the span used in ``info.span``, why in ``info.broken``); ``signals``: asked for
    with ``keep_signals``, the whole span replayed (the ``span`` chosen), with the rates:
    what :func:`loop_windows` cuts the node's windows from (monitoring), from the same read.
    """

    estimate: Estimate
    stats: dict[str, StreamStats]
    info: RecordingInfo
    anomalies: tuple[str, ...]
    signals: LoopData | None = None


@dataclass(frozen=True)
class _Aligned:
    """A recording aligned twice, as the node and whole: what :func:`_replayed` takes.

    ``every``: every span with history (the holes judged by the node's limits), or what
    makes it when first needed; ``node``: the node's own window aligner fed alike (None:
    not fed, a span other than the latest);
    ``cfg``: the configuration at the recording's rates; ``what``: the recording in
    messages; ``tail``: appended to the message when no window is found.
    """

    every: Callable[[], Aligner]
    node: Aligner | None
    notes: tuple[str, ...]
    info: RecordingInfo
    cfg: IdentConfig
    what: str
    tail: str = ""


def _node_aligner(cfg: IdentConfig, labels: bool) -> Aligner:
    """The node's window aligner for ``cfg``."""
    return Aligner(
        cfg.window_samples,
        cfg.ratio,
        cfg.reorder_blocks,
        labels=labels,
        bridge=config_bridging(cfg),
    )


def _replayed(rec: _Aligned, span: str, stop: int | None, keep_signals: bool) -> ReplayResult:
    """The window the node identified last (of ``span``), its estimate and the whole span.

    The one assembly of both replays: the node's aligner as fed live for the latest span,
    else the span chosen from ``rec.every`` pushed into a fresh one (its holes as holes).
    """
    cfg = rec.cfg
    labels = bool(cfg.excitation_index_topic)
    notes = list(rec.notes)
    info = rec.info
    if span == "latest" and rec.node is not None:
        al = rec.node
    else:
        al = _node_aligner(cfg, labels)
        chosen, info = _chosen(rec.every(), span, notes, info, rec.what)
        _push(al, chosen)
        notes = [info.broken, *notes] if info.broken else notes
    win = al.window(cfg.min_samples, stop=stop)
    if win is None:
        lo, hi = al.span(stop)
        raise DataError(
            f"{rec.what}: no gap-free aligned window of at least {cfg.min_samples} samples "
            f"(min_window_s = {cfg.min_window_s:g} s at {cfg.fs_high:g} Hz); aligned span at "
            f"the end: {max(0, hi - lo)} samples; {describe_spans(rec.every().spans())}"
            + _what_broke(rec.every(), rec.notes, rec.info)
            + rec.tail
        )
    signals = None
    if keep_signals:
        whole, _ = _chosen(rec.every(), span, rec.notes, rec.info, rec.what)
        signals = replace(whole, fs_high=cfg.fs_high, ratio=cfg.ratio)
    seen = rec.node if span == "latest" and rec.node is not None else rec.every()
    return ReplayResult(estimate(win, cfg), seen.stats, info, tuple(notes), signals)


def replay(
    path: str | Path,
    config: IdentConfig,
    *,
    topics: Sequence[str] | None = None,
    stop: int | None = None,
    span: str = "latest",
    keep_signals: bool = False,
) -> ReplayResult:
    """Run a recording's block topics through the node's alignment and identification.

    The estimate is computed from the last aligned window (``config.window_s``)
    ending at or before sample index ``stop`` (default: the end of the data) -
    the window the live node identified last when it saw the same blocks. ``span``
    other than "latest": the last window of that span (:mod:`mr_ident.live.spans`)
    instead. ``keep_signals``: also the whole span (:attr:`ReplayResult.signals`).

    Raises
    ------
    DataError
        As :func:`~mr_ident.io.recording.read_blocks`; no window of ``min_window_s``.
    """
    check_span(span)
    labels = config.excitation_index_topic
    items, info, _ = read_blocks(path, topics, labels)

    fed: list[list[str]] = []

    @cache
    def every() -> Aligner:  # every span, the holes judged as the node judges them
        al = Aligner(
            1 << 62,
            config.ratio,
            config.reorder_blocks,
            history=True,
            labels=bool(labels),
            bridge=config_bridging(config),
        )
        fed.append(_feed(al, items, stop))
        return al

    node = None
    if span == "latest":  # the node's aligner, fed as it was live
        node = _node_aligner(config, bool(labels))
        notes = _feed(node, items, stop)
    else:
        every()
        notes = fed[0]
    rec = _Aligned(every, node, tuple(notes), info, config, f"{path}: the recording")
    return _replayed(rec, span, stop, keep_signals)


def replay_bag(
    path: str | Path,
    config: IdentConfig,
    specs: Mapping[str, Sequence[str]],
    *,
    fs_high: float | None = None,
    ratio: int | None = None,
    stop: int | None = None,
    span: str = "latest",
    msg_path: Sequence[str | Path] = (),
    keep_signals: bool = False,
) -> ReplayResult:
    """:func:`replay` for per-sample sources.

    The window the node would have identified last (``config.window_s``, ending at or before
    ``stop``; ``span`` other than "latest": the last window of that span);
    ``fs_high``/``ratio`` None: read off the stamps (and the configuration's replaced by
    them). ``keep_signals``: also the whole span (:attr:`ReplayResult.signals`).
    """
    check_span(span)
    read = read_bag(
        path,
        specs,
        fs_high=fs_high,
        ratio=ratio,
        stop=stop,
        history=True,
        msg_path=msg_path,
        labels=config.excitation_index_topic,
        options=config,
        node=config if span == "latest" else None,
    )
    cfg = config.replace(fs_high=read.fs_high, ratio=read.ratio)
    what = f"{path}: the sources"
    rec = _Aligned(
        lambda: read.aligner,
        read.node,
        read.notes,
        read.info,
        cfg,
        what,
        f"; sources: {read.sources}",
    )
    return _replayed(rec, span, stop, keep_signals)


def _length(items: Sequence[tuple[int, int, Block | BlockError]]) -> int:
    """The indices the items of a recording cover, first to last (0: none)."""
    firsts = [it.first for _, _, it in items if isinstance(it, Block)]
    ends = [it.end for _, _, it in items if isinstance(it, Block)]
    return max(ends) - min(firsts) if firsts else 0


def _push(al: Aligner, w: LoopData) -> None:
    """The span ``w`` into ``al``: r, u, y and, where ``al`` aligns them, the labels.

    Its missing samples (NaN rows) as holes, so ``al`` keeps them as its own would.
    """
    streams = [w.r, w.u, w.y]
    if al.labels:
        if w.labels is None:
            raise DataError("the window has no labels for an aligner that aligns them")
        streams.append(w.labels.astype(float))
    for s, x in enumerate(streams):
        lost: npt.NDArray[np.bool_] = np.asarray(np.isnan(x).any(axis=1))
        if not lost.any():
            al.push(s, Block(w.first, x))
            continue
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], lost.astype(int), [-1]])))
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            if bool(lost[int(a)]):
                al.hole(s, w.first + int(a), int(b - a))
            else:
                al.push(s, Block(w.first + int(a), x[a:b]))


def _what_broke(al: Aligner, notes: Sequence[str], info: RecordingInfo | None = None) -> str:
    """Why a recording gives less aligned data than it should, to append to a message.

    "" or "; <parts>" (the truncation too when ``info`` is given).
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
    path: str | Path,
    ratio: int,
    *,
    topics: Sequence[str] | None = None,
    span: str = DEFAULT_SPAN,
    labels: str = "",
    bridge: BridgeRule | None = None,
) -> tuple[LoopData, RecordingInfo]:
    """r, u, y of an aligned span of a recording (all of it when no hole splits it).

    Holes of u and y within ``bridge``'s limits are missing samples (NaN; default: the
    limits of ``identify``'s default options over the whole recording,
    :func:`~mr_ident.live.gaps.bridging`).

    ``span``: which one where there are gaps (:mod:`mr_ident.live.spans`; default the
    longest); ``first`` is the span's first sample index, ``info.broken`` says which span
    was used and why. ``labels``: the topic of an excitation's labels, aligned as a fourth
    block stream (the data's ``labels``; "": none).

    Raises
    ------
    DataError
        As :func:`read_blocks`, when no aligned sample exists, or ``span`` "all" with gaps.
    """
    check_span(span)
    items, info, _ = read_blocks(path, topics, labels)
    total = sum(item.samples.shape[0] for _, _, item in items if isinstance(item, Block))
    n = _length(items)
    al = Aligner(
        max(total, ratio),
        ratio,
        reorder_blocks=8,
        history=True,
        labels=bool(labels),
        bridge=bridge or bridging(n, n, ratio=ratio),
    )
    notes = _feed(al, items)
    return _chosen(al, span, notes, info, str(path))


def _chosen(
    al: Aligner, span: str, notes: Sequence[str], info: RecordingInfo, what: str
) -> tuple[LoopData, RecordingInfo]:
    """The ``span`` of an aligner with history, and ``info`` with its span and why (a copy)."""
    try:
        w, note = choose(al, span, what=what)
    except DataFieldError as err:  # the request's fields kept for the caller to say
        raise DataFieldError(err.template + _what_broke(al, notes, info), *err.fields) from None
    except DataError as err:
        raise DataError(f"{err}{_what_broke(al, notes, info)}") from None
    broken = note + _what_broke(al, notes) if note else info.broken
    return w, replace(info, span=(w.first, w.end), broken=broken)


def bag_signals(
    path: str | Path,
    specs: Mapping[str, Sequence[str]],
    *,
    fs_high: float | None = None,
    ratio: int | None = None,
    span: str = DEFAULT_SPAN,
    msg_path: Sequence[str | Path] = (),
    labels: str = "",
    bridge: BridgeRule | None = None,
) -> tuple[LoopData, RecordingInfo]:
    """r, u, y of an aligned span of a bag's sources (``span``: which one).

    With the rates (``identify`` and ``diagnose`` on a bag); as :func:`recorded_signals`
    (``labels`` too).
    """
    check_span(span)
    read = read_bag(
        path,
        specs,
        fs_high=fs_high,
        ratio=ratio,
        history=True,
        msg_path=msg_path,
        labels=labels,
        bridge=bridge,
    )
    w, info = _chosen(read.aligner, span, read.notes, read.info, f"{path}: sources {read.sources}")
    return replace(w, fs_high=read.fs_high, ratio=read.ratio), info


def bag_windows(
    path: str | Path,
    config: IdentConfig,
    specs: Mapping[str, Sequence[str]] | None = None,
    *,
    topics: Sequence[str] | None = None,
    fs_high: float | None = None,
    ratio: int | None = None,
    span: str = DEFAULT_SPAN,
    msg_path: Sequence[str | Path] = (),
) -> Iterator[tuple[float, LoopData, IdentConfig]]:
    """The windows the node would have identified while the bag was recorded.

    Yields (loop time in s since the first aligned sample, window, the config with the
    bag's rates) every ``update_period_s`` of loop time, once ``min_window_s`` is aligned;
    each window is the latest ``window_s`` ending there. ``specs`` None: the block contract
    (``topics``), rates from the arguments or ``config``; with sources, rates as
    :func:`bag_signals`. The span ``span`` of the bag is replayed (default the
    longest).
    """
    labels = config.excitation_index_topic
    if specs is None:
        F = ratio or config.ratio
        # the holes judged as the node judged them
        node = config_bridging(config.replace(ratio=F)) or NO_BRIDGING
        data, _ = recorded_signals(path, F, topics=topics, span=span, labels=labels, bridge=node)
        cfg = config.replace(fs_high=fs_high or config.fs_high, ratio=F)
    else:
        data, _ = bag_signals(
            path,
            specs,
            fs_high=fs_high,
            ratio=ratio,
            span=span,
            msg_path=msg_path,
            labels=labels,
            bridge=config_bridging(config.replace(ratio=ratio or config.ratio)) or NO_BRIDGING,
        )
        cfg = config.replace(fs_high=data.fs_high, ratio=data.ratio)
    yield from loop_windows(data, cfg, str(path))


def _window_step(cfg: IdentConfig) -> int:
    """Samples between the node's windows: ``update_period_s`` on the F grid."""
    F = cfg.ratio
    return max(F, F * int(round(cfg.update_period_s * cfg.fs_high / F)))


def window_count(n_samples: int, cfg: IdentConfig) -> int:
    """How many windows :func:`loop_windows` gives over ``n_samples`` aligned samples."""
    return len(range(cfg.min_samples, n_samples + 1, _window_step(cfg)))


def loop_windows(
    data: LoopData, cfg: IdentConfig, what: str = "the data"
) -> Iterator[tuple[float, LoopData, IdentConfig]]:
    """The windows the node would have identified over ``data`` (one span).

    Yields (loop time in s since the span's first sample, window, ``cfg``) every
    ``update_period_s`` of loop time, once ``min_window_s`` is aligned; each window the
    latest ``window_s`` ending there. ``cfg`` carries the rates. DataError naming ``what``
    when the span is shorter than ``min_window_s``.
    """
    F, N = cfg.ratio, data.n_samples
    step = _window_step(cfg)
    if N < cfg.min_samples:
        raise DataError(
            f"{what}: {N} aligned samples, fewer than min_window_s = {cfg.min_window_s:g} s "
            f"({cfg.min_samples} samples at {cfg.fs_high:g} Hz)"
        )
    for end in range(cfg.min_samples, N + 1, step):
        start = max(0, end - cfg.window_samples)
        w = replace(data.part(start, end), fs_high=None, ratio=F)
        yield end / cfg.fs_high, w, cfg


def bag_estimates(
    path: str | Path,
    config: IdentConfig,
    specs: Mapping[str, Sequence[str]] | None = None,
    **kwargs: Any,
) -> Iterator[tuple[float, Estimate]]:
    """The estimates the node would have published while the bag was recorded.

    (loop time, estimate) of every window of :func:`bag_windows` (same arguments).
    """
    for t, w, cfg in bag_windows(path, config, specs, **kwargs):
        yield t, estimate(w, cfg)
