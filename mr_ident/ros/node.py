# SPDX-License-Identifier: Apache-2.0
"""``mr-ident-node``: live identification of a multirate loop on a ROS 2 graph (a managed node).

A thin adapter: messages -> :func:`~mr_ident.ros.messages.decode_raw` ->
:class:`~mr_ident.live.ingest.Ingest` (the path replay takes too) -> the
:class:`~mr_ident.live.align.Aligner` (executor thread); every ``update_period_s`` (ROS
clock) the latest aligned window goes to a worker thread that runs
:func:`~mr_ident.live.estimate.estimate` and publishes. Parameters are the fields of
:class:`~mr_ident.io.config.IdentConfig`, validated through it on every set.

Lifecycle (``rclpy.lifecycle``; ros2/demos' ``lifecycle_py`` talker is the model):

* ``configure``: the parameters checked, the monitoring reference loaded, publishers,
  services and timers made, the warm-up identification started;
* ``activate``: the inputs subscribed, ``record_path`` opened, estimates published;
* ``deactivate``: the subscriptions dropped, the window dropped, the recording finalised;
* ``cleanup``: back to unconfigured; ``shutdown``: the recording finalised first, then a
  running identification awaited at most :data:`JOIN_S`.

``mr-ident-node`` waits unconfigured for a launch file or lifecycle manager, as a managed
node does; with ``autostart:=true`` it configures and activates itself. A request for a
transition the state has not is refused (success false, the reason logged), never fatal
(:mod:`mr_ident.ros.lifecycle`). Without its interfaces (mr_ident_msgs) configure fails,
saying how to build them.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter

from ..errors import ConfigError, MrIdentError
from ..io.config import IdentConfig
from ..live.estimate import Estimate, estimate, warm_up
from ..numerics.signals import LoopData
from ..numerics.threads import BLAS_UNLIMITED, find_scipy_blas
from . import params
from .health import NO_CLOCK, Health, identification_status, unconfigured_status
from .inputs import Inputs
from .lifecycle import answer_every_request, logged, state_label
from .monitoring import PlantMonitoring
from .outputs import EstimateMsg, Outputs
from .recorder import NodeRecorder
from .services import NodeServices

JOIN_S = 1.0  # at shutdown, a running identification is awaited this long (after the MCAP)
#: Why configure fails without the interface package, and how to get it.
MISSING_INTERFACES = (
    "the interface package mr_ident_msgs (~/estimate, ~/summary and the services) is not "
    "installed: build it with this package (`colcon build` in the workspace that holds the "
    "mr_ident repository, then `source install/setup.bash`; or `make venv` in the repository)"
)

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR


@dataclass(frozen=True)
class Published:
    """The latest estimate as it went out: the estimate, its stamp (ns), its window's data."""

    estimate: Estimate
    stamp_ns: int
    window: LoopData
    message: Any


