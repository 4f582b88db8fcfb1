# SPDX-License-Identifier: Apache-2.0
"""The interface package mr_ident_msgs: built from this repository's files, its messages
round-trip through CDR, and an Estimate crosses DDS from one process to another."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, domain_env

pytest.importorskip("rclpy")
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rosgraph import graph as graph  # noqa: E402  (the fixture)
from rosgraph import wait_for  # noqa: E402

from mr_ident_msgs.msg import Estimate, Summary  # noqa: E402
from mr_ident_msgs.srv import Diagnose, Record, SaveEstimate  # noqa: E402

SOURCES = ROOT / "mr_ident_msgs"


def filled_estimate() -> Estimate:
    """An Estimate with every field set: K = 5 bins of a 2 x 1 plant."""
    rng = np.random.default_rng(7)
    K, n_out, n_in = 5, 2, 1
    m = Estimate()
    m.header.stamp.sec, m.header.stamp.nanosec = 1234, 500_000_000
    m.header.frame_id = "loop_1"
    m.window_first, m.window_last, m.missing_samples = 2**40, 2**40 + 99_999, 3
    m.fs_high, m.ratio = 1000.0, 4
    m.method, m.local_model = "freq-lifted", "polynomial"
    m.n_out, m.n_in = n_out, n_in
    m.frequency = np.linspace(1.0, 5.0, K)
    for name in ("response_real", "response_imag", "response_std"):
        setattr(m, name, rng.standard_normal(K * n_out * n_in))
    m.halfwidth = np.array([0, 3, 4, 8, 8], dtype=np.uint32)
    for name in ("pfg", "pfg_std", "pfg_data", "pfg_data_std"):
        setattr(m, name, rng.random(K))
    return m


def test_the_installed_interfaces_are_this_repositorys():
    """The build the tests run against is of these files, not a stale one."""
    import mr_ident_msgs

    share = Path(mr_ident_msgs.__file__).resolve().parents[4] / "share" / "mr_ident_msgs"
    for src in [*SOURCES.glob("msg/*.msg"), *SOURCES.glob("srv/*.srv")]:
        built = share / src.parent.name / src.name
        assert built.is_file(), f"{built} missing: make rebuilds mr_ident_msgs"
        assert built.read_text() == src.read_text(), f"{built} is stale: make rebuilds it"


def test_an_estimate_round_trips_through_cdr():
    m = filled_estimate()
    back = deserialize_message(serialize_message(m), Estimate)
    assert back == m
    assert back.window_first == 2**40 and back.header.frame_id == "loop_1"
    K, n_out, n_in = len(back.frequency), back.n_out, back.n_in
    P = (np.asarray(back.response_real) + 1j * np.asarray(back.response_imag)).reshape(
        K, n_out, n_in
    )
    expected = np.asarray(m.response_real) + 1j * np.asarray(m.response_imag)
    np.testing.assert_array_equal(P, expected.reshape(K, n_out, n_in))
    np.testing.assert_array_equal(back.halfwidth, [0, 3, 4, 8, 8])


def test_a_summary_keeps_nan_for_what_is_unavailable():
    s = Summary(window_last=7, pfg_peak=1.5, drift_max_sigma=float("nan"))
    back = deserialize_message(serialize_message(s), Summary)
    assert back.window_last == 7 and back.pfg_peak == 1.5 and np.isnan(back.drift_max_sigma)


@pytest.mark.parametrize("srv", [SaveEstimate, Diagnose, Record])
def test_every_service_answers_with_success_and_a_message(srv):
    response = srv.Response(success=True, message="ok")
    back = deserialize_message(serialize_message(response), srv.Response)
    assert back.success and back.message == "ok"


TALKER = """
import sys, time
import rclpy
from rclpy.duration import Duration
from rclpy.serialization import deserialize_message
from mr_ident_msgs.msg import Estimate

msg = deserialize_message(bytes.fromhex(sys.stdin.read()), Estimate)
rclpy.init()
node = rclpy.create_node("estimate_talker")
pub = node.create_publisher(Estimate, "/test_msgs/estimate", 10)
t0 = time.monotonic()
while pub.get_subscription_count() == 0:
    if time.monotonic() - t0 > 20:
        sys.exit("no subscriber within 20 s")
    time.sleep(0.05)
time.sleep(0.5)  # matching is not symmetric: let the subscriber match this writer too
pub.publish(msg)
pub.wait_for_all_acked(Duration(seconds=10))
node.destroy_node()
rclpy.shutdown()
"""


def test_an_estimate_crosses_dds_between_two_processes(graph):
    got: list[Estimate] = []
    listener = graph.node("estimate_listener")
    listener.create_subscription(Estimate, "/test_msgs/estimate", got.append, 10)
    sent = filled_estimate()
    proc = subprocess.run(
        [sys.executable, "-c", TALKER],
        input=serialize_message(sent).hex(),
        env=domain_env(graph.domain),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    wait_for(lambda: got, 10.0, "the Estimate from the other process")
    assert got[0] == sent
