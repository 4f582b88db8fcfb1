# SPDX-License-Identifier: Apache-2.0
"""The node's inputs: its subscriptions and the window they fill (executor thread).

The block contract (``reference``, ``input``, ``output``, relative names: the node's
namespace and remaps apply) or per-sample sources
(:class:`~mr_ident.ros.sources.SourceSubscriber`), into one
:class:`~mr_ident.live.ingest.Ingest` and :class:`~mr_ident.live.align.Aligner`. Made at
activate, dropped at deactivate; :meth:`Inputs.new_window` starts the window afresh (a
reset, a parameter change) and counts a generation, so that estimates of an older window,
still running, are not published.

Timers here run on the steady clock: the sources are drained and reordered blocks given
up on whatever the ROS clock does (with ``use_sim_time`` and no /clock the memory stays
bounded).

QoS of the block topics: reliable (keep-last 1000) unless a publisher on the topic offers
best effort (a sensor-data publisher) when the node subscribes; a best-effort publisher
that comes later is reported incompatible by DDS: the node names it (the policy, on
/diagnostics) and subscribes that stream again best effort, which matches every publisher.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import QoSPolicyKind, QoSProfile, ReliabilityPolicy, qos_policy_name_from_kind
from std_msgs.msg import Float64MultiArray

from ..io.blocks import STREAMS, Block
from ..io.config import IdentConfig
from ..live.align import Aligner
from ..live.feed import SignalSources, SourceFeed
from ..live.gaps import config_bridging
from ..live.ingest import Ingest
from ..live.sampling import grid_stamps
from ..numerics.signals import LoopData
from .messages import BLOCK_QOS, BLOCK_TYPE, decode_raw, subscription_qos
from .recorder import NodeRecorder
from .sources import BATCH_S, SourceSubscriber

REORDER_WAIT_S = 0.5  # blocks wait this long (wall clock) for a missing one before it is a gap


class Inputs:
    """What one node receives, aligned (see the module docstring).

    ``note(text)`` reports an anomaly (the node logs it and shows it on /diagnostics).
    """

    def __init__(
        self,
        node: Any,
        cfg: IdentConfig,
        recording: NodeRecorder,
        note: Callable[[str], None],
        steady: Any,
    ) -> None:
        self.node = node
        self.config = cfg
        self.recording = recording
        self.note = note
        self.steady = steady
        self.subs: list[Any] = []
        self.qos_problems: dict[str, str] = {}  # stream -> the incompatible QoS policy seen
        self._best_effort: set[int] = set()  # streams to subscribe again best effort
        self.sources: SourceSubscriber | None = None
        self.samples_in = 0
        self.generation = 0
        self._timers = [node.create_timer(0.1, self.expire, clock=steady)]
        self.new_window(cfg)

    # -- the window -------------------------------------------------------------------------
    def new_window(self, c: IdentConfig) -> None:
        """A fresh, empty window (estimates of the old one, still running, are void)."""
        self.config = c
        self.aligner = Aligner(
            c.window_samples,
            c.ratio,
            c.reorder_blocks,
            labels=bool(c.excitation_index_topic),
            bridge=config_bridging(c),
        )
        self.ingest = Ingest(self.aligner)
        self.arrivals = [0.0] * len(self.aligner.names)
        self.generation += 1
        self.last_end = -1
        self._anchor: tuple[int, int] | None = None  # (sample index, ROS time ns) of a block
        if self.sources is not None:
            self.sources.fs_high = c.fs_high
            if self.sources.sources is not None:
                self.sources.feed = self.make_feed(self.sources.sources)

    def reset(self) -> None:
        """Drop the window now: the next estimate holds only samples that come after.

        What the sources received before goes into the old window, and with it. The
        sources' grid (their t0) stays.
        """
        src = self.sources
        if src is not None:
            src.flush(time.monotonic())
        feed = src.feed if src is not None else None
        self.new_window(self.config)
        if src is not None and feed is not None:
            feed.ingest = self.ingest
            src.feed = feed

    def window(self, min_samples: int) -> LoopData | None:
        """The latest aligned window when it is new and long enough (marked taken), else None."""
        lo, hi = self.aligner.span()
        if hi - lo < min_samples or hi == self.last_end:
            return None
        w = self.aligner.window(min_samples)
        if w is not None:
            self.last_end = w.end
        return w

    def stamp(self, last: int) -> int:
        """ROS time (ns) of sample ``last``: from the sources' stamps, else the output's arrival.

        Block contract: the ROS time at which the output block holding the latest sample
        arrived, less the samples since ``last`` at fs_high (the ROS time now, when no block
        came since the ROS clock runs: use_sim_time before the first /clock).
        """
        feed = self.sources.feed if self.sources is not None else None
        if feed is not None and feed.sampler.t0 is not None:
            return int(grid_stamps(feed.sampler.t0, last, 1, feed.sampler.fs_high)[0])
        if self._anchor is None or self._anchor[1] <= 0:  # no block since the clock runs
            return self._ros_now()
        index, ns = self._anchor
        return ns - round((index - last) * 1e9 / self.config.fs_high)

    def _ros_now(self) -> int:
        return int(self.node.get_clock().now().nanoseconds)

    # -- subscriptions ----------------------------------------------------------------------
    def subscribe(self) -> None:
        """Subscribe to the inputs (activate)."""
        cfg = self.config
        if cfg.sources is None:  # the block contract on reference, input, output
            labels = cfg.excitation_index_topic  # and the excitation's labels
            for s, topic in enumerate(STREAMS + ((labels,) if labels else ())):
                self.subs.append(self._block_subscription(s, topic))
            return
        # per-sample sources: subscribed once their topics are on the graph
        self.sources = SourceSubscriber(
            self.node,
            dict(cfg.sources),
            self.make_feed,
            self.recording.source,
            cfg.fs_high,
            labels=cfg.excitation_index_topic,
        )
        self.sources.poll()
        self._timers += [
            self.node.create_timer(0.5, self.sources.poll, clock=self.steady),
            self.node.create_timer(BATCH_S, self.on_sources, clock=self.steady),
        ]

    def _block_subscription(self, stream: int, topic: str, best_effort: bool = False) -> Any:
        """The subscription of a block stream: reliable unless a publisher offers less."""
        node = self.node
        infos = node.get_publishers_info_by_topic(node.resolve_topic_name(topic))
        qos = (
            subscription_qos(infos, depth=BLOCK_QOS.depth)
            if infos
            else QoSProfile(
                history=BLOCK_QOS.history,
                depth=BLOCK_QOS.depth,
                reliability=BLOCK_QOS.reliability,
                durability=BLOCK_QOS.durability,
            )
        )  # a profile of its own: BLOCK_QOS is everyone's
        if best_effort:
            qos.reliability = ReliabilityPolicy.BEST_EFFORT
        return node.create_subscription(
            Float64MultiArray,
            topic,
            functools.partial(self.on_block, stream),
            qos,
            raw=True,
            event_callbacks=SubscriptionEventCallbacks(
                incompatible_qos=functools.partial(self.on_incompatible, stream)
            ),
        )

    def on_incompatible(self, stream: int, event: Any) -> None:
        """A publisher the subscription cannot match: named, and best effort if it can help."""
        name = self.aligner.names[stream]
        policy = qos_policy_name_from_kind(event.last_policy_kind)
        sub = self.subs[stream] if stream < len(self.subs) else None
        if sub is None:  # unsubscribed meanwhile
            return
        reliable = sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        if event.last_policy_kind == QoSPolicyKind.RELIABILITY and reliable:
            self._best_effort.add(stream)  # the steady timer subscribes again
            self.note(
                f"{name}: a publisher on {sub.topic_name} offers best effort (incompatible "
                f"QoS: {policy}): subscribed again best effort"
            )
            return
        self.qos_problems[name] = policy
        topic = sub.topic_name
        self.note(f"{name}: a publisher on {topic} offers an incompatible QoS ({policy})")

    def unsubscribe(self) -> None:
        """Drop the subscriptions (deactivate)."""
        for sub in self.subs:
            self.node.destroy_subscription(sub)
        self.subs = []
        for t in self._timers[1:]:
            self.node.destroy_timer(t)
        del self._timers[1:]
        if self.sources is not None:
            self.sources.close()
            self.sources = None

    def destroy(self) -> None:
        """Unsubscribe and drop the timers (cleanup)."""
        self.unsubscribe()
        for t in self._timers:
            self.node.destroy_timer(t)
        self._timers = []

    # -- messages ---------------------------------------------------------------------------
    def on_block(self, stream: int, raw: bytes) -> None:
        """One raw block message of ``stream``."""
        now = time.monotonic()
        self.arrivals[stream] = now
        self.recording.message(self.subs[stream].topic_name, BLOCK_TYPE, raw)
        item = decode_raw(raw)  # a Block or a BlockError, never an exception
        if isinstance(item, Block):
            self.samples_in += item.samples.shape[0]
            if stream == 2:  # the output's arrival times stamp the estimates
                self._anchor = (item.first + item.samples.shape[0] - 1, self._ros_now())
        note = self.ingest.offer(stream, item, now)
        if note:
            self.note(note)

    def make_feed(self, sources: SignalSources) -> SourceFeed:
        """The feed from resolved sources into the window."""
        c = self.config
        return SourceFeed(
            sources, self.ingest, fs_high=c.fs_high, ratio=c.ratio, tolerance=c.stamp_tolerance
        )

    def on_sources(self) -> None:
        """Decode the messages the sources received meanwhile (a timer, every BATCH_S)."""
        src = self.sources
        if src is None:
            return
        now = time.monotonic()
        before = [st.samples for st in src.feed.stats] if src.feed else []
        for note in src.flush(now):
            self.note(note)
        if src.feed is not None and src.sources is not None:
            for (stream, _, _), st, b in zip(src.sources.all, src.feed.stats, before, strict=True):
                if st.samples > b:
                    self.arrivals[stream] = now
                    self.samples_in += st.samples - b

    def expire(self) -> None:
        """Give up on blocks that waited too long for a missing one (a steady timer).

        And subscribe again best effort the streams a best-effort publisher asked for.
        """
        for stream in sorted(self._best_effort):
            if stream < len(self.subs):
                old = self.subs[stream]
                self.subs[stream] = self._block_subscription(stream, old.topic_name, True)
                self.node.destroy_subscription(old)
        self._best_effort.clear()
        for note in self.ingest.expire(time.monotonic(), REORDER_WAIT_S):
            self.note(note)