class IdentNode(LifecycleNode):
    """The identification node (see the module docstring and docs/node.md)."""

    def __init__(self, name: str = "mr_ident", **kwargs: Any):
        super().__init__(name, **kwargs)
        answer_every_request(self)  # a transition the state has not: success false, logged
        params.declare(self)  # values are checked at configure
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._after_set)
        self.config: IdentConfig | None = None
        self.configure_error = ""
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._lock = threading.Lock()  # held on every access to the six fields below
        self._busy = False  # a worker (warm-up or identification) runs
        self._warm_up = ""
        self._published: Published | None = None
        self._last_estimate_wall = 0.0
        self._estimates = 0
        self._last_error = ""
        self._last_error_time = 0.0
        self._pending: tuple[IdentConfig, Any] | None = None
        self._active = False
        self._stopping = False
        self._joined = False  # shutdown has waited for the threads
        self._notes: list[tuple[float, str]] = []
        self._started = time.monotonic()
        self._worker_thread: threading.Thread | None = None
        self._recording = NodeRecorder(self)
        self._naming = False
        self._update_timer: Any = None  # made at configure
        self._node_timers: list[Any] = []
        self.inputs: Inputs | None = None  # subscriptions and window, made at configure
        self._outputs: Outputs | None = None
        self._monitoring: PlantMonitoring | None = None
        self._srv: NodeServices | None = None
        # /diagnostics from the start (an unconfigured node says that it waits) to finalized
        self._pub_diag: Any = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._diag_timer: Any = self.create_timer(
            1.0, self._publish_diagnostics, clock=self._steady
        )

    # -- lifecycle ----------------------------------------------------------------------
    def autostart(self) -> bool:
        """Configure and activate when the parameter ``autostart`` says so; whether it worked."""
        if not params.flag(self, "autostart"):
            self.get_logger().info(
                "unconfigured: waiting for lifecycle transitions (a launch file or lifecycle "
                "manager; autostart:=true configures and activates at start)"
            )
            return True
        return self.trigger_configure() == SUCCESS and self.trigger_activate() == SUCCESS

    @logged
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Check the parameters, load the reference, make the outputs, start the warm-up."""
        try:
            if EstimateMsg is None:
                raise ConfigError(MISSING_INTERFACES)
            cfg = params.read(self)
            monitoring = PlantMonitoring(self, cfg)  # loads the reference
        except MrIdentError as err:
            self.configure_error = str(err)
            self.get_logger().error(f"configure failed: {err}")
            return FAILURE
        self.configure_error = ""
        if BLAS_UNLIMITED:  # optional (no rosdep key): the node runs without it, slower
            self.get_logger().warning(BLAS_UNLIMITED, once=True)
        find_scipy_blas()  # before the workers: a diagnosis holds SciPy's BLAS to one thread
        self.config, self._monitoring = cfg, monitoring
        self._stopping = self._joined = False
        self.inputs = Inputs(self, cfg, self._recording, self._note, self._steady)
        self._outputs = Outputs(self, params.flag(self, "legacy_array_topics"))
        self._srv = NodeServices(self)
        self._update_timer = self.create_timer(cfg.update_period_s, self._on_update)  # ROS clock
        self._node_timers = [self._update_timer]
        # One identification of a synthetic full-size window, so that the first real one
        # does not pay the one-time costs (see live.warm_up); estimates wait for it.
        with self._lock:
            self._busy, self._warm_up = True, ""
        self._worker_thread = threading.Thread(
            target=self._warm, args=(cfg,), daemon=True, name="mr_ident-warm-up"
        )
        self._worker_thread.start()
        return super().on_configure(state)

    @logged
    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Subscribe to the inputs, open ``record_path``, publish estimates."""
        cfg = self.config
        assert cfg is not None
        assert self.inputs is not None
        self.inputs.subscribe()
        if cfg.record_path:  # a new file named after the path asked for, never an old one
            self.start_recording(self._recording.last or cfg.record_path)
        self._active = True
        return super().on_activate(state)

    @logged
    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Unsubscribe, finalise the recording, drop the window."""
        self._active = False
        if self.inputs is not None:
            self.inputs.unsubscribe()
            self.inputs.new_window(self.inputs.config)
        self._recording.close()
        return super().on_deactivate(state)

    @logged
    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Undo the configure (back to unconfigured)."""
        self._release()
        return super().on_cleanup(state)

    @logged
    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Finalise the recording, wait a bounded time for the workers, release everything.

        Finalized, the node keeps only what rclpy gives every node (the lifecycle and
        parameter services): no subscription, service, timer or publisher of its own.
        """
        self.shutdown()
        self._release()
        self.destroy_timer(self._diag_timer)
        self.destroy_publisher(self._pub_diag)
        self._pub_diag = None
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release everything; back to unconfigured."""
        self.get_logger().error("a transition raised: the node goes back to unconfigured")
        self.shutdown()
        self._release()
        self._stopping = False
        return SUCCESS

    def _release(self) -> None:
        """Everything configure made, undone (the recording finalised first)."""
        self._active = False
        self._stopping = True
        if self.inputs is not None:
            self.inputs.destroy()
            self.inputs = None
        self._recording.close()
        for t in self._node_timers:
            self.destroy_timer(t)
        self._node_timers = []
        if self._srv is not None:
            self._srv.destroy()
            self._srv = None
        if self._outputs is not None:
            self._outputs.destroy()
            self._outputs = None
        if self._monitoring is not None:
            self._monitoring.destroy()
            self._monitoring = None
        self.config = None

    # -- parameters: checked in _on_set, applied in _after_set -----------------------------
    def _on_set(self, changed: list[Parameter]) -> SetParametersResult:
        changes = params.changes(changed)
        if not changes:
            return SetParametersResult(successful=True)
        try:
            base = self.config
            if base is None:
                try:
                    base = params.read(self)
                except ConfigError:
                    base = IdentConfig()
            new = base.replace(**changes)
            watch = self._monitoring.load(new) if self._monitoring is not None else None
        except MrIdentError as err:
            return SetParametersResult(successful=False, reason=str(err))
        self._pending = (new, watch)
        return SetParametersResult(successful=True)

    def _after_set(self, changed: list[Parameter]) -> None:
        for p in changed:  # a path asked for (not the file's name): new files are named after it
            if p.name == "record_path" and not self._naming:
                self._recording.last = str(p.value or "")
        pending, self._pending = self._pending, None
        old = self.config
        if pending is None or old is None:  # unconfigured: read at configure
            return
        new, watch = pending
        assert self._monitoring is not None
        self._monitoring.install(new, watch)
        self.config = new
        if self.inputs is not None:
            self.inputs.config = new
        if (new.fs_high, new.ratio, new.window_samples, new.reorder_blocks) != (
            old.fs_high,
            old.ratio,
            old.window_samples,
            old.reorder_blocks,
        ):
            assert self.inputs is not None
            self.inputs.new_window(new)
            self._note("parameters changed (rate, F, window or reorder): window restarts")
        if new.update_period_s != old.update_period_s:
            self.destroy_timer(self._update_timer)
            self._update_timer = self.create_timer(new.update_period_s, self._on_update)
            self._node_timers[0] = self._update_timer
        current = self._recording.path
        if new.record_path != old.record_path and self._active:
            if new.record_path != (str(current) if current is not None else ""):
                self._recording.close()
                self._recording.error = ""
                if new.record_path:
                    self.start_recording(new.record_path)

    # -- the recording ------------------------------------------------------------------------
    def start_recording(self, path: str) -> Path | None:
        """Record the inputs to a new file, ``path`` or a new name beside it; its path.

        ``record_path`` is set to the file being written (None and :attr:`recording`'s error
        when it cannot be opened).
        """
        target = self._recording.open(path)
        if target is not None:
            self._name_recording(str(target))
        return target

    def stop_recording(self) -> Path | None:
        """Finalise the recording; ``record_path`` empty. The file finalised, or None."""
        path = self._recording.path
        self._recording.close()
        self._name_recording("")
        return path

    def _name_recording(self, value: str) -> None:
        if self.get_parameter("record_path").value != value:
            self._naming = True  # the file's name, not a new path asked for
            try:
                self.set_parameters([Parameter("record_path", value=value)])
            finally:
                self._naming = False

    # -- the window -------------------------------------------------------------------------
    def reset_window(self) -> None:
        """Drop the window now: the next estimate holds only samples that come after."""
        assert self.inputs is not None
        self.inputs.reset()
        self._note("window dropped (~/reset)")

    def current_window(self) -> LoopData | None:
        """The window the next estimate would take (executor thread), or None."""
        if self.inputs is None or self.config is None:
            return None
        return self.inputs.aligner.window(self.config.min_samples)

    def _note(self, text: str) -> None:
        self._notes.append((time.monotonic(), text))
        del self._notes[:-50]
        self.get_logger().warning(text, throttle_duration_sec=1.0)

    # -- estimation ---------------------------------------------------------------------
    def _on_update(self) -> None:
        with self._lock:  # only this thread sets _busy, the workers clear it
            if self._busy or self._stopping or not self._active:
                return
        cfg, inputs = self.config, self.inputs
        assert cfg is not None and inputs is not None
        window = inputs.window(cfg.min_samples)
        if window is None:
            return
        with self._lock:
            self._busy = True
        self._worker_thread = threading.Thread(
            target=self._work,
            args=(
                window,
                cfg,
                inputs.stamp(window.end - 1),
                inputs.generation,
                inputs.aligner.missing(window.first, window.end),
            ),
            daemon=True,
            name="mr_ident-estimate",
        )
        self._worker_thread.start()

    def _work(
        self, window: LoopData, cfg: IdentConfig, stamp: int, generation: int, missing: int
    ) -> None:
        try:
            est = estimate(window, cfg)
            inputs = self.inputs
            current = (
                not self._stopping
                and self._active
                and inputs is not None
                and generation == inputs.generation
            )
            if current and self._outputs is not None and self._monitoring is not None:
                state = self._monitoring.observe(est, window, cfg, stamp)
                msg = self._outputs.publish(est, cfg, stamp, state, missing)
                with self._lock:
                    self._published = Published(est, stamp, window, msg)
                    self._last_estimate_wall = time.monotonic()
                    self._estimates += 1
        except Exception as err:  # keep the node alive; report on /diagnostics
            with self._lock:
                self._last_error, self._last_error_time = (
                    f"identification failed: {err}",
                    time.monotonic(),
                )
            self.get_logger().error(f"identification failed: {err}")
        finally:
            with self._lock:
                self._busy = False

    def _warm(self, cfg: IdentConfig) -> None:
        try:
            seconds = warm_up(cfg)
            with self._lock:
                self._warm_up = f"{seconds:.4f}"
            self.get_logger().info(
                f"warm-up: one identification of {cfg.window_samples} samples took {seconds:.3f} s"
            )
        except Exception as err:  # only a speed-up: the node works without it
            with self._lock:
                self._warm_up = f"failed: {err}"
            self.get_logger().warning(f"warm-up identification failed: {err}")
        finally:
            with self._lock:
                self._busy = False

    @property
    def published(self) -> Published | None:
        """The latest estimate as published (None before the first)."""
        with self._lock:
            return self._published

    @property
    def last_estimate(self) -> Estimate | None:
        """The latest estimate (None before the first)."""
        p = self.published
        return p.estimate if p is not None else None

    @property
    def recording(self) -> NodeRecorder:
        """The node's recording of its inputs."""
        return self._recording

    @property
    def monitoring(self) -> PlantMonitoring | None:
        """The plant monitoring (None while unconfigured)."""
        return self._monitoring

    @property
    def active(self) -> bool:
        """Whether the node is active (subscribed, estimating)."""
        return self._active

    # -- diagnostics --------------------------------------------------------------------
    def diagnostic_status(self) -> DiagnosticStatus:
        """The node's status for /diagnostics: level, message, every counter."""
        fqn = self.get_fully_qualified_name()
        cfg, inputs = self.config, self.inputs
        if cfg is None or inputs is None:
            return unconfigured_status(fqn, self.configure_error, state_label(self))
        with self._lock:
            pub, err, err_t = self._published, self._last_error, self._last_error_time
            n_est, est_t, warm = self._estimates, self._last_estimate_wall, self._warm_up
        path = self._recording.path
        health = Health(
            now=time.monotonic(),
            config=cfg,
            stats=inputs.aligner.stats,
            span=inputs.aligner.span(),
            missing=inputs.aligner.missing(*inputs.aligner.span()),
            restarts=inputs.aligner.restarts,
            estimate=pub.estimate if pub is not None else None,
            estimates=n_est,
            estimate_wall=est_t,
            error=err,
            error_time=err_t,
            notes=list(self._notes),
            arrivals=list(inputs.arrivals),
            started=self._started,
            samples_in=inputs.samples_in,
            sources=inputs.sources,
            record_error=self._recording.error,
            recording=path.as_posix() if path is not None else "",
            warm_up=warm,
            clock=NO_CLOCK
            if self.get_parameter("use_sim_time").value and self.get_clock().now().nanoseconds == 0
            else "",
            active=self._active,
            qos_problems=dict(inputs.qos_problems),
        )
        return identification_status(health, fqn, fqn)

    def _publish_diagnostics(self) -> None:
        if self._pub_diag is None:
            return
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostic_status()]
        if self.config is None or self._monitoring is None:
            self._pub_diag.publish(msg)
            return
        stale = max(3.0 * self.config.update_period_s, self.config.stall_timeout_s)
        fqn = self.get_fully_qualified_name()
        plant = self._monitoring.status(fqn, fqn, stale)
        if plant is not None:
            msg.status.append(plant)
        self._pub_diag.publish(msg)

    def shutdown(self, timeout: float = JOIN_S) -> None:
        """Stop estimating, finalise the recording, then wait a bounded time for the workers.

        Idempotent (the threads are waited on once); any state. The MCAP is closed before
        any thread is waited on.
        """
        if self._stopping and self._recording.path is None and self._joined:
            return
        self._stopping = True
        self._active = False
        if self.inputs is not None and self.inputs.sources is not None:
            self.inputs.sources.close()
        self._recording.close()
        t = self._worker_thread
        if t is not None:
            t.join(timeout)
        if self._monitoring is not None:
            self._monitoring.shutdown(timeout)
        if self._srv is not None:
            self._srv.shutdown(timeout)
        self._joined = True
