# SPDX-License-Identifier: Apache-2.0
"""``replay``: a recording through the node's own steps, offline.

:func:`replay_recording` settles the node's configuration from the request (its parameters
file, the options that replace its values, the rates) and runs
:func:`~mr_ident.live.replay.replay` (block contract) or
:func:`~mr_ident.live.replay.replay_bag` (per-sample sources); :func:`plant_events` the
plant status changes the node would have shown (monitoring, the diagnosis loaded then);
:func:`estimates_in_time` every estimate the node would have published (``mr-ident view
--bag``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .requests import Notice, Notify, ReplayRequest, ignore

if TYPE_CHECKING:
    from ..io.config import IdentConfig
    from ..live.estimate import Estimate
    from ..live.replay import ReplayResult
    from ..numerics.signals import LoopData

    _W = tuple[float, LoopData, IdentConfig]  # a window and its time and configuration
    from ..numerics.systems.model import Model

#: Anomalies of a replay told at most (the rest are counted in the result's ``anomalies``).
SHOWN_ANOMALIES = 20


@dataclass(frozen=True)
class Replayed:
    """The replay's result and the configuration it ran with (the rates settled).

    Attributes
    ----------
    result : ReplayResult
        The last window's estimate, the aligner's statistics, what was read and noticed.
    config : IdentConfig
        The node's configuration the replay ran with, its rates those the estimate used.
    monitoring : bool
        The configuration names a model or reference to watch the plant against
        (:func:`plant_events`); the result then holds the span replayed.
    notices : tuple of Notice
        The truncation and the first :data:`SHOWN_ANOMALIES` anomalies.
    """

    result: ReplayResult
    config: IdentConfig
    monitoring: bool
    notices: tuple[Notice, ...] = ()


def replay_config(req: ReplayRequest) -> IdentConfig:
    """The node's configuration the request asks for: ``params`` with the options applied.

    Parameters
    ----------
    req : ReplayRequest
        Its ``params`` file (None: the node's defaults), ``y_rate`` and
        ``excitation_index`` where given.

    Returns
    -------
    IdentConfig

    Raises
    ------
    ConfigError
        A parameters file that cannot be read or holds invalid values, an option out of
        range.
    """
    from ..io.config import IdentConfig, load_params

    cfg = load_params(req.params) if req.params else IdentConfig()
    if req.y_rate:
        cfg = cfg.replace(y_rate=req.y_rate)
    if req.excitation_index:
        cfg = cfg.replace(excitation_index_topic=req.excitation_index)
    return cfg


def replay_recording(req: ReplayRequest, notify: Notify = ignore) -> Replayed:
    """The estimate the node would have made last from the request's recording.

    The node's configuration (:func:`replay_config`), then the recording through the node's
    own alignment and identification: block topics by
    :func:`~mr_ident.live.replay.replay`, per-sample sources by
    :func:`~mr_ident.live.replay.replay_bag` (their rates from the request, the parameters
    file, else the stamps).

    Parameters
    ----------
    req : ReplayRequest
        The recording, its sources, the parameters file and the options.
    notify : callable, optional
        Hears the truncation and the first :data:`SHOWN_ANOMALIES` anomalies (the outcome
        keeps them too).

    Returns
    -------
    Replayed

    Raises
    ------
    FieldError
        A :class:`~mr_ident.errors.ConfigError` naming the request's fields: some of the
        sources given, not all.
    DataFieldError
        A :class:`~mr_ident.errors.DataError` whose remedy names the request's fields:
        rates the stamps cannot tell, bare topics given as sources, ``span`` "all" on a
        recording with gaps.
    DataError
        A recording that is missing or unreadable, stamps that contradict the rates, no
        gap-free window of ``min_window_s``.
    ConfigError
        A parameters file that cannot be read or holds invalid values.
    """
    from ..live.replay import replay, replay_bag
    from ..live.spans import DEFAULT_SPAN, NOTE_FIELDS

    reading = req.reading
    cfg = replay_config(req)
    specs = reading.specs()
    monitoring = bool(cfg.monitor_model or cfg.monitor_reference)
    if specs is not None:
        fs = req.fs_high or (cfg.fs_high if req.params else None)
        F = req.ratio or (cfg.ratio if req.params else None)
        res = replay_bag(
            reading.path,
            cfg,
            specs,
            fs_high=fs,
            ratio=F,
            stop=req.stop,
            keep_signals=monitoring,
            span=reading.span or DEFAULT_SPAN,
            msg_path=reading.msg_path,
        )
        ident = res.estimate.identification
        cfg = cfg.replace(fs_high=ident.fs_high, ratio=ident.ratio)
    else:
        res = replay(
            reading.path,
            cfg,
            topics=reading.topics,
            stop=req.stop,
            span=reading.span or "latest",
            keep_signals=monitoring,
        )
    info = res.info
    notices = []
    if info.truncated:
        notices.append(
            Notice(
                "warning",
                f"{reading.path} is cut short; recovered {sum(info.messages.values())} "
                f"messages ({info.bytes_read} of {info.file_bytes} bytes) ({info.reason})",
            )
        )
    notices += [Notice("note", a, fields=NOTE_FIELDS) for a in res.anomalies[:SHOWN_ANOMALIES]]
    for n in notices:
        notify(n)
    return Replayed(res, cfg, monitoring, tuple(notices))


def plant_events(
    replayed: Replayed, what: str, progress: Callable[[str], None] | None = None
) -> Iterator[str]:
    """The plant status changes the node would have shown (monitor_* in the parameters).

    Over the span the replay read (not read again), window by window as the node; each as
    one line. Nothing without monitoring.

    Parameters
    ----------
    replayed : Replayed
        :func:`replay_recording`'s outcome.
    what : str
        How messages name the recording.
    progress : callable, optional
        Told each window as it begins ("window k of n, at t s").

    Yields
    ------
    str
        ``plant at <t> s: <LEVEL> <text>`` for each change.

    Raises
    ------
    ConfigError
        A monitoring model at other rates than the loop's.
    ModelError
        A monitoring model file that is not a valid model.
    DataError
        A monitoring reference that cannot be read.
    """
    if not replayed.monitoring:
        return
    from ..diagnosis.monitoring.monitor import load_watch, watch_windows
    from ..live.replay import loop_windows, window_count

    cfg, signals = replayed.config, replayed.result.signals
    watch = load_watch(cfg)
    assert watch is not None and signals is not None
    windows = loop_windows(signals, cfg, what)
    if progress is not None:
        windows = _told(windows, progress, window_count(signals.n_samples, cfg))
    for ev in watch_windows(windows, watch):
        yield f"plant at {ev.time_s:.1f} s: {ev.level.upper()} {ev.text}"


def _told(windows: Iterator[_W], progress: Callable[[str], None], total: int) -> Iterator[_W]:
    """``windows`` as they are, each told to ``progress`` as it begins."""
    for k, w in enumerate(windows, 1):
        progress(f"monitoring: window {k} of {total}, at {w[0]:.0f} s of the recording")
        yield w


def estimates_in_time(
    req: ReplayRequest, model: Model | None = None
) -> tuple[IdentConfig, Iterator[tuple[float, Estimate]]]:
    """The configuration, and the estimates the node would have published over time.

    Parameters
    ----------
    req : ReplayRequest
        The recording, its sources, the parameters file and the options.
    model : Model, optional
        Its rates, and its controller for the PFG where the parameters give none.

    Returns
    -------
    IdentConfig
        The configuration the estimates are made with.
    iterator of (float, Estimate)
        (loop time in s, estimate) while the recording was made, lazily
        (:func:`~mr_ident.live.replay.bag_estimates`): the errors of
        :func:`replay_recording` come as it is consumed.

    Raises
    ------
    FieldError, ConfigError
        As :func:`replay_config`; some of the sources given, not all.
    """
    from ..live.replay import bag_estimates
    from ..live.spans import DEFAULT_SPAN

    reading = req.reading
    specs = reading.specs()
    cfg = replay_config(req)
    if model is not None:
        cfg = cfg.replace(fs_high=model.fs_high, ratio=model.ratio)
        if model.controller is not None and not cfg.controller_num:
            cfg = cfg.with_controller(model.controller)  # the PFG from the model's K_l
    estimates = bag_estimates(
        reading.path,
        cfg,
        specs,
        topics=reading.topics,
        fs_high=req.fs_high or (model.fs_high if model else None),
        ratio=req.ratio or (model.ratio if model else None),
        span=reading.span or DEFAULT_SPAN,
        msg_path=reading.msg_path,
    )
    return cfg, estimates
