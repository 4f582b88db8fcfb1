# SPDX-License-Identifier: Apache-2.0
"""``mr-ident record`` and ``mr-ident replay --publish``: MCAP to and from a ROS 2 graph.

Recording subscribes raw (the CDR bytes rclpy received, never re-serialized) to
each topic once a publisher appears, and stores it with
:class:`~mr_ident.recording.McapRecorder`. SIGINT and SIGTERM end the
recording cleanly (one shutdown path, :mod:`mr_ident.ros.program`): the file is
finalised (summary and footer written), whenever the signal comes. A write
that fails (the disk is full) ends the recording with a
:class:`~mr_ident.errors.RecordingError`; the file then holds every finished
chunk, and ``mr-ident replay`` reports how much it recovered.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from ..errors import ConfigError, DataError, RecordingError
from ..io.blocks import STREAMS
from ..io.recording import McapRecorder
from .messages import qos_dict, subscription_qos
from .program import Stop, handle_signals, ros_context, spin_until_stopped


def message_class(type_name: str) -> Any:
    """The Python class of ``pkg/msg/Type``."""
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def _absolute(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


class Recorder:
    """Record ``topics`` of ``node``'s graph into ``path`` (call :meth:`poll` periodically)."""

    def __init__(
        self,
        node: Node,
        path: str | Path,
        topics: Sequence[str],
        on_failure: Callable[[], Any] | None = None,
    ):
        self.node = node
        self.topics = [_absolute(t) for t in topics]
        try:  # an existing file is never truncated (as rosbag2 refuses an existing bag)
            self.rec = McapRecorder(path, exclusive=True)
        except FileExistsError:
            raise ConfigError(
                f"{path} exists: a recording is never overwritten (remove it or choose "
                "another name)"
            ) from None
        self._on_failure = on_failure
        self._subs: dict[str, Any] = {}
        self.counts: dict[str, int] = {t: 0 for t in self.topics}

    def poll(self) -> None:
        """Subscribe to every wanted topic that has gained a publisher."""
        for topic in self.topics:
            if topic in self._subs:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            type_name = infos[0].topic_type
            qos = subscription_qos(infos)
            cid = self.rec.add_topic(topic, type_name, [qos_dict(i.qos_profile) for i in infos])
            self._subs[topic] = self.node.create_subscription(
                message_class(type_name),
                topic,
                self._writer(topic, cid),  # type: ignore[arg-type]  # (raw, info): rclpy passes both
                qos,
                raw=True,
            )
            self.node.get_logger().info(f"recording {topic} ({type_name})")

    def _writer(self, topic: str, cid: int) -> Callable[[bytes, dict[str, Any]], None]:
        def write(raw: bytes, info: dict[str, Any]) -> None:
            t = time.time_ns()  # log time: received; publish time: the DDS source timestamp
            if self.rec.write(cid, raw, t, info.get("source_timestamp") or t):
                self.counts[topic] += 1
            elif self.rec.error is not None and self._on_failure is not None:
                self._on_failure()

        return write

    def close(self) -> None:
        """Finalise the recording."""
        self.rec.close()


def record(
    path: str | Path,
    topics: Sequence[str],
    *,
    duration: float | None = None,
    args: Sequence[str] | None = None,
    stop: Stop | None = None,
) -> dict[str, int]:
    """Record until ``duration`` s have passed.

    Or a stop (SIGINT/SIGTERM, see :func:`~mr_ident.ros.program.handle_signals`); returns
    messages per topic.

    The file is opened first and finalised on every way out.

    Raises
    ------
    RecordingError
        When a write failed (e.g. the disk is full); the file keeps its finished chunks.
    """
    stop = stop if stop is not None else handle_signals()
    with ros_context(args) as rclpy:
        node = rclpy.create_node("mr_ident_record")
        executor = SingleThreadedExecutor()
        recorder: Recorder | None = None
        try:
            recorder = Recorder(node, path, topics or STREAMS, on_failure=stop.request)
            node.create_timer(0.1, recorder.poll)
            if duration is not None:
                node.create_timer(duration, stop.request)
            executor.add_node(node)
            spin_until_stopped(executor, node, stop)
        finally:
            if recorder is not None:
                recorder.close()
            executor.shutdown()
            node.destroy_node()
    assert recorder is not None
    if recorder.rec.failure:
        raise RecordingError(recorder.rec.failure)
    return recorder.counts


def publish_recording(
    path: str | Path,
    *,
    rate: float = 1.0,
    wait: float = 5.0,
    args: Sequence[str] | None = None,
    stop: Stop | None = None,
) -> int:
    """Re-publish every message of an MCAP recording on its topic (raw CDR).

    Paced by its log times divided by ``rate``, until the end or a stop. Returns the number
    of messages published.
    """
    from mcap.reader import make_reader

    from .messages import BLOCK_QOS

    stop = stop if stop is not None else handle_signals()
    try:
        fh = open(path, "rb")
    except OSError as err:
        raise DataError(f"cannot read recording {str(path)!r}: {err.strerror}") from err
    sent = 0
    with fh, ros_context(args) as rclpy:
        node = rclpy.create_node("mr_ident_replay")
        try:
            reader = make_reader(fh)
            try:
                summary = reader.get_summary()
            except Exception as err:
                raise DataError(
                    f"{path}: cannot read the summary ({err}); is the file finalised?"
                ) from err
            if summary is None:
                raise DataError(f"{path}: no summary section; is the file finalised?")
            pubs = {
                cid: node.create_publisher(
                    message_class(summary.schemas[ch.schema_id].name), ch.topic, BLOCK_QOS
                )
                for cid, ch in summary.channels.items()
            }
            deadline = time.monotonic() + wait
            while (
                time.monotonic() < deadline
                and not stop.requested
                and any(p.get_subscription_count() == 0 for p in pubs.values())
            ):
                stop.wait(0.02)
            if wait > 0:
                stop.wait(
                    min(wait, 0.5)
                )  # matching is not symmetric: let subscribers match us too
            t0 = time.monotonic()
            first_log = None
            for _, channel, message in reader.iter_messages(log_time_order=True):
                if stop.requested:
                    break
                first_log = message.log_time if first_log is None else first_log
                due = t0 + (message.log_time - first_log) * 1e-9 / rate
                while (d := due - time.monotonic()) > 0 and not stop.requested:
                    stop.wait(min(d, 0.1))
                pubs[channel.id].publish(bytes(message.data))
                sent += 1
            for p in pubs.values():  # reliable delivery: do not exit before the readers have it
                p.wait_for_all_acked(Duration(seconds=1 if stop.requested else 5))
        finally:
            node.destroy_node()
    return sent
