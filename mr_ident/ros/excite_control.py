# SPDX-License-Identifier: Apache-2.0
"""``mr-ident excite --publish`` driven from the graph: ``~/start``, ``~/stop`` and a status.

The publisher node serves ``~/start`` and ``~/stop`` (``std_srvs/Trigger``) and puts a
status ``<node>: excitation`` on ``/diagnostics`` once a second: whether it publishes, the
realization, period and sample of the last sample sent, the samples sent, the topic.

A stop does not hold the sample index: the index (and the stamps, ``t0 + i / fs_high``)
follow the clock, so the samples due while stopped are never sent; a subscriber sees a gap
(the loop ran on without excitation), and after ``~/start`` the design goes on at the
realization and period that index falls in.
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger


class ExciteControl:
    """Start/stop services and the status of one excitation publisher on ``node``."""

    def __init__(self, node: Any, topic: str, *, running: bool = True) -> None:
        self.node = node
        self.topic = node.resolve_topic_name(topic)
        self.running = running
        self.done = False
        self.sent = 0
        self.labels: tuple[int, int, int] | None = None  # of the last sample sent
        self._made = [
            node.create_service(Trigger, "~/start", self._start),
            node.create_service(Trigger, "~/stop", self._stop),
        ]
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = node.create_timer(1.0, self.publish_status, clock=steady)

    def _start(self, _req: Any, res: Any) -> Any:
        res.success = not self.done
        res.message = "publishing" if not self.done else "the design has been played"
        self.running = self.running or not self.done
        return res

    def _stop(self, _req: Any, res: Any) -> Any:
        self.running = False
        res.success, res.message = True, "stopped (~/start resumes)"
        return res

    def status(self) -> DiagnosticStatus:
        """``<node>: excitation``: publishing or not, where in the design, how much went out."""
        fqn = self.node.get_fully_qualified_name()
        where = ""
        values = {"topic": self.topic, "samples_sent": str(self.sent)}
        if self.labels is not None:
            m, p, k = self.labels
            where = f": realization {m}, period {p}"
            values |= {"realization": str(m), "period": str(p), "sample": str(k)}
        state = "done" if self.done else "publishing" if self.running else "stopped"
        values["state"] = state
        st = DiagnosticStatus(
            level=DiagnosticStatus.OK,
            name=f"{fqn}: excitation",
            message=state + (where if state == "publishing" else ""),
            hardware_id=fqn,
        )
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        return st

    def publish_status(self) -> None:
        """One /diagnostics message with :meth:`status`."""
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [self.status()]
        self._pub.publish(msg)

    def destroy(self) -> None:
        """Services, publisher and timer gone (the run is over)."""
        self.publish_status()
        for srv in self._made:
            self.node.destroy_service(srv)
        self.node.destroy_timer(self._timer)
        self.node.destroy_publisher(self._pub)
