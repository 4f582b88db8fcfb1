# SPDX-License-Identifier: Apache-2.0
"""The excitation publisher over DDS: `mr-ident excite --publish` drives the simulated loop
(`mr-ident-sim --reference-topic`), the node identifies it, and the labels that travel with
the samples cut the record back into realizations and periods.

Each test in its own domain (localhost only), every wait bounded.
"""

from __future__ import annotations

import subprocess
import threading

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
from rclpy.serialization import deserialize_message  # noqa: E402
from rosgraph import (  # noqa: E402
    PAPER,
    await_estimate_ending_at,
    child,
    domain_env,
    fast_params,
    venv_bin,
    wait_for,
)
from rosgraph import graph as graph  # noqa: E402  (the fixture)
from std_msgs.msg import Float64MultiArray  # noqa: E402

from mr_ident.io.modelfile import load_model  # noqa: E402
from mr_ident.live.sampling import grid_stamps  # noqa: E402
from mr_ident.numerics.excitation.bla import best_linear_approximation  # noqa: E402
from mr_ident.numerics.excitation.multisine import design  # noqa: E402
from mr_ident.numerics.excitation.schedule import LABELS, Schedule, realizations_of  # noqa: E402
from mr_ident.ros.excite_pub import index_topic, make_form, publish  # noqa: E402
from mr_ident.ros.messages import BLOCK_QOS, block_of  # noqa: E402

try:  # ros2_control's messages: a robot's stack has them; no wheel on the package index
    from control_msgs.msg import MultiDOFCommand
except ImportError:
    MultiDOFCommand = None
NO_CONTROL_MSGS = "control_msgs is not installed here (a ros2_control stack has it)"


class Blocks:
    """Every block received on a topic, joined by index into one array."""

    def __init__(self, node, topic: str):
        self.blocks: dict[int, np.ndarray] = {}
        node.create_subscription(Float64MultiArray, topic, self._on, BLOCK_QOS)

    def _on(self, msg):
        b = block_of(msg)
        self.blocks[b.first] = b.samples

    @property
    def samples(self) -> int:
        return sum(x.shape[0] for x in self.blocks.values())

    def array(self, n: int) -> np.ndarray:
        firsts = sorted(self.blocks)
        x = np.concatenate([self.blocks[f] for f in firsts])
        starts = np.concatenate([[f] * self.blocks[f].shape[0] for f in firsts])
        idx = starts + np.concatenate([np.arange(self.blocks[f].shape[0]) for f in firsts])
        assert np.array_equal(idx[:n], np.arange(n)), "a gap or a repeat in the stream"
        return x[:n]


