"""``replay``: a recording through the node's own steps, offline.

:func:`replay_recording` settles the node's configuration from the request (its parameters
file, the options that replace its values, the rates) and runs
:func:`~mr_ident.live.replay.replay` (block contract) or
:func:`~mr_ident.live.replay.replay_bag` (per-sample sources); :func:`plant_events` the
plant status changes the node would have shown (monitoring, the diagnosis loaded then).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .requests import Notice, Notify, ReplayRequest, ignore

if TYPE_CHECKING:
    from ..io.config import IdentConfig
    from ..live.replay import ReplayResult

#: Anomalies of a replay told at most (the rest are counted in the result's ``anomalies``).
SHOWN_ANOMALIES = 20


@dataclass(frozen=True)
class Replayed:
    """The replay's result and the configuration it ran with (the rates settled).

    ``monitoring``: the configuration names a model or reference to watch the plant
    against (:func:`plant_events`); the result then holds the span replayed.
    """

    result: ReplayResult
    config: IdentConfig
    monitoring: bool
    notices: tuple[Notice, ...] = ()


def replay_config(req: ReplayRequest) -> IdentConfig:
    """The node's configuration the request asks for: ``params`` with the options applied."""
    from ..io.config import IdentConfig, load_params

    cfg = load_params(req.params) if req.params else IdentConfig()
    if req.y_rate:
        cfg = cfg.replace(y_rate=req.y_rate)
    if req.excitation_index:
        cfg = cfg.replace(excitation_index_topic=req.excitation_index)
    return cfg


def replay_recording(req: ReplayRequest, notify: Notify = ignore) -> Replayed:
    """The estimate the node would have made last from the request's recording.

    ``notify`` hears the truncation and the first :data:`SHOWN_ANOMALIES` anomalies (the
    outcome keeps them too).
    """
    from ..live.replay import replay, replay_bag
    from ..live.spans import DEFAULT_SPAN

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
    notices += [Notice("note", a) for a in res.anomalies[:SHOWN_ANOMALIES]]
    for n in notices:
        notify(n)
    return Replayed(res, cfg, monitoring, tuple(notices))


def plant_events(replayed: Replayed, what: str) -> Iterator[str]:
    """The plant status changes the node would have shown (monitor_* in the parameters).

    Over the span the replay read (not read again), window by window as the node; each as
    one line. Nothing without monitoring.
    """
    if not replayed.monitoring:
        return
    from ..diagnosis.monitoring.monitor import load_watch, watch_windows
    from ..live.replay import loop_windows

    cfg, signals = replayed.config, replayed.result.signals
    watch = load_watch(cfg)
    assert watch is not None and signals is not None
    for ev in watch_windows(loop_windows(signals, cfg, what), watch):
        yield f"plant at {ev.time_s:.1f} s: {ev.level.upper()} {ev.text}"
