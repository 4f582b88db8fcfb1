"""``mr-ident view`` on a live graph.

Subscribes to the node's estimate, its drift (monitoring) and /diagnostics and hands them to
the view's state; the HTTP server (:mod:`mr_ident.view.server`) shows them.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..errors import MrIdentError
from ..view.server import ViewServer
from ..view.state import ViewState
from .program import Stop, ros_context


class _Collector:
    """The node's result topics joined into one estimate (same K), then the state."""

    def __init__(self, state: ViewState) -> None:
        self.state = state
        self.parts: dict[str, Any] = {}
        self.window: dict[str, Any] = {}

    def put(self, name: str, value: Any) -> None:
        self.parts[name] = value
        if name not in ("P_std", "pfg_std", "pfg_data_std"):
            return  # the node publishes f, P, std, then the PFGs, each value before its std
        f, P, S = (self.parts.get(k) for k in ("freq", "P", "P_std"))
        if f is None or P is None or S is None or not (f.size == P.shape[0] == S.shape[0]):
            return
        pfgs = {}
        for key in ("pfg", "pfg_data"):
            g, gs = self.parts.get(key), self.parts.get(f"{key}_std")
            ok = g is not None and gs is not None and g.size == gs.size == f.size
            pfgs[key], pfgs[f"{key}_std"] = (g, gs) if ok else (None, None)
        self.state.set_estimate(
            f,
            P,
            S,
            pfgs["pfg"],
            pfgs["pfg_std"],
            self.window,
            pfg_data=pfgs["pfg_data"],
            pfg_data_std=pfgs["pfg_data_std"],
        )


def _listen(rclpy: Any, node_name: str, collector: _Collector) -> Any:
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray

    from .messages import RESULT_QOS, frf_of, status_values, std_of

    n = rclpy.create_node("mr_ident_view")
    base = "/" + node_name.strip("/")

    def vec(name: str):
        return lambda m: collector.put(name, np.frombuffer(m.data, dtype=float).copy())

    def diag(m: DiagnosticArray) -> None:
        for s in m.status:
            if not s.name.startswith(node_name.strip("/")):
                continue
            values = status_values(s)
            if s.name.endswith(": plant"):  # the monitoring status, beside the identification
                collector.state.set_plant(values)
                continue
            collector.window = {
                k: values[k] for k in ("estimate_first", "estimate_samples") if k in values
            }
            collector.state.set_health(values)

    def drift(m: Float64MultiArray) -> None:
        rows = np.frombuffer(m.data, dtype=float).reshape(4, -1)  # f, deviation, z, threshold
        with np.errstate(invalid="ignore"):
            collector.state.set_drift(rows[0], rows[2] > rows[3])

    subs = {
        "frequencies": vec("freq"),
        "plant_frf": lambda m: collector.put("P", frf_of(m)),
        "plant_frf_std": lambda m: collector.put("P_std", std_of(m)),
        "pfg": vec("pfg"),
        "pfg_std": vec("pfg_std"),
        "pfg_data": vec("pfg_data"),
        "pfg_data_std": vec("pfg_data_std"),
    }
    for topic, cb in subs.items():
        n.create_subscription(Float64MultiArray, f"{base}/{topic}", cb, RESULT_QOS)
    n.create_subscription(Float64MultiArray, f"{base}/drift", drift, RESULT_QOS)
    n.create_subscription(DiagnosticArray, "/diagnostics", diag, 10)
    return n


def run_live_view(server: ViewServer, node_name: str, wait_s: float, stop: Stop) -> int:
    """Serve the page while the node runs; MrIdentError if no node appears in ``wait_s``."""
    state = server.state
    with ros_context() as rclpy:
        n = _listen(rclpy, node_name, _Collector(state))
        try:
            topic = "/" + node_name.strip("/") + "/plant_frf"
            t0 = time.monotonic()
            while n.count_publishers(topic) == 0:
                if stop.requested:
                    return 0
                if time.monotonic() - t0 > wait_s:
                    raise MrIdentError(
                        f"no node publishes {topic} (waited {wait_s:g} s): start mr-ident-node, "
                        "or name it with --node"
                    )
                rclpy.spin_once(n, timeout_sec=0.1)
            print(f"listening to {node_name}", flush=True)
            while not stop.requested:
                rclpy.spin_once(n, timeout_sec=0.1)
        finally:
            n.destroy_node()
    return 0
