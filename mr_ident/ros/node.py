"""``mr-ident-node``: live identification of a multirate loop on a ROS 2 graph.

A thin adapter: messages -> :func:`~mr_ident.ros.messages.decode_raw` ->
:class:`~mr_ident.live.ingest.Ingest` (the path replay takes too) -> the
:class:`~mr_ident.live.align.Aligner` (executor thread); every ``update_period_s`` the
latest aligned window goes to a worker thread that runs
:func:`~mr_ident.live.estimate.estimate` and publishes (the first one waits for a
:func:`~mr_ident.live.estimate.warm_up` started with the node). Parameters are the fields
of :class:`~mr_ident.io.config.IdentConfig`, validated through it on every set.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray

from ..allocator import keep_freed_memory
from ..errors import MrIdentError
from ..io.blocks import STREAMS, Block
from ..io.config import IdentConfig
from ..live.align import Aligner
from ..live.estimate import Estimate, estimate, publish_grid, warm_up
from ..live.feed import SignalSources, SourceFeed
from ..live.ingest import Ingest
from ..numerics.signals import LoopData
from . import params
from .health import Health, identification_status
from .messages import BLOCK_QOS, BLOCK_TYPE, ResultPublishers, decode_raw
from .monitoring import PlantMonitoring
from .program import handle_signals, ros_context, spin_until_stopped
from .recorder import NodeRecorder
from .sources import BATCH_S, SourceSubscriber

REORDER_WAIT_S = 0.5  # blocks wait this long (wall clock) for a missing one before it is a gap


class IdentNode(Node):
    """The identification node (see the module docstring and the README)."""

    def __init__(self, name: str = "mr_ident", **kwargs: Any):
        super().__init__(name, **kwargs)
        self.config = params.declare(self)  # raises ConfigError on a bad params file
        self.add_on_set_parameters_callback(self._on_set)

        self._lock = threading.Lock()  # guards the estimate state below
        self._aligner = self._new_aligner(self.config)
        self._ingest = Ingest(self._aligner)
        self._notes: list[tuple[float, str]] = []
        self._arrivals = [0.0] * len(self._aligner.names)
        self._samples_in = 0
        self._started = time.monotonic()
        self._last_estimate: Estimate | None = None
        self._last_estimate_wall = 0.0
        self._estimates = 0
        self._last_error = ""
        self._last_error_time = 0.0
        self._last_end = -1
        self._warm_up = ""  # "" while running, then its result
        self._busy = False
        self._stopping = False
        self._worker_thread: threading.Thread | None = None
        self._recording = NodeRecorder(self)

        self._subs = []
        self._sources: SourceSubscriber | None = None
        if self.config.sources is None:  # the block contract on reference, input, output
            labels = self.config.excitation_index_topic  # and the excitation's labels
            for s, topic in enumerate(STREAMS + ((labels,) if labels else ())):
                self._subs.append(
                    self.create_subscription(
                        Float64MultiArray,
                        topic,
                        functools.partial(self._on_block, s),
                        BLOCK_QOS,
                        raw=True,
                    )
                )
        else:  # per-sample sources: subscribed once their topics are on the graph
            self._sources = SourceSubscriber(
                self,
                dict(self.config.sources),
                self._new_feed,
                self._recording.source,
                self.config.fs_high,
                labels=self.config.excitation_index_topic,
            )
            self._sources.poll()
            self.create_timer(0.5, self._sources.poll)
            self.create_timer(BATCH_S, self._on_sources)
        self._results = ResultPublishers(self)
        self._monitoring = PlantMonitoring(self, self.config)  # raises on a bad reference
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._update_timer = self.create_timer(self.config.update_period_s, self._on_update)
        self.create_timer(1.0, self._publish_diagnostics)
        if self.config.record_path:
            self._recording.open(self.config.record_path)
        # One identification of a synthetic full-size window, so that the first real one
        # does not pay the one-time costs (see live.warm_up); estimates wait for it.
        self._busy = True
        self._worker_thread = threading.Thread(
            target=self._warm, args=(self.config,), daemon=True, name="mr_ident-warm-up"
        )
        self._worker_thread.start()

    # -- parameters ------------------------------------------------------------------
    def _on_set(self, changed: list[Parameter]) -> SetParametersResult:
        changes = params.changes(changed)
        try:
            new = self.config.replace(**changes)
        except MrIdentError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if (new.sources, new.excitation_index_topic) != (
            self.config.sources,
            self.config.excitation_index_topic,
        ):
            return SetParametersResult(
                successful=False,
                reason="r_source, u_source, y_source and excitation_index_topic are read at "
                "start; restart the node to change them",
            )
        try:
            self._monitoring.reconfigure(new)
        except MrIdentError as err:
            return SetParametersResult(successful=False, reason=str(err))
        old, self.config = self.config, new
        if (new.fs_high, new.ratio, new.window_samples, new.reorder_blocks) != (
            old.fs_high,
            old.ratio,
            old.window_samples,
            old.reorder_blocks,
        ):
            self._aligner = self._new_aligner(new)
            self._ingest = Ingest(self._aligner)
            if self._sources is not None:
                self._sources.fs_high = new.fs_high
                if self._sources.sources is not None:
                    self._sources.feed = self._new_feed(self._sources.sources)
            self._note("parameters changed (rate, F, window or reorder): window restarts")
        if new.update_period_s != old.update_period_s:
            self._update_timer.cancel()
            self.destroy_timer(self._update_timer)
            self._update_timer = self.create_timer(new.update_period_s, self._on_update)
        if new.record_path != old.record_path:
            self._recording.close()
            self._recording.error = ""
            if new.record_path:
                self._recording.open(new.record_path)
        return SetParametersResult(successful=True)

    @staticmethod
    def _new_aligner(c: IdentConfig) -> Aligner:
        return Aligner(
            c.window_samples, c.ratio, c.reorder_blocks, labels=bool(c.excitation_index_topic)
        )

    # -- ingestion (executor thread) ----------------------------------------------------
    def _note(self, text: str) -> None:
        self._notes.append((time.monotonic(), text))
        del self._notes[:-50]
        self.get_logger().warning(text, throttle_duration_sec=1.0)

    def _on_block(self, stream: int, raw: bytes) -> None:
        now = time.monotonic()
        self._arrivals[stream] = now
        self._recording.message(self._subs[stream].topic_name, BLOCK_TYPE, raw)
        item = decode_raw(raw)  # a Block or a BlockError, never an exception
        if isinstance(item, Block):
            self._samples_in += item.samples.shape[0]
        note = self._ingest.offer(stream, item, now)
        if note:
            self._note(note)

    def _new_feed(self, sources: SignalSources) -> SourceFeed:
        c = self.config
        return SourceFeed(
            sources, self._ingest, fs_high=c.fs_high, ratio=c.ratio, tolerance=c.stamp_tolerance
        )

    def _on_sources(self) -> None:
        """Decode the messages the sources received meanwhile (a timer, every BATCH_S)."""
        assert self._sources is not None
        now = time.monotonic()
        before = [st.samples for st in self._sources.feed.stats] if self._sources.feed else []
        for note in self._sources.flush(now):
            self._note(note)
        if self._sources.feed is not None and self._sources.sources is not None:
            for (stream, _, _), st, b in zip(
                self._sources.sources.all, self._sources.feed.stats, before, strict=True
            ):
                if st.samples > b:
                    self._arrivals[stream] = now
                    self._samples_in += st.samples - b

    # -- estimation ---------------------------------------------------------------------
    def _on_update(self) -> None:
        for note in self._ingest.expire(time.monotonic(), REORDER_WAIT_S):
            self._note(note)
        if self._busy or self._stopping:
            return
        cfg = self.config
        lo, hi = self._aligner.span()
        if hi - lo < cfg.min_samples or hi == self._last_end:
            return
        window = self._aligner.window(cfg.min_samples)
        if window is None:
            return
        self._last_end = window.end
        self._busy = True
        self._worker_thread = threading.Thread(
            target=self._work, args=(window, cfg), daemon=True, name="mr_ident-estimate"
        )
        self._worker_thread.start()

    def _work(self, window: LoopData, cfg: IdentConfig) -> None:
        try:
            est = estimate(window, cfg)
            if not self._stopping:
                self._publish(est, cfg)
                self._monitoring.observe(est, window, cfg)
            with self._lock:
                self._last_estimate = est
                self._last_estimate_wall = time.monotonic()
                self._estimates += 1
        except Exception as err:  # keep the node alive; report on /diagnostics
            with self._lock:
                self._last_error, self._last_error_time = (
                    f"identification failed: {err}",
                    time.monotonic(),
                )
            self.get_logger().error(self._last_error)
        finally:
            self._busy = False

    def _warm(self, cfg: IdentConfig) -> None:
        try:
            seconds = warm_up(cfg)
            self._warm_up = f"{seconds:.4f}"
            self.get_logger().info(
                f"warm-up: one identification of {cfg.window_samples} samples took {seconds:.3f} s"
            )
        except Exception as err:  # only a speed-up: the node works without it
            self._warm_up = f"failed: {err}"
            self.get_logger().warning(f"warm-up identification failed: {err}")
        finally:
            self._busy = False

    def _publish(self, est: Estimate, cfg: IdentConfig) -> None:
        ident = est.identification
        self._results.publish(ident, publish_grid(ident.plant.frequency.size, cfg.publish_points))

    @property
    def last_estimate(self) -> Estimate | None:
        """The latest estimate (None before the first)."""
        with self._lock:
            return self._last_estimate

    # -- diagnostics --------------------------------------------------------------------
    def diagnostic_status(self) -> DiagnosticStatus:
        """The node's status for /diagnostics: level, message, every counter."""
        with self._lock:
            est, err, err_t = self._last_estimate, self._last_error, self._last_error_time
            n_est, est_t = self._estimates, self._last_estimate_wall
        path = self._recording.path
        health = Health(
            now=time.monotonic(),
            config=self.config,
            stats=self._aligner.stats,
            span=self._aligner.span(),
            restarts=self._aligner.restarts,
            estimate=est,
            estimates=n_est,
            estimate_wall=est_t,
            error=err,
            error_time=err_t,
            notes=list(self._notes),
            arrivals=list(self._arrivals),
            started=self._started,
            samples_in=self._samples_in,
            sources=self._sources,
            record_error=self._recording.error,
            recording=path.as_posix() if path is not None else "",
            warm_up=self._warm_up,
        )
        return identification_status(health, self.get_name(), self.get_fully_qualified_name())

    def _publish_diagnostics(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostic_status()]
        stale = max(3.0 * self.config.update_period_s, self.config.stall_timeout_s)
        plant = self._monitoring.status(self.get_name(), self.get_fully_qualified_name(), stale)
        if plant is not None:
            msg.status.append(plant)
        self._pub_diag.publish(msg)

    def shutdown(self, timeout: float = 30.0) -> None:
        """Stop estimating, wait for a running identification, finalise the recording."""
        self._stopping = True
        if self._sources is not None:
            self._sources.close()
        t = self._worker_thread
        if t is not None:
            t.join(timeout)
        self._monitoring.shutdown(timeout)
        self._recording.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``mr-ident-node`` (accepts ``--ros-args ...``).

    SIGINT and SIGTERM stop it at any moment through one path
    (:mod:`mr_ident.ros.program`): the running identification is awaited, the
    recording finalised, then rclpy shut down; exit 0.
    """
    stop = handle_signals()
    args = list(sys.argv if argv is None else argv)
    keep_freed_memory()
    try:
        with ros_context(args):
            node = None
            try:
                node = IdentNode()
                # Not rclpy.experimental.EventsExecutor: in rclpy 7.1.6 its spin() starves other
                # Python threads (measured: the identification thread and publishers from other
                # threads stall), and the identification must run off the executor thread.
                executor = SingleThreadedExecutor()
                executor.add_node(node)
                spin_until_stopped(executor, node, stop)
                executor.shutdown()
            finally:
                if node is not None:
                    node.shutdown()
                    node.destroy_node()
    except (
        MrIdentError,
        rclpy.exceptions.InvalidParameterTypeException,
        rclpy.exceptions.InvalidParameterValueException,
    ) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
