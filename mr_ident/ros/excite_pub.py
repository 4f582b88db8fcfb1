# SPDX-License-Identifier: Apache-2.0
"""``mr-ident excite --publish TOPIC``: stream an excitation design on a topic at fs_high.

The design (M realizations of P periods of N samples, ``mr-ident excite``) is played
realization after realization and looped
(:class:`~mr_ident.numerics.excitation.schedule.Schedule`),
on a timer: each tick publishes the samples that are due by then, so the stream keeps
fs_high × ``rate`` on average whatever the timer's jitter. Sample index i counts from
the first sample published; its stamp is ``t0 + round(i / fs_high)`` (t0 the node's
clock at the start), computed from the index, never read off the wall clock per message
(:func:`~mr_ident.live.sampling.grid_stamps`). Three forms (``--as``):

``block``
    The block contract (``std_msgs/Float64MultiArray``, data[0] the index): one message
    per tick. What ``mr-ident-node`` and ``mr-ident-sim --reference-topic`` read.
``jointstate``
    ``sensor_msgs/JointState``, one message per sample: ``header.stamp`` the sample's
    stamp, ``name`` the joints (``--joint``, one per input), ``position`` the values.
``float64multiarray``
    ``std_msgs/Float64MultiArray``, one message per sample, ``data`` one value per joint:
    the command of ros2_control's ``forward_command_controller`` (``~/commands``). It has
    no stamp: the controller applies the latest command at its update, so publish at
    ``--tick`` one sample (the default for this form).
``multidofcommand``
    ``control_msgs/MultiDOFCommand``, one message per sample: ``dof_names`` the joints,
    ``values`` the values, ``values_dot`` NaN (not commanded): the setpoint of
    ros2_controllers' ``pid_controller`` (``~/reference``), which takes the latest message
    at its update (its subscription keeps one, best effort). Needs control_msgs (a
    ros2_control stack has it). Play a design at the controller's rate, one sample a tick.

Beside the signal, on ``TOPIC/excitation_index``, the same form carries each sample's
labels (realization, period, sample of the period;
:data:`~mr_ident.numerics.excitation.schedule.LABELS`):
a block of 3 channels at the same index; a JointState with the same stamp, names
``realization``, ``period``, ``sample`` in ``position``; a Float64MultiArray
``[realization, period, sample]`` after each command. A recording of both topics can be
cut back into realizations and periods
(:func:`~mr_ident.numerics.excitation.schedule.realizations_of`) with the sources the signal itself
is read with (e.g. ``TOPIC/excitation_index.position{name=="realization"}``).

Per-sample forms are serialized many at once: one message of the layout is serialized
by rclpy, the bytes of its stamp and values located, and every message of a tick is that
template with its numbers written in (numpy), published as raw bytes.
"""

from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..io.labels import index_topic
from ..live.sampling import grid_stamps
from ..numerics.arrays import FloatArray, IntArray
from ..numerics.catalog import EXCITATION_FORMS
from ..numerics.excitation.schedule import LABELS, Schedule
from .program import Stop, spin_until_stopped

#: The message forms of ``--as``.
FORMS = EXCITATION_FORMS