def test_published_multisine_drives_the_sim_and_the_node_estimates_the_exact_plant(graph):
    """`mr-ident excite --publish reference` (block contract, 10x real time) streams a full
    multisine (2 realizations x 3 periods of 10 s, 240 Hz); `mr-ident-sim --reference-topic
    reference` closes the paper's loop on it and publishes u and y at its indices; the node
    identifies from the publisher's r and the sim's u, y. Its estimate of the last 10 s window
    (one steady-state period) equals the exact P_h: median relative error < 2e-4, max < 2e-2
    (measured offline on the same data: 5.8e-5 and 8.0e-3, the LPM's smoothing at the
    resonances). Every sample's labels are the schedule's, r is the design's, and the BLA of
    the record cut by its labels (first period of each realization dropped) is P_h to 1e-9.
    A second node with excitation_index_topic = reference/excitation_index (window 30 s)
    aligns the labels with r, u, y and identifies its last window, realization 1's three
    periods, as the BLA from the two after the transient: P_h to 1e-9 at every line, the
    same numbers as the record's BLA above, published on its plant_frf topics (on the
    publish grid of its lines) and described on /diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray

    from mr_ident.live.estimate import publish_grid
    from mr_ident.ros.messages import RESULT_QOS, frf_of

    N, P, M, fs = 2400, 3, 2, 240.0
    total = N * P * M
    model = load_model(PAPER)
    node = graph.ident(fast_params(window_s=10.0))
    periodic = fast_params(
        window_s=30.0, excitation_index_topic=index_topic("reference"), legacy_array_topics=True
    )
    bla_node = graph.ident(periodic, name="mr_ident_bla")
    lis = graph.node("listener")
    got: dict[str, object] = {}
    for name in ("frequencies", "plant_frf"):
        lis.create_subscription(
            Float64MultiArray, f"/mr_ident_bla/{name}",
            lambda m, name=name: got.__setitem__(name, m), RESULT_QOS,
        )  # fmt: skip
    status: list = []
    lis.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: status.extend(s for s in m.status if s.name == "/mr_ident_bla: identification"),
        10,
    )  # fmt: skip
    streams = {
        t: Blocks(lis, t)
        for t in ("reference", index_topic("reference"), "input", "output")  # r, labels, u, y
    }
    with child(
        graph,
        "mr-ident-sim",
        str(PAPER),
        "--reference-topic",
        "reference",
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    ) as sim:
        wait_for(lambda: lis.count_publishers("output") > 0, 30, "the sim's publishers")
        proc = subprocess.run(
            [
                venv_bin("mr-ident"),
                "excite",
                *("--fs-high", "240", "--band", "0,120", "--kind", "full", "--seed", "1"),
                *("--period", str(N), "--periods", str(P), "--realizations", str(M)),
                *("--publish", "reference", "--rate", "10", "--subscribers", "4", "--wait", "20"),
            ],
            env=domain_env(graph.domain),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        assert f"published {total} samples" in proc.stdout, proc.stdout
        wait_for(lambda: all(s.samples >= total for s in streams.values()), 30, "every sample")
        await_estimate_ending_at(node, total)
        await_estimate_ending_at(
            bla_node, total, what="the periodic node's estimate of the final window"
        )
        assert sim.poll() is None, sim.stdout.read() if sim.stdout else ""
    est = node.last_estimate
    assert est.n_samples == N and all(s.gaps == 0 for s in node.inputs.aligner.stats.values())
    plant = est.identification.plant
    Ptrue = model.plant_discrete().freqresp(plant.frequency)
    rel = np.abs(plant.response - Ptrue) / np.abs(Ptrue)
    assert np.median(rel) < 2e-4 and rel.max() < 2e-2, (np.median(rel), rel.max())

    ms = design(
        fs_high=fs, period=N, band=(0, 120), kind="full", periods=P, realizations=M, seed=1
    )
    sched = Schedule.of(ms.r, N)
    r, lab, u, y = (s.array(total) for s in streams.values())
    np.testing.assert_array_equal(r, sched.take(ms.r, 0, total))
    np.testing.assert_array_equal(lab, sched.labels(0, total).astype(float))
    pos = realizations_of(lab.astype(np.int64), N, transient=1)
    assert pos.shape == (M, (P - 1) * N)
    bla = best_linear_approximation(r[pos][..., 0], u[pos][..., 0], y[pos][..., 0], N)
    Pl = model.plant_discrete().freqresp(bla.lines * fs / N)[:, 0, 0]
    assert np.max(np.abs(bla.response - Pl) / np.abs(Pl)) < 1e-9

    live = bla_node.last_estimate  # the node's BLA of its last window
    assert live.bla is not None and live.n_samples == P * N, live.periodic
    assert live.periodic.startswith(f"BLA from 1 realization(s) x {P - 1} period(s) of {N}")
    assert all(st.gaps == 0 for st in bla_node.inputs.aligner.stats.values())
    assert "excitation_index" in bla_node.inputs.aligner.stats
    Pb = model.plant_discrete().freqresp(live.bla.lines * fs / N)[:, 0, 0]
    assert np.max(np.abs(live.bla.response - Pb) / np.abs(Pb)) < 1e-9
    last = slice(-(P - 1) * N, None)  # realization 1 after its transient: the record's too
    want = best_linear_approximation(r[last, 0], u[last, 0], y[last, 0], N)
    np.testing.assert_allclose(live.bla.response, want.response, rtol=1e-12)
    picks = publish_grid(live.bla.lines.size, bla_node.config.publish_points)

    def published() -> bool:
        if "plant_frf" not in got or "frequencies" not in got:
            return False
        P_pub = frf_of(got["plant_frf"])[:, 0, 0]
        f_pub = np.frombuffer(got["frequencies"].data)
        return (
            P_pub.shape == f_pub.shape == picks.shape
            and np.allclose(P_pub, live.bla.response[picks], rtol=1e-12, atol=0)
            and np.allclose(f_pub, live.bla.lines[picks] * fs / N, rtol=1e-12, atol=0)
        )

    wait_for(published, 10, "the published BLA of the final window")
    wait_for(
        lambda: any(
            kv.key == "bla_periods" and kv.value == str(P - 1) for s in status for kv in s.values
        ),
        10,
        "the BLA on /diagnostics",
    )


def _play(pub_node, r, fs, period, form, loops=1):
    """Stream ``r`` on /cmd (joints a, b) from ``pub_node`` at twice real time; what went out."""
    played = []
    th = threading.Thread(
        target=lambda: played.append(
            publish(
                pub_node,
                "/cmd",
                r,
                fs_high=fs,
                period=period,
                form=form,
                joints=["a", "b"],
                rate=2.0,
                loops=loops,
                wait=10.0,
            )  # fmt: skip
        ),
        daemon=True,
    )
    th.start()
    th.join(30)
    assert not th.is_alive(), "the publisher did not finish"
    return played[0]


@pytest.mark.parametrize(
    "form",
    [
        "jointstate",
        "float64multiarray",
        pytest.param(
            "multidofcommand",
            marks=pytest.mark.skipif(MultiDOFCommand is None, reason=NO_CONTROL_MSGS),
        ),
    ],
)
def test_per_sample_forms_carry_the_values_stamps_from_the_index_and_the_labels(graph, form):
    """JointState (a position per joint, header.stamp t0 + i/fs_high exactly) and the
    forward_command_controller command (data per joint, no stamp): one message per sample,
    in order, the design's values; on TOPIC/excitation_index the same form with the labels
    (JointState: the same stamps). The messages are serialized from a template with the
    numbers written in: they decode with rclpy as messages built field by field would."""
    fs, N, P, M = 240.0, 24, 2, 2
    ms = design(fs_high=fs, period=N, band=(1, 100), kind="full", periods=P, realizations=M)
    r = np.concatenate([ms.r, -ms.r], axis=2)  # two joints
    total = N * P * M
    cls = {"jointstate": sensor_msgs.JointState, "multidofcommand": MultiDOFCommand}.get(
        form, Float64MultiArray
    )
    got: dict[str, list] = {"sig": [], "idx": []}
    lis = graph.node("listener")
    for key, topic in (("sig", "/cmd"), ("idx", index_topic("/cmd"))):
        lis.create_subscription(
            cls, topic, lambda m, key=key: got[key].append(m), BLOCK_QOS, raw=True
        )
    pub_node = rclpy.create_node("excite", context=graph.ctx)
    try:
        played = [_play(pub_node, r, fs, N, form)]
        wait_for(
            lambda: len(got["sig"]) >= total and len(got["idx"]) >= total, 10, "every message"
        )
    finally:
        pub_node.destroy_node()
    assert played[0].samples == total and played[0].messages == total
    sig = [deserialize_message(m, cls) for m in got["sig"]]
    idx = [deserialize_message(m, cls) for m in got["idx"]]
    sched = Schedule.of(r, N)
    if form == "jointstate":
        values = np.array([m.position for m in sig])
        labels = np.array([m.position for m in idx])
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in sig])
        istamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in idx])
        np.testing.assert_array_equal(stamps, grid_stamps(played[0].t0, 0, total, fs))
        np.testing.assert_array_equal(istamps, stamps)
        assert all(list(m.name) == ["a", "b"] for m in sig)
        assert all(list(m.name) == list(LABELS) for m in idx)
    elif form == "multidofcommand":  # pid_controller's setpoint: values, values_dot NaN
        values = np.array([m.values for m in sig])
        labels = np.array([m.values for m in idx])
        assert all(list(m.dof_names) == ["a", "b"] and np.isnan(m.values_dot).all() for m in sig)
    else:
        values = np.array([m.data for m in sig])
        labels = np.array([m.data for m in idx])
    np.testing.assert_array_equal(values, sched.take(r, 0, total))
    np.testing.assert_array_equal(labels, sched.labels(0, total))
    # the template's bytes are those rclpy serializes for the message built field by field
    from rclpy.serialization import serialize_message

    fm = make_form(form, ["a", "b"])
    stamp = grid_stamps(7, 5, 1, fs)
    one = fm.signal.encode(values[5:6], stamp)[0]
    ref = cls()
    if form == "jointstate":
        ref.name, ref.position = ["a", "b"], [float(v) for v in values[5]]
        ref.header.stamp.sec, ref.header.stamp.nanosec = divmod(int(stamp[0]), 10**9)
    elif form == "multidofcommand":
        ref.dof_names, ref.values = ["a", "b"], [float(v) for v in values[5]]
        ref.values_dot = [float("nan")] * 2
    else:
        ref.data = [float(v) for v in values[5]]
    assert one == bytes(serialize_message(ref))


def test_the_node_reads_the_labels_in_the_joint_state_form_with_its_sources(graph):
    """Per-sample sources: the publisher streams two joints (a, and b = -a) as JointState
    with the labels as JointState on /cmd/excitation_index (the same stamps); a node with
    r and u from joint a, y from joint b and excitation_index_topic /cmd/excitation_index
    reads the labels in that form (three sources by name), aligns them by stamp and
    identifies its last window (2 realizations x 2 periods; each run's first dropped) as the
    BLA of y = -u: -1 at every line, exactly."""
    from rclpy.parameter import Parameter

    fs, N, P, M = 240.0, 24, 2, 2
    ms = design(fs_high=fs, period=N, band=(1, 100), kind="full", periods=P, realizations=M)
    r = np.concatenate([ms.r, -ms.r], axis=2)
    cycle = N * P * M
    params = [
        Parameter(k, value=v)
        for k, v in dict(
            fs_high=fs, ratio=1, method="etfe", window_s=cycle / fs, min_window_s=cycle / fs,
            update_period_s=0.2, r_source=['/cmd.position{name=="a"}'],
            u_source=['/cmd.position{name=="a"}'], y_source=['/cmd.position{name=="b"}'],
            excitation_index_topic="/cmd/excitation_index",
        ).items()
    ]  # fmt: skip
    node = graph.ident(params)
    pub_node = rclpy.create_node("excite", context=graph.ctx)
    try:
        assert _play(pub_node, r, fs, N, "jointstate", loops=2).samples == 2 * cycle

        def final():
            est = node.last_estimate
            return est is not None and est.first + est.n_samples == 2 * cycle and est

        est = wait_for(final, 15, "the node's estimate of the last window")
    finally:
        pub_node.destroy_node()
    assert est.bla is not None, est.periodic
    assert (est.bla.realizations, est.bla.periods) == (M, P - 1), est.periodic
    np.testing.assert_allclose(est.bla.response, -1.0, rtol=0, atol=1e-12)
    assert set(node.inputs.aligner.stats) == {"reference", "input", "output", "excitation_index"}


def test_the_publisher_is_started_and_stopped_from_the_graph(graph):
    """``--paused``: nothing goes out until ~/start (std_srvs/Trigger); then blocks, and the
    status '<node>: excitation' on /diagnostics says publishing, with realization and period;
    after ~/stop no more samples, the status says stopped."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger

    from mr_ident.ros.program import Stop

    ms = design(fs_high=240.0, period=240, band=(1, 100), kind="full", periods=2, realizations=2)
    pub_node = rclpy.create_node("excite", context=graph.ctx)
    lis = graph.node("listener")
    got, status = Blocks(lis, "/cmd"), []
    lis.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: status.extend(m.status), 10
    )  # fmt: skip
    stop = Stop()
    run = dict(fs_high=240.0, period=240, rate=10.0, loops=0, wait=0.0, stop=stop, paused=True)
    th = threading.Thread(target=publish, args=(pub_node, "/cmd", ms.r), kwargs=run, daemon=True)
    th.start()

    def call(name: str):
        cli = lis.create_client(Trigger, f"/excite/{name}")
        assert cli.wait_for_service(timeout_sec=10), name
        future = cli.call_async(Trigger.Request())
        wait_for(future.done, 10, f"the response of ~/{name}")
        return future.result()

    def said(text: str):
        return lambda: any(s.name == "/excite: excitation" and text in s.message for s in status)

    try:
        wait_for(said("stopped"), 10, "the status: stopped")
        assert got.samples == 0
        assert call("start").success
        wait_for(lambda: got.samples > 2400, 20, "samples after ~/start")
        wait_for(said("publishing: realization"), 10, "the status: publishing")
        assert call("stop").success
        status.clear()
        wait_for(said("stopped"), 10, "the status: stopped again")
        n = got.samples
        threading.Event().wait(0.5)
        assert got.samples == n
    finally:
        stop.request()
        th.join(10)
        pub_node.destroy_node()


@pytest.mark.skipif(MultiDOFCommand is not None, reason="control_msgs is installed here")
def test_the_pid_controllers_setpoint_form_says_what_it_needs_where_control_msgs_is_absent():
    from mr_ident.errors import ConfigError

    with pytest.raises(ConfigError, match="cannot import control_msgs: source the ROS 2"):
        make_form("multidofcommand", ["j1"])


def test_a_multidof_setpoint_leaves_its_derivative_uncommanded():
    from types import SimpleNamespace

    from mr_ident.ros.excite_pub import multidof_values

    msg = SimpleNamespace(values=[], values_dot=[])
    multidof_values(msg, [0.5, -1.0])
    assert (
        msg.values == [0.5, -1.0] and np.isnan(msg.values_dot).all() and len(msg.values_dot) == 2
    )
