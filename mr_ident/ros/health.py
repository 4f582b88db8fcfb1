# SPDX-License-Identifier: Apache-2.0
"""The node's ``/diagnostics`` status ``<node>: identification``: level, reason, counters.

:func:`identification_status` turns a :class:`Health` snapshot (taken by the node under its
lock) into a DiagnosticStatus; the order of the checks is the order of what an operator
must fix first: a recording that failed, a source that cannot work, a failed
identification, a stalled stream, recent anomalies, silence, and otherwise the window
filling or the estimates running.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ..io.config import IdentConfig
from ..live.align import StreamStats
from ..live.estimate import Estimate
from .excitation import bla_values
from .sources import SourceSubscriber

WARN_HOLD_S = 10.0  # an anomaly keeps the level at WARN this long
#: Why no estimate comes with use_sim_time before the first /clock.
NO_CLOCK = (
    "use_sim_time is true and no /clock has come: estimates wait for it "
    "(update_period_s runs on the ROS clock)"
)


@dataclass(frozen=True)
class Health:
    """What the status is made of, at ``now`` (monotonic seconds)."""

    now: float
    config: IdentConfig
    stats: dict[str, StreamStats]
    span: tuple[int, int]
    restarts: int
    estimate: Estimate | None
    estimates: int
    estimate_wall: float
    error: str
    error_time: float
    notes: list[tuple[float, str]]
    arrivals: list[float]
    started: float
    samples_in: int
    sources: SourceSubscriber | None
    record_error: str
    recording: str
    warm_up: str
    clock: str = ""  # why the ROS clock stands still ("" when it runs)
    active: bool = True
    missing: int = 0  # indices of the window where r, u or y is missing (bridged holes)
    qos_problems: dict[str, str] | None = None  # stream -> an incompatible QoS policy seen


def _level(h: Health) -> tuple[Any, str, list[str]]:
    cfg, now, src = h.config, h.now, h.sources
    recent = list(dict.fromkeys(text for t, text in h.notes if now - t < WARN_HOLD_S))
    names = list(h.stats)  # reference, input, output (and excitation_index)
    stalled = [names[i] for i, t in enumerate(h.arrivals) if t and now - t > cfg.stall_timeout_s]
    silent = [names[i] for i, t in enumerate(h.arrivals) if not t]
    src_problem = (src.error or src.rate_problem()) if src is not None else ""
    lo, hi = h.span
    fill = max(0, hi - lo) / cfg.window_samples
    if h.record_error:
        return DiagnosticStatus.ERROR, h.record_error, recent
    if not h.active:
        return DiagnosticStatus.OK, "inactive (lifecycle): activate it to subscribe", recent
    if h.clock:
        return DiagnosticStatus.WARN, h.clock, recent
    if src_problem:
        return DiagnosticStatus.ERROR, src_problem, recent
    if src is not None and src.sources is None:
        return DiagnosticStatus.WARN, src.status, recent
    if h.error and now - h.error_time < WARN_HOLD_S:
        return DiagnosticStatus.ERROR, h.error, recent
    if stalled:
        return (
            DiagnosticStatus.WARN,
            f"stream(s) {', '.join(stalled)} stalled "
            f"(> {cfg.stall_timeout_s:g} s without a block)",
            recent,
        )
    if recent:
        more = f" (+{len(recent) - 1} more: recent_anomalies)" if len(recent) > 1 else ""
        return DiagnosticStatus.WARN, h.notes[-1][1] + more, recent
    if silent and now - h.started > cfg.stall_timeout_s:
        qos = h.qos_problems or {}
        why = [f"{s} (a publisher's QoS is incompatible: {qos[s]})" if s in qos else s
               for s in silent]  # fmt: skip
        return DiagnosticStatus.WARN, f"no data yet on {', '.join(why)}", recent
    if h.estimate is None:
        return (
            DiagnosticStatus.OK,
            f"filling window ({100 * fill:.0f} %, first estimate at "
            f"{100 * cfg.min_samples / cfg.window_samples:.0f} %)",
            recent,
        )
    return DiagnosticStatus.OK, "estimating", recent


def identification_status(h: Health, name: str, hardware_id: str) -> DiagnosticStatus:
    """The status ``<name>: identification`` of ``h`` with every counter as a value.

    ``name``: the node's fully qualified name, so that two nodes never share a status.
    """
    level, reason, recent = _level(h)
    cfg, est = h.config, h.estimate
    lo, hi = h.span
    values: dict[str, Any] = {
        "samples_in": h.samples_in,
        "window_fill": f"{max(0, hi - lo) / cfg.window_samples:.4f}",
        "window_first_index": lo,
        "window_end_index": hi,
        "estimates": h.estimates,
        "last_update_age_s": f"{h.now - h.estimate_wall:.3f}" if est is not None else "never",
        "recording": h.recording,
        "window_restarts": h.restarts,
        "window_missing": h.missing,
        "warm_up_s": h.warm_up or "running",
        "recent_anomalies": " | ".join(recent[-8:]),
        "lifecycle": "active" if h.active else "inactive",
    }
    if h.sources is not None:
        values.update(h.sources.values())
    if est is not None:
        values.update(
            {
                "compute_s": f"{est.compute_s:.4f}",
                "lifting_phase": est.phase,
                "lifting_phase_source": est.phase_source,
                "estimate_first_index": est.first,
                "estimate_samples": est.n_samples,
                "injection": est.identification.injection,
                "loop_structure": est.structure,
            }
        )
        values.update(bla_values(est))
    else:
        values["lifting_phase"] = cfg.lifting_phase
    for stream, st in h.stats.items():
        values.update({f"{stream}.{k}": v for k, v in st.as_dict().items()})
    for stream, policy in (h.qos_problems or {}).items():
        values[f"{stream}.incompatible_qos"] = policy
    status = DiagnosticStatus(
        level=level, name=f"{name}: identification", message=reason, hardware_id=hardware_id
    )
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return status


def unconfigured_status(fqn: str, error: str, state: str = "unconfigured") -> DiagnosticStatus:
    """The status of a node not configured: it waits for configure, or why configure failed.

    OK while it waits (a managed node starts so, until its launch file or lifecycle manager
    configures it); ERROR when its last configure failed, with the reason.
    """
    if error:
        level, message = DiagnosticStatus.ERROR, f"{state}: configure failed: {error}"
    else:
        message = (
            f"{state}: waiting for configure (a launch file or lifecycle manager; "
            f"ros2 lifecycle set {fqn} configure)"
        )
        level = DiagnosticStatus.OK
    status = DiagnosticStatus(
        level=level, name=f"{fqn}: identification", message=message, hardware_id=fqn
    )
    status.values = [KeyValue(key="lifecycle", value=state)]
    return status