class RawTemplate:
    """Serialized messages of one layout, many at once, with their numbers patched in.

    ``msg`` is a message of the layout (arrays already of their final length) whose
    ``n_values`` doubles (``values_of(msg)``'s list) and, if ``stamped``,
    ``header.stamp`` are written per message; everything else is copied.
    """

    def __init__(self, msg: Any, n_values: int, set_values: Any, stamped: bool) -> None:
        from rclpy.serialization import serialize_message

        marks = [-(1.0 + i) * 2.0**-1000 for i in range(n_values)]  # unlikely bytes
        set_values(msg, marks)
        if stamped:
            msg.header.stamp.sec, msg.header.stamp.nanosec = 0x5EC05EC0, 0x3A5EC0DE
        raw = bytes(serialize_message(msg))
        self.template = np.frombuffer(raw, np.uint8)
        self.values = [self._find(raw, struct.pack("<d", v)) for v in marks]
        self.sec = self._find(raw, struct.pack("<i", 0x5EC05EC0)) if stamped else -1
        self.nanosec = self._find(raw, struct.pack("<I", 0x3A5EC0DE)) if stamped else -1

    @staticmethod
    def _find(raw: bytes, mark: bytes) -> int:
        at = raw.find(mark)
        if at < 0 or raw.find(mark, at + 1) >= 0:
            raise ConfigError(f"cannot place a value in the serialized message ({mark.hex()})")
        return at

    def encode(self, values: FloatArray, stamps: IntArray | None = None) -> list[bytes]:
        """One payload per row of ``values`` (n, n_values), with ``stamps`` (n,) in ns."""
        n = values.shape[0]
        L = self.template.size
        buf = np.empty((n, L), np.uint8)
        buf[:] = self.template
        v = np.ascontiguousarray(values, dtype="<f8").view(np.uint8).reshape(n, -1, 8)
        for j, at in enumerate(self.values):
            buf[:, at : at + 8] = v[:, j]
        if stamps is not None and self.sec >= 0:
            sec, ns = np.divmod(np.asarray(stamps, np.int64), 1_000_000_000)
            buf[:, self.sec : self.sec + 4] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
            buf[:, self.nanosec : self.nanosec + 4] = ns.astype("<u4").view(np.uint8).reshape(n, 4)
        raw = buf.tobytes()
        return [raw[i * L : (i + 1) * L] for i in range(n)]


@dataclass(frozen=True)
class Form:
    """How one tick's samples become messages of a form, on the signal and index topics."""

    name: str
    msg_type: Any
    per_sample: bool
    signal: RawTemplate | None = None
    index: RawTemplate | None = None

    def messages(
        self, first: int, r: FloatArray, labels: IntArray, stamps: IntArray
    ) -> tuple[list[Any], list[Any]]:
        """(signal messages, index messages) of samples ``first ..`` (r (n, n_in))."""
        if self.signal is None or self.index is None:
            from .messages import block_msg

            return [block_msg(first, r)], [block_msg(first, labels.astype(float))]
        return (
            self.signal.encode(r, stamps),
            self.index.encode(labels.astype(float), stamps),
        )


def make_form(name: str, joints: list[str]) -> Form:
    """The :class:`Form` ``name`` for inputs named ``joints``."""
    if name == "block":
        from std_msgs.msg import Float64MultiArray

        return Form(name, Float64MultiArray, per_sample=False)
    if name == "jointstate":
        from sensor_msgs.msg import JointState

        def js(names: list[str]) -> RawTemplate:
            def put(m: Any, v: list[float]) -> None:
                m.position = v

            return RawTemplate(JointState(name=list(names)), len(names), put, stamped=True)

        return Form(name, JointState, True, js(joints), js(list(LABELS)))
    if name == "float64multiarray":
        from std_msgs.msg import Float64MultiArray

        def fa(n: int) -> RawTemplate:
            def put(m: Any, v: list[float]) -> None:
                m.data = v

            return RawTemplate(Float64MultiArray(), n, put, stamped=False)

        return Form(name, Float64MultiArray, True, fa(len(joints)), fa(len(LABELS)))
    if name == "multidofcommand":
        command = _multidof_type()

        def md(names: list[str]) -> RawTemplate:
            nan = [math.nan] * len(names)
            msg = command(dof_names=list(names), values=nan, values_dot=nan)
            return RawTemplate(msg, len(names), multidof_values, stamped=False)

        return Form(name, command, True, md(joints), md(list(LABELS)))
    raise ConfigError(f"--as must be one of {', '.join(FORMS)}, got {name!r}")


def multidof_values(msg: Any, values: list[float]) -> None:
    """A MultiDOFCommand's ``values`` (its ``values_dot`` NaN: not commanded)."""
    msg.values = list(values)
    msg.values_dot = [math.nan] * len(values)


