# SPDX-License-Identifier: Apache-2.0
"""``mr-ident view`` on a live graph.

Subscribes to the node's ``~/estimate`` (one ``mr_ident_msgs/Estimate`` per estimate), its
drift (monitoring) and /diagnostics, and hands them to the view's state; the HTTP server
(:mod:`mr_ident.view.server`) shows them. ``--node`` is the node's name, fully qualified
with its namespace (``/arm/mr_ident``) or relative to the root (``mr_ident``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..errors import MrIdentError
from ..view.server import ViewServer
from ..view.state import ViewState
from .program import Stop, ros_context


def node_name(name: str) -> str:
    """The fully qualified name of ``--node`` (a leading ``/`` added)."""
    return "/" + name.strip("/")


def _listen(rclpy: Any, name: str, state: ViewState) -> Any:
    from diagnostic_msgs.msg import DiagnosticArray

    from .messages import RESULT_QOS, status_values
    from .outputs import DriftMsg, EstimateMsg, estimate_arrays

    if EstimateMsg is None:
        raise MrIdentError(
            "the interface package mr_ident_msgs is not installed: build it with this package "
            "(colcon build, then source install/setup.bash; or make venv)"
        )
    n = rclpy.create_node("mr_ident_view")
    base = node_name(name)

    def on_estimate(m: Any) -> None:
        e = estimate_arrays(m)
        state.set_estimate(
            e.frequency,
            e.response,
            e.std,
            e.pfg,
            e.pfg_std,
            {
                "estimate_first": e.window_first,
                "estimate_samples": e.window_last - e.window_first + 1,
                "stamp_s": e.stamp_ns * 1e-9,
            },
            pfg_data=e.pfg_data,
            pfg_data_std=e.pfg_data_std,
        )

    def diag(m: DiagnosticArray) -> None:
        for s in m.status:
            if not s.name.startswith(base + ": "):  # "<fully qualified name>: <what>"
                continue
            values = status_values(s)
            if s.name.endswith(": plant"):  # the monitoring status, beside the identification
                state.set_plant(values)
            else:
                state.set_health(values)

    def drift(m: Any) -> None:  # mr_ident_msgs/Drift
        z, limit = np.asarray(m.sigma_error, float), np.asarray(m.threshold, float)
        with np.errstate(invalid="ignore"):
            state.set_drift(np.asarray(m.frequency, float), z > limit)

    n.create_subscription(EstimateMsg, f"{base}/estimate", on_estimate, RESULT_QOS)
    n.create_subscription(DriftMsg, f"{base}/drift", drift, RESULT_QOS)
    n.create_subscription(DiagnosticArray, "/diagnostics", diag, 10)
    return n


def run_live_view(server: ViewServer, name: str, wait_s: float, stop: Stop) -> int:
    """Serve the page while the node runs; MrIdentError if no node appears in ``wait_s``."""
    with ros_context() as rclpy:
        n = _listen(rclpy, name, server.state)
        try:
            topic = node_name(name) + "/estimate"
            t0 = time.monotonic()
            while n.count_publishers(topic) == 0:
                if stop.requested:
                    return 0
                if time.monotonic() - t0 > wait_s:
                    raise MrIdentError(
                        f"no node publishes {topic} (waited {wait_s:g} s): start mr-ident-node, "
                        "or name it with --node (e.g. --node /arm/mr_ident)"
                    )
                rclpy.spin_once(n, timeout_sec=0.1)
            print(f"listening to {node_name(name)}", flush=True)
            while not stop.requested:
                rclpy.spin_once(n, timeout_sec=0.1)
        finally:
            n.destroy_node()
    return 0
