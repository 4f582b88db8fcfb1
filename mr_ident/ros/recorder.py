# SPDX-License-Identifier: Apache-2.0
"""The node's recording (``record_path``): every raw message of its inputs into one MCAP.

Messages are written as they arrive (raw CDR, never decoded again), with the publishers'
QoS, so that ``mr-ident replay`` and ``ros2 bag play`` take the file. A write that fails
closes the file and leaves :attr:`NodeRecorder.error` set (ERROR on /diagnostics) until
``record_path`` changes.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from rclpy.node import Node

from ..errors import MrIdentError
from ..io.recording import McapRecorder
from .messages import qos_dict


class NodeRecorder:
    """Records what ``node`` receives (see the module docstring)."""

    def __init__(self, node: Node):
        self._node = node
        self._rec: McapRecorder | None = None
        self._channels: dict[str, int] = {}  # topic -> channel id
        self.error = ""

    @property
    def path(self) -> Path | None:
        """The file being written, or None."""
        rec = self._rec
        return rec.path if rec is not None else None

    def open(self, path: str) -> None:
        """Start recording to ``path`` (an error is kept in :attr:`error`, not raised)."""
        self.close()
        self.error = ""
        try:
            self._rec = McapRecorder(path)
        except OSError as err:
            self.error = f"cannot record to {path}: {err.strerror or err}"
            self._node.get_logger().error(self.error)
        self._channels = {}

    def close(self) -> None:
        """Finalise the file (its summary and index)."""
        rec, self._rec = self._rec, None
        if rec is not None:
            rec.close()

    def message(self, topic: str, type_name: str, raw: bytes, sent: int | None = None) -> None:
        """One raw message of ``topic`` (a channel added on its first message)."""
        rec = self._rec
        if rec is None:
            return
        cid = self._channels.get(topic)
        if cid is None:
            node = self._node
            qos = [qos_dict(i.qos_profile) for i in node.get_publishers_info_by_topic(topic)]
            try:
                cid = self._channels[topic] = rec.add_topic(topic, type_name, qos)
            except MrIdentError as err:
                self.error = f"cannot record {topic}: {err}"
                return
        t = time.time_ns()
        if not rec.write(cid, raw, t, sent or t) and rec.error is not None and rec is self._rec:
            self.close()
            self.error = rec.failure  # ERROR on /diagnostics until record_path changes
            self._node.get_logger().error(self.error)

    def source(self, topic: str, type_name: str, raw: bytes, info: dict[str, Any]) -> None:
        """A raw message of a per-sample source topic (its source timestamp kept)."""
        self.message(topic, type_name, raw, info.get("source_timestamp"))