def _multidof_type() -> Any:
    """control_msgs' MultiDOFCommand, or a ConfigError naming the package to install."""
    try:
        from control_msgs.msg import MultiDOFCommand
    except ImportError:
        raise ConfigError(
            "--as multidofcommand publishes control_msgs/MultiDOFCommand (pid_controller's "
            "~/reference), and this Python cannot import control_msgs: source the ROS 2 "
            "installation of the ros2_control stack (apt: ros-jazzy-control-msgs)"
        ) from None
    return MultiDOFCommand


@dataclass(frozen=True)
class Played:
    """What a run published: samples, messages per topic, ticks, its stamp origin (ns)."""

    samples: int
    messages: int
    ticks: int
    t0: int
    late_ticks: int


def publish(
    node: Any,
    topic: str,
    r: FloatArray,
    *,
    fs_high: float,
    period: int,
    form: str = "block",
    joints: list[str] | None = None,
    rate: float = 1.0,
    loops: int = 1,
    tick: float | None = None,
    block: int = 1000,
    wait: float = 5.0,
    subscribers: int = 1,
    stop: Stop | None = None,
    paused: bool = False,
) -> Played:
    """Stream the design ``r`` (M, P·N, n_in) on ``topic`` (module docstring) from ``node``.

    Parameters
    ----------
    rate : float
        Times real time (stamps stay on the fs_high grid: loop time).
    loops : int
        Times through every realization and period; 0: until ``stop``.
    tick : float or None
        Timer period in s of wall time; default one sample for the per-sample forms (at
        least 1 ms), else 10 ms.
    block : int
        Most samples per block message (``form`` "block").
    wait, subscribers :
        Wait up to ``wait`` s for ``subscribers`` on the signal topic before the first
        sample (then 0.5 s more: matching is not symmetric).
    paused : bool
        Start stopped: nothing goes out before a call of ``~/start``
        (:mod:`~mr_ident.ros.excite_control`: ``~/start``, ``~/stop``, the status on
        /diagnostics).

    Returns
    -------
    Played
        What went out: samples, messages per topic, ticks, the stamp origin, late ticks.

    Raises
    ------
    ConfigError
        ``r`` not (M, P·N, n_in) with ``period`` N dividing P·N, ``joints`` not one per
        input, an option out of range, or an unknown ``form``.

    Notes
    -----
    The steps: check the options, advertise both topics and wait for their readers, play
    on a timer (``_Player``) until done or stopped, wait for the readers' acks.
    """
    from rclpy.duration import Duration

    from .excite_control import ExciteControl
    from .messages import BLOCK_QOS

    sched = Schedule.of(r, period)
    joints = _checked(r, joints, rate=rate, loops=loops, block=block, tick=tick)
    fm = make_form(form, joints)
    if tick is None:
        tick = max(1.0 / (fs_high * rate), 1e-3) if fm.per_sample else 0.01
    stop = stop if stop is not None else Stop()
    control = ExciteControl(node, topic, running=not paused)
    sig = node.create_publisher(fm.msg_type, topic, BLOCK_QOS)
    idx = node.create_publisher(fm.msg_type, index_topic(topic), BLOCK_QOS)
    _await_subscribers(sig, wait, subscribers, stop)
    player = _Player(
        schedule=sched,
        r=r,
        form=fm,
        topics=(sig, idx),
        control=control,
        stop=stop,
        fs_high=fs_high,
        rate=rate,
        tick=tick,
        block=block,
        total=None if loops == 0 else loops * sched.cycle,
        t0=node.get_clock().now().nanoseconds,
        start=time.monotonic(),
    )
    _spin(node, tick, player, stop, control)
    for pub in (sig, idx):  # reliable delivery: do not exit before the readers have it
        pub.wait_for_all_acked(Duration(seconds=1 if stop.signal is not None else 5))
    return Played(
        samples=player.next_index,
        messages=player.messages,
        ticks=player.ticks,
        t0=player.t0,
        late_ticks=player.late,
    )


