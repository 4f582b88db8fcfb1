# SPDX-License-Identifier: Apache-2.0
"""What the node says is so: Estimate.missing_samples is its window's missing count, block
inputs take sensor-data publishers and name an incompatible QoS on /diagnostics, the node
runs without its one pip-only import (threadpoolctl), and every benchmark and script
listens to the node's current interface.

Own domain, localhost only, every wait bounded (test/rosgraph.py).
"""

from __future__ import annotations

import os
import re
import subprocess

import pytest
from conftest import ROOT, domain_env

pytest.importorskip("rclpy")
pytest.importorskip("mr_ident_msgs", reason="mr_ident_msgs is not built (make venv builds it)")
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from rosgraph import (  # noqa: E402
    PAPER,
    Feed,
    Listener,
    await_subscribers,
    fast_params,
    publish_sim,
    publishers,
    venv_bin,
    wait_for,
)
from rosgraph import graph as graph  # noqa: E402  (the fixture)
from std_msgs.msg import Float64MultiArray  # noqa: E402

from mr_ident.io.modelfile import load_model  # noqa: E402


def test_missing_samples_is_the_windows_missing_count(graph):
    """One input block of 60 samples never arrives (a 10 s window bridges it): the estimate
    of every window holding the hole says 60 missing samples, the others 0."""
    node = graph.ident(fast_params(window_s=10.0))
    lis = Listener(graph)
    sent = publish_sim(publishers(graph), load_model(PAPER), 12.0, skip=(1, 20), block=60)
    hole = range(sent[20][0], sent[20][0] + 60)
    end = sent[-1][0] + 59
    wait_for(
        lambda: lis.estimates and lis.estimates[-1].window_last == end, 30, "the final window"
    )
    assert node.inputs.aligner.stats["input"].bridged_samples == 60
    for m in lis.estimates:
        holds = m.window_first <= hole[0] and hole[-1] <= m.window_last
        assert m.missing_samples == (60 if holds else 0), (m.window_first, m.window_last)
    assert any(m.missing_samples == 60 for m in lis.estimates)


def _sensor_publishers(n):
    return [
        n.create_publisher(Float64MultiArray, t, qos_profile_sensor_data)
        for t in ("reference", "input", "output")
    ]


def test_a_sensor_data_publisher_feeds_the_node_before_or_after_it_subscribes(graph):
    """Best-effort (sensor data) publishers present at activation: subscribed best effort,
    estimates come. A best-effort publisher that comes later: /diagnostics names the
    incompatible QoS (RELIABILITY), the node subscribes again best effort, estimates come."""
    model = load_model(PAPER)
    early = graph.node("sensor_blocks")
    pubs = _sensor_publishers(early)
    node = graph.ident(fast_params(window_s=5.0))
    lis = Listener(graph)
    await_subscribers(pubs)
    Feed(pubs, model, seed=3, block=240).send(30, pause=0.02)
    wait_for(lambda: lis.estimates, 30, "an estimate from sensor-data publishers")
    assert node.inputs.qos_problems == {}

    for pub in pubs:  # gone from the graph: the next activation finds no publisher
        early.destroy_publisher(pub)
    names = ("reference", "input", "output")
    wait_for(lambda: not any(node.count_publishers(f"/{t}") for t in names), 10, "none left")
    late = graph.node("late_sensor")
    node.trigger_deactivate()  # a fresh, reliable subscription, and then a late publisher
    assert node.trigger_activate().to_label() == "transition_success"
    lis.estimates.clear()
    lis.diag.clear()
    reliable = [node.inputs.subs[s].qos_profile.reliability for s in range(3)]
    assert {r.name for r in reliable} == {"RELIABLE"}, reliable
    pubs = _sensor_publishers(late)
    wait_for(
        lambda: (
            any("incompatible QoS: RELIABILITY" in s.message for s in lis.diag)
            or any("RELIABILITY" in kv.value for s in lis.diag for kv in s.values)
        ),
        30,
        "the incompatible QoS named on /diagnostics",
    )
    await_subscribers(pubs)
    Feed(pubs, model, seed=4, block=240).send(30, pause=0.02)
    wait_for(lambda: lis.estimates, 30, "an estimate after subscribing again best effort")


def test_the_node_runs_without_threadpoolctl_and_says_so(graph, tmp_path):
    """threadpoolctl has no rosdep key: hidden from mr-ident-node, it still estimates, and
    its log says what is missing and how to get it."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "threadpoolctl.py").write_text("raise ImportError('hidden by the test')\n")
    env = domain_env(graph.domain)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(hide), env.get("PYTHONPATH", "")) if p)
    args = ["--ros-args", "-p", "autostart:=true", "-p", "window_s:=5.0"]
    args += ["-p", "min_window_s:=5.0", "-p", "update_period_s:=0.2"]
    proc = subprocess.Popen(
        [venv_bin("mr-ident-node"), *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        lis = Listener(graph)
        publish_sim(publishers(graph), load_model(PAPER), 7.0, block=240, wait=30)
        wait_for(lambda: lis.estimates, 30, "an estimate of the node without threadpoolctl")
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
    assert "threadpoolctl is not installed (pip install threadpoolctl)" in out, out
    assert "Traceback" not in out


#: The node's result topics of earlier versions (legacy_array_topics only).
LEGACY = ("plant_frf", "plant_frf_std", "frequencies", "bode_mag_db", "bode_phase_deg")


def test_every_benchmark_and_script_listens_to_the_current_interface():
    """No benchmark, script or program of the package subscribes to a legacy array topic of
    the node (they are off by default: `make soak` once counted no estimate at all)."""
    files = [*ROOT.glob("benchmarks/*.py"), *ROOT.glob("scripts/*.py")]
    files.append(ROOT / "mr_ident" / "ros" / "demo.py")
    names = "|".join(LEGACY)
    pattern = re.compile(r"""["'][^"']*/mr_ident/(""" + names + r""")["']""")
    found = [f"{f.name}: {m.group(0)}" for f in files for m in pattern.finditer(f.read_text())]
    assert not found, found
    soak = (ROOT / "benchmarks" / "soak.py").read_text()
    assert '"/mr_ident/estimate"' in soak
