# SPDX-License-Identifier: Apache-2.0
"""The node's plant monitoring: ``~/drift``, ``~/diagnosis`` and the status ``<node>: plant``.

A thin adapter around :class:`~mr_ident.diagnosis.monitoring.monitor.PlantWatch`: each estimate is
held against the reference on the estimating thread (a few ms); when the watch asks for a
diagnosis, the window goes to a thread of its own (seconds), never blocking the estimates,
and at most one runs at a time. With ``record_path`` set, the diagnosed window is kept
beside the recording as ``<record_path stem>.event-<k>.npz`` (r, u, y, fs_high, F), which
``mr-ident diagnose --data`` reads.

``~/drift`` (``mr_ident_msgs/Drift``, stamped as the estimate it compares): frequency
(Hz), relative deviation ``|P̂ - P_ref| / |P_ref|``, σ-error and its threshold, on the
published bins. ``~/diagnosis`` (std_msgs/String): the latest diagnosis as JSON
(:meth:`~mr_ident.diagnosis.monitoring.monitor.WindowDiagnosis.as_dict`, plus ``event_file``).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node
from std_msgs.msg import String

from ..diagnosis.monitoring.monitor import MonitorState, PlantWatch, WindowDiagnosis, load_watch
from ..errors import MrIdentError
from ..io.config import IdentConfig
from ..io.datafile import write_data
from ..live.estimate import Estimate, publish_grid
from ..numerics.signals import LoopData
from ..numerics.systems.model import Model
from .messages import RESULT_QOS
from .outputs import DriftMsg, floats, stamp

#: :meth:`PlantMonitoring.load`: the watch in use stays.
KEEP = object()

_LEVEL = {
    "ok": DiagnosticStatus.OK,
    "warn": DiagnosticStatus.WARN,
    "error": DiagnosticStatus.ERROR,
}


class PlantMonitoring:
    """Publishers, the diagnosis thread and the plant status of one node."""

    def __init__(self, node: Node, cfg: IdentConfig):
        self._node = node
        self._lock = threading.Lock()
        self._watch = load_watch(cfg)
        self._config = cfg
        self._pub_drift = node.create_publisher(DriftMsg, "~/drift", RESULT_QOS)
        self._pub_diag = node.create_publisher(String, "~/diagnosis", RESULT_QOS)
        self._state: MonitorState | None = None
        self._state_wall = 0.0
        self._found: WindowDiagnosis | None = None
        self._found_error = ""
        self._event_file = ""
        self._events = 0
        self._thread: threading.Thread | None = None

    @property
    def enabled(self) -> bool:
        """Whether a reference is configured."""
        return self._watch is not None

    def load(self, cfg: IdentConfig) -> Any:
        """The watch ``cfg`` asks for, loaded when a monitor_* value or the rates changed.

        Else :data:`KEEP`. Raises what
        :func:`~mr_ident.diagnosis.monitoring.monitor.load_watch` raises (the parameter set
        is then refused); :meth:`install` puts it in place.
        """
        keys = (
            *("monitor_model", "monitor_reference", "monitor_alpha", "monitor_error_db"),
            *("monitor_hold", "fs_high", "ratio", "method", "n", "degree"),
        )
        if any(getattr(cfg, k) != getattr(self._config, k) for k in keys):
            return load_watch(cfg)
        return KEEP

    def install(self, cfg: IdentConfig, watch: Any) -> None:
        """Use ``cfg`` and the watch :meth:`load` gave (from now on)."""
        if watch is not KEEP:
            with self._lock:
                self._watch, self._state, self._found = watch, None, None
        self._config = cfg

    @property
    def model(self) -> Model | None:
        """The model that names causes (monitor_model), or None."""
        watch = self._watch
        return watch.model if watch is not None else None

    def destroy(self) -> None:
        """The publishers destroyed (the node's cleanup)."""
        self._node.destroy_publisher(self._pub_drift)
        self._node.destroy_publisher(self._pub_diag)

    # -- the estimating thread ----------------------------------------------------------
    def observe(
        self, est: Estimate, window: LoopData, cfg: IdentConfig, stamp_ns: int = 0
    ) -> MonitorState | None:
        """Hold ``est`` against the reference; publish; start a diagnosis when one is due.

        The monitor's state (None without a reference). ``stamp_ns``: the estimate's stamp.
        """
        watch = self._watch
        if watch is None:
            return None
        state = watch.observe(est)
        with self._lock:
            self._state, self._state_wall = state, time.monotonic()
        d = state.drift
        k = publish_grid(d.frequency.size, cfg.publish_points)
        msg = DriftMsg()
        stamp(msg, stamp_ns)
        msg.window_last = int(est.first + est.n_samples - 1)
        for field in ("frequency", "deviation", "sigma_error", "threshold"):
            setattr(msg, field, floats(getattr(d, field)[k]))
        self._pub_drift.publish(msg)
        busy = self._thread is not None and self._thread.is_alive()
        if state.diagnose and watch.model is not None and not busy:
            self._thread = threading.Thread(
                target=self._diagnose,
                args=(watch, window, est, cfg.record_path),
                daemon=True,
                name="mr_ident-diagnose",
            )
            self._thread.start()
        return state

    def _diagnose(self, watch: PlantWatch, window: LoopData, est: Estimate, record: str) -> None:
        event = ""
        try:
            if record:
                self._events += 1
                p = Path(record)
                event = str(p.with_name(f"{p.stem}.event-{self._events}.npz"))
                write_data(
                    event,
                    window.r,
                    window.u,
                    window.y,
                    fs_high=self._config.fs_high,
                    ratio=self._config.ratio,
                )
            found = watch.diagnose(window, est)
        except (MrIdentError, OSError, ArithmeticError, ValueError) as err:
            with self._lock:
                self._found_error = f"diagnosis failed: {err}"
            self._node.get_logger().error(self._found_error)
            return
        if found is None:
            return
        with self._lock:
            self._found, self._found_error, self._event_file = found, "", event
        text = json.dumps(found.as_dict() | {"event_file": event})
        self._pub_diag.publish(String(data=text))
        self._node.get_logger().warning(f"plant drift: {found.headline()}")

    # -- the status ---------------------------------------------------------------------
    def status(self, name: str, hardware_id: str, stale_s: float) -> DiagnosticStatus | None:
        """``<name>: plant``; None when monitoring is off.

        STALE when no estimate came for ``stale_s`` (a stream problem is reported by the
        identification status, not taken for drift).
        """
        if self._watch is None:
            return None
        with self._lock:
            state, wall, found, err = self._state, self._state_wall, self._found, self._found_error
            event = self._event_file
        values: dict[str, Any] = {
            "reference": self._config.monitor_reference or self._config.monitor_model,
            "alarms": self._watch.monitor.alarms,
            "estimates_checked": self._watch.monitor.estimates,
        }
        if state is None:
            level, message = DiagnosticStatus.OK, "waiting for the first estimate"
        elif time.monotonic() - wall > stale_s:
            level = DiagnosticStatus.STALE
            message = f"no new estimate for {time.monotonic() - wall:.0f} s (see identification)"
            if state.level != "ok":  # what was last seen stays readable
                message += f"; last: {state.drift.describe()}"
                message += f"; {found.headline()}" if found is not None else ""
        else:
            level = _LEVEL[state.level]
            message = state.drift.describe() if state.level != "ok" else "matches the reference"
            if state.level != "ok" and found is not None:
                message += f"; {found.headline()}"
            elif state.level != "ok" and err:
                message += f"; {err}"
            elif state.level != "ok" and self._thread is not None and self._thread.is_alive():
                message += "; diagnosing"
            elif state.level != "ok" and self._watch.waiting:
                message += "; the cause once a window after the change is in"
            d = state.drift
            values |= {
                "drift_db": f"{d.size_db:.3f}",
                "drift_bands_hz": " ".join(f"{lo:.4g}-{hi:.4g}" for lo, hi in d.bands()),
                "estimate_level": state.raw_level,
            }
        if found is not None:
            values |= {
                "cause": found.cause,
                "cause_parameters": json.dumps(found.as_dict()["parameters"]),
                "event_file": event,
            }
        st = DiagnosticStatus(
            level=level, name=f"{name}: plant", message=message, hardware_id=hardware_id
        )
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return st

    def shutdown(self, timeout: float) -> None:
        """Wait for a running diagnosis."""
        t = self._thread
        if t is not None:
            t.join(timeout)