def _checked(
    r: FloatArray,
    joints: list[str] | None,
    *,
    rate: float,
    loops: int,
    block: int,
    tick: float | None,
) -> list[str]:
    """The joints' names (``j0`` ... by default), the options checked."""
    n_in = r.shape[2]
    joints = list(joints) if joints else [f"j{i}" for i in range(n_in)]
    if len(joints) != n_in:
        raise ConfigError(f"--joint must name {n_in} joint(s), one per input, got {joints}")
    for name, value, ok in (
        ("--rate", rate, rate > 0 and math.isfinite(rate)),
        ("--loops", loops, loops >= 0),
        ("--block", block, block >= 1),
        ("--tick", tick, tick is None or (tick > 0 and math.isfinite(tick))),
    ):
        if not ok:
            raise ConfigError(f"{name} must be positive, got {value!r}")
    return joints


def _await_subscribers(pub: Any, wait: float, subscribers: int, stop: Stop) -> None:
    """Wait up to ``wait`` s for ``subscribers`` on ``pub``, then 0.5 s more (matching)."""
    deadline = time.monotonic() + wait
    while (
        time.monotonic() < deadline
        and not stop.requested
        and pub.get_subscription_count() < subscribers
    ):
        stop.wait(0.02)
    if wait > 0:
        stop.wait(min(wait, 0.5))


@dataclass
class _Player:
    """The stream's progress, advanced by the timer: every tick sends the samples due."""

    schedule: Schedule
    r: FloatArray
    form: Form
    topics: tuple[Any, Any]  # the signal's publisher and the labels'
    control: Any  # the ExciteControl: running, sent, labels, done
    stop: Stop
    fs_high: float
    rate: float  # times real time
    tick: float
    block: int
    total: int | None  # samples to send (None: until stopped)
    t0: int  # the stamp of sample 0 (ns)
    start: float  # time.monotonic() at sample 0
    next_index: int = 0
    messages: int = 0
    ticks: int = 0
    late: int = 0  # ticks that found more than two ticks' samples due

    def __call__(self) -> None:
        """One tick: the samples due by now sent (dropped while stopped from the graph)."""
        due = int((time.monotonic() - self.start) * self.fs_high * self.rate) + 1
        if self.total is not None:
            due = min(due, self.total)
        self.ticks += 1
        if not self.control.running:  # stopped from the graph: the due samples are not sent
            self.next_index = due
        else:
            if due - self.next_index > max(2, int(2 * self.tick * self.fs_high * self.rate)):
                self.late += 1  # the timer fell behind by more than a tick: a burst
            self.next_index = self._send(self.next_index, due)
        if self.total is not None and self.next_index >= self.total:
            self.control.done = True
            self.stop.request()

    def _send(self, first: int, due: int) -> int:
        """Samples ``first .. due - 1`` published (in blocks of ``block`` for that form)."""
        sig, idx = self.topics
        while first < due:
            n = min(due - first, self.block) if not self.form.per_sample else due - first
            x = self.schedule.take(self.r, first, n)
            labels = self.schedule.labels(first, n)
            stamps = grid_stamps(self.t0, first, n, self.fs_high)
            msgs, index = self.form.messages(first, x, labels, stamps)
            for m, k in zip(msgs, index, strict=True):
                sig.publish(m)
                idx.publish(k)
            self.messages += len(msgs)
            first += n
            self.control.sent += n
            self.control.labels = tuple(int(v) for v in labels[-1])
        return first


def _spin(node: Any, tick: float, on_tick: _Player, stop: Stop, control: Any) -> None:
    """Run ``on_tick`` every ``tick`` s on the node's own executor until ``stop``."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    timer = node.create_timer(tick, on_tick)
    try:
        spin_until_stopped(executor, node, stop)
    finally:
        timer.cancel()
        node.destroy_timer(timer)
        control.destroy()
        executor.remove_node(node)
