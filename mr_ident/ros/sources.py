# SPDX-License-Identifier: Apache-2.0
"""The node's per-sample sources: subscriptions with the types found on the graph.

:class:`SourceSubscriber` waits until the sources' topics appear on the graph, resolves
the sources against the installed definitions of their types (any type installed in the
environment: ``sensor_msgs``, ``control_msgs``, ``pal_statistics_msgs`` ...), subscribes
raw (the CDR bytes, never deserialised by rclpy) with the publishers' QoS, and every
``BATCH_S`` hands the messages received meanwhile, as one batch per topic, to the same
:class:`~mr_ident.live.feed.SourceFeed` that replay uses. Adapter only: decoding is
:mod:`mr_ident.io.cdr`, the rules are :mod:`mr_ident.live.sampling`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import DataError, MrIdentError
from ..io.cdr import Batch
from ..io.msgdef import installed_schema, parse_schema
from ..io.sources import (
    STATISTICS_NAMES,
    Resolved,
    Samples,
    evaluate_batch,
    names_by_version,
    stamps_of,
)
from ..live.bagread import resolve_sources
from ..live.feed import SIGNALS, SignalSources, SourceFeed
from ..live.sampling import infer_rate

#: Received messages are decoded in batches this often (s): latency for throughput.
BATCH_S = 0.02
#: Reader queue per source topic: a message per sample needs a deep one (10 s at 2 kHz).
QUEUE_DEPTH = 20000
#: Stamps kept per source for the rate check.
RATE_WINDOW = 400


def topic_of(spec: str) -> str:
    """The topic part of a source (what comes before its first field, element or filter)."""
    return spec.split(".")[0].split("{")[0].split("[")[0]


def resolved(node: Any, spec: str) -> str:
    """``spec`` with its topic resolved as ``node`` resolves its own topic names.

    A relative topic is in the node's namespace, ``~/x`` under the node's name, and the
    node's remaps apply (``-r joint_states:=/robot/joint_states``).
    """
    topic = topic_of(spec)
    return node.resolve_topic_name(topic) + spec[len(topic) :]


class SourceSubscriber:
    """Subscribe and decode per-sample sources for ``node`` (see the module docstring).

    ``make_feed(sources)`` builds the :class:`SourceFeed` into the node's aligner;
    ``record(topic, type, raw, info)`` records a raw message (or is None). A message without
    header is placed by its DDS source timestamp (when the publisher wrote it). ``labels``:
    the topic of an excitation's labels, read in its form (:mod:`mr_ident.io.labels`) as a
    fourth stream ("": none).
    """

    def __init__(
        self,
        node: Any,
        specs: dict[str, tuple[str, ...]],
        make_feed: Callable[[SignalSources], SourceFeed],
        record: Callable[[str, str, bytes, dict[str, Any]], None] | None = None,
        fs_high: float = 0.0,
        *,
        labels: str = "",
    ):
        self.node = node
        self.specs = {k: tuple(resolved(node, s) for s in v) for k, v in specs.items()}
        self.labels = node.resolve_topic_name(labels) if labels else ""
        self.make_feed = make_feed
        self.record = record
        self.fs_high = fs_high
        self.sources: SignalSources | None = None
        self.feed: SourceFeed | None = None
        self.status = "waiting for the sources' topics on the graph"
        self._error = ""
        self._rates_told: set[str] = set()  # sources whose rate problem the console has
        self._types: dict[str, str] = {}
        self._pending: dict[str, list[tuple[bytes, int]]] = {}
        self._names: dict[str, dict[int, list[str]]] = {}
        self._stamps: list[list[np.ndarray]] = []
        self._subs: list[Any] = []
        self._drain: _Drain | None = None
        self._layouts: dict[str, dict[str, Any]] = {}

    @property
    def error(self) -> str:
        """Why the sources cannot work ("" when they can): on /diagnostics and the console."""
        return self._error

    @error.setter
    def error(self, text: str) -> None:
        if text and text != self._error:  # each new problem once in the node's console
            self.node.get_logger().error(text)
        self._error = text

    # -- graph ------------------------------------------------------------------------------
    def poll(self) -> None:
        """Resolve and subscribe once every topic is on the graph (called by a timer)."""
        if self.sources is not None:
            return
        graph = {name: types for name, types in self.node.get_topic_names_and_types()}
        wanted = {topic_of(spec) for group in self.specs.values() for spec in group} | (
            {self.labels} if self.labels else set()
        )
        candidates = set(wanted) | {
            f"{t}/{s}" for t in wanted for s in ("full", "values", "names")
        }
        types: dict[str, tuple[str, str]] = {}
        for topic in candidates & set(graph):
            type_name = graph[topic][0]
            try:
                types[topic] = (type_name, installed_schema(type_name))
            except MrIdentError as err:
                if topic in wanted:
                    self.error = (
                        f"topic {topic} has type {type_name}, which is not installed here: {err}"
                    )
                    return
        try:
            sources = resolve_sources(types, self.specs, self.labels)
        except DataError as err:
            missing = [
                t
                for t in wanted
                if t not in graph and not any(c.startswith(t + "/") for c in graph)
            ]
            if missing:
                self.status = f"waiting for topic(s) {', '.join(sorted(missing))} on the graph"
                self.error = ""
            else:
                self.error = str(err)
            return
        self.error = ""
        self.sources = sources
        self.feed = self.make_feed(sources)
        self._stamps = [[] for _ in sources.all]
        for topic in sorted(sources.topics):
            self._subscribe(topic, types[topic][0])
        self.status = "subscribed: " + "; ".join(
            f"{s.spec.text} <- {s.topic} ({s.type})" for _, _, s in sources.all
        )

    def _subscribe(self, topic: str, type_name: str) -> None:
        from .messages import subscription_qos
        from .record import message_class

        qos = subscription_qos(self.node.get_publishers_info_by_topic(topic), depth=QUEUE_DEPTH)
        self._types[topic] = type_name
        pending = self._pending.setdefault(topic, [])
        record = self.record

        def on_message(raw: bytes, info: dict[str, Any], topic: str = topic) -> None:
            sent = info.get("source_timestamp") or info.get("received_timestamp") or time.time_ns()
            pending.append((raw, int(sent)))
            if record is not None:
                record(topic, type_name, raw, info)

        if self._drain is None:
            self._drain = _Drain(self.node)
        # the callback is called by the drain thread, not by an executor
        sub = self._drain.node.create_subscription(
            message_class(type_name), topic, lambda _: None, qos, raw=True
        )
        self._subs.append(sub)
        self._drain.add(sub, on_message)

    def close(self) -> None:
        """Stop taking messages (the node's shutdown)."""
        if self._drain is not None:
            self._drain.stop()

    # -- data ------------------------------------------------------------------------------
    def flush(self, now: float) -> list[str]:
        """Decode what arrived since the last call, as one batch per topic; returns notes."""
        if self.sources is None or self.feed is None:
            return []
        batches: dict[str, tuple[Batch, np.ndarray]] = {}
        for topic, pending in self._pending.items():
            if pending:
                items = pending[:]
                del pending[: len(items)]
                batches[topic] = (
                    Batch.of([raw for raw, _ in items]),
                    np.array([t for _, t in items], np.int64),
                )
        for topic, (batch, _) in batches.items():
            if self._types.get(topic) == STATISTICS_NAMES:
                reg = parse_schema(STATISTICS_NAMES, installed_schema(STATISTICS_NAMES))
                self._names.setdefault(topic, {}).update(names_by_version(reg, batch))
        samples: list[Samples | None] = []
        for i, (_, _, src) in enumerate(self.sources.all):
            got = batches.get(src.topic)
            if got is None:
                samples.append(None)
                continue
            smp = self._samples(src, *got)
            samples.append(smp)
            kept = self._stamps[i]
            kept.append(smp.stamps)
            if sum(s.size for s in kept) > 2 * RATE_WINDOW:
                self._stamps[i] = [np.concatenate(kept)[-RATE_WINDOW:]]
        if all(s is None for s in samples):
            return []
        return self.feed.push(samples, now)

    def _samples(self, src: Resolved, batch: Batch, received: np.ndarray) -> Samples:
        try:
            value, valid = evaluate_batch(
                src,
                batch,
                self._names.get(src.names_topic),
                self._layouts.setdefault(src.spec.text, {}),
            )
            return Samples(stamps_of(src, batch, received), value, valid, not src.stamped)
        except DataError as err:  # a message that does not decode: count it, carry on
            self.error = f"source {src.spec.text}: {err}"
            n = batch.size
            return Samples(received, np.zeros(n), np.zeros(n, bool), True)

    def rate_problem(self) -> str:
        """Why the stamps disagree with fs_high (after enough messages), or ""."""
        if self.sources is None or not self.fs_high:
            return ""
        for (_, _, src), kept in zip(self.sources.all, self._stamps, strict=True):
            if src.spec.hold or sum(s.size for s in kept) < 50:
                continue
            fs = infer_rate(np.concatenate(kept))
            if fs is not None and abs(fs / self.fs_high - 1.0) > 0.01:
                text = (
                    f"source {src.spec.text}: the stamps say {fs:.6g} Hz, fs_high is "
                    f"{self.fs_high:g} Hz; "
                    "set fs_high to the rate the loop runs at"
                )
                if src.spec.text not in self._rates_told:  # once in the console
                    self._rates_told.add(src.spec.text)
                    self.node.get_logger().error(text)
                return text
        return ""

    def values(self) -> dict[str, str]:
        """Per-source counters for /diagnostics."""
        out: dict[str, str] = {"sources": self.status}
        if self.feed is not None and self.sources is not None:
            for (stream, channel, src), st in zip(self.sources.all, self.feed.stats, strict=True):
                key = f"source.{SIGNALS[stream]}{channel}"
                out[key] = (
                    f"{src.spec.text}: {st.messages} messages, {st.samples} samples, "
                    f"{st.off_grid} off grid, {st.unmatched} without value"
                )
        return out


class _Drain:
    """Takes the sources' messages in a thread of its own, every queued one at each wake-up.

    rclpy's executor handles one message per turn and rebuilds its wait set each time, which
    limits it to a few thousand messages per second; a message per sample needs more. The
    subscriptions live on a helper node that no executor spins; this thread waits on them
    (rclpy's wait set, as :func:`rclpy.wait_for_message.wait_for_message` does) and takes
    every message queued on each ready one.

    The helper is hidden (its name starts with ``_``), named after its owner and unique in
    the process, in the owner's namespace; it takes no global arguments (a launch file's
    ``__node``/``__ns`` remaps name the owner only; its topics come resolved from the owner)
    and serves nothing (no parameter services, no type description service, no rosout).
    """

    _count = 0

    def __init__(self, owner: Any):
        import os

        import rclpy
        from rclpy.guard_condition import GuardCondition
        from rclpy.parameter import Parameter

        _Drain._count += 1
        context = owner.context
        self.node = rclpy.create_node(
            f"_{owner.get_name()}_sources_{os.getpid()}_{_Drain._count}",
            namespace=owner.get_namespace(),
            context=context,
            use_global_arguments=False,
            start_parameter_services=False,
            enable_rosout=False,
            parameter_overrides=[Parameter("start_type_description_service", value=False)],
        )
        self._context = context
        self._subs: list[tuple[Any, Callable[[bytes, dict[str, Any]], None]]] = []
        self._wake = GuardCondition(None, None, context=context)
        self._stopping = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="mr_ident-sources", daemon=True)
        self._thread.start()

    def add(self, sub: Any, callback: Callable[[bytes, dict[str, Any]], None]) -> None:
        with self._lock:
            self._subs.append((sub, callback))
        self._wake.trigger()

    def _run(self) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        while not self._stopping:
            with self._lock:
                subs = list(self._subs)
            try:
                ws = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, self._context.handle)
                ws.clear_entities()
                for sub, _ in subs:
                    ws.add_subscription(sub.handle)
                ws.add_guard_condition(self._wake.handle)
                ws.wait(200_000_000)
                ready = set(ws.get_ready_entities("subscription"))
                for sub, callback in subs:
                    if sub.handle.pointer not in ready:
                        continue
                    while not self._stopping:
                        with sub.handle:
                            taken = sub.handle.take_message(sub.msg_type, True)
                        if taken is None:
                            break
                        callback(taken[0], taken[1])
            except Exception:  # noqa: BLE001 - the context is going away: stop
                if self._stopping or not self._context.ok():
                    return
                raise

    def stop(self) -> None:
        self._stopping = True
        try:
            self._wake.trigger()
        except Exception:  # noqa: BLE001 - already destroyed
            pass
        self._thread.join(5)
        self.node.destroy_node()
