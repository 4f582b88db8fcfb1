# SPDX-License-Identifier: Apache-2.0
"""The node's recording (``record_path``): every raw message of its inputs into one MCAP.

Messages are written as they arrive (raw CDR, never decoded again), with the publishers'
QoS, so that ``mr-ident replay`` and ``ros2 bag play`` take the file. A write that fails
closes the file and leaves :attr:`NodeRecorder.error` set (ERROR on /diagnostics) until
``record_path`` changes.

A recording is never destroyed: an existing file is never opened for writing (a new name
beside it is chosen, ``<stem>_<k>.mcap``, and logged), so every start (an activation,
``~/start_recording``) makes a new file. A chunk is closed at 1 MB or :data:`CHUNK_S`
after its first message, whichever comes first, and goes to the operating system at once:
a node killed (SIGKILL, a crash) leaves a file readable up to its last few seconds.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ..errors import MrIdentError
from ..io.recording import McapRecorder, fresh_path
from .messages import qos_dict

#: A chunk of the recording is closed this many seconds after its first message (at the
#: latest; or at 1 MB): what a killed node can lose.
CHUNK_S = 2.0


class NodeRecorder:
    """Records what ``node`` receives (see the module docstring)."""

    def __init__(self, node: Node):
        self._node = node
        self._rec: McapRecorder | None = None
        self._channels: dict[str, int] = {}  # topic -> channel id
        self._timer: Any = None
        self.error = ""
        self.last = ""  # the path last asked for (a new start names its file after it)

    @property
    def path(self) -> Path | None:
        """The file being written, or None."""
        rec = self._rec
        return rec.path if rec is not None else None

    def open(self, path: str) -> Path | None:
        """Start recording to a new file: ``path``, or a new name beside it when it exists.

        The file's path, or None (the error kept in :attr:`error`, not raised).
        """
        self.close()
        self.error, self.last = "", path
        for _ in range(100):  # another writer may take a free name first
            target = fresh_path(path)
            try:
                self._rec = McapRecorder(target, chunk_s=CHUNK_S, exclusive=True)
                break
            except FileExistsError:
                continue
            except OSError as err:
                self.error = f"cannot record to {target}: {err.strerror or err}"
                self._node.get_logger().error(self.error)
                return None
        else:
            self.error = f"cannot record to {path}: no free name beside it"
            return None
        self._channels = {}
        self._timer = self._node.create_timer(
            CHUNK_S / 4, self._rec.tick, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        if target != Path(path):
            self._node.get_logger().info(
                f"{path} exists (a recording is never overwritten): recording to {target}"
            )
        return target

    def close(self) -> None:
        """Finalise the file (its summary and index)."""
        rec, self._rec = self._rec, None
        timer, self._timer = self._timer, None
        if timer is not None:
            self._node.destroy_timer(timer)
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
