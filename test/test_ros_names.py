# SPDX-License-Identifier: Apache-2.0
"""Names over DDS: two nodes in two namespaces on one domain, and the sources' helper node.

Own domain, localhost only, every wait bounded (test/rosgraph.py).
"""

from __future__ import annotations

import subprocess
import time
from dataclasses import replace

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("mr_ident_msgs", reason="mr_ident_msgs is not built (make venv builds it)")
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.srv import GetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph import PAPER, child, fast_params, wait_for  # noqa: E402
from rosgraph import graph as graph  # noqa: E402  (the fixture)

from mr_ident.io.modelfile import load_model, model_to_dict  # noqa: E402
from mr_ident.ros.messages import RESULT_QOS  # noqa: E402
from mr_ident.ros.outputs import estimate_arrays  # noqa: E402
from mr_ident_msgs.msg import Estimate as EstimateMsg  # noqa: E402

QUIET = {"stdout": subprocess.DEVNULL, "stderr": subprocess.STDOUT}


def _relative_error(e, model) -> float:
    P = model.plant_discrete().freqresp(e.frequency)
    return float(np.median(np.abs(e.response - P) / np.abs(P)))


def test_two_nodes_in_two_namespaces_each_on_its_own_loop(graph, tmp_path):
    """Loop a (the paper's) in /a with the node in-process, block topics relative; loop b (its
    plant gain halved) in /b, node and sim as console scripts renamed (``__node:=ident``) and
    remapped (``output:=y_meas``) by global arguments, parameters from a ``/**`` file. Each
    estimate is its own loop's plant (median relative error < 1e-3) on its own topic; the
    parameters, the nodes and the /diagnostics statuses never clash."""
    model_a = load_model(PAPER)
    model_b = replace(model_a, plant_gain=0.5)
    path_b = tmp_path / "b.yaml"
    path_b.write_text(yaml.safe_dump(model_to_dict(model_b), sort_keys=False))
    params = tmp_path / "p.yaml"
    params.write_text(
        yaml.safe_dump(
            {"/**": {"ros__parameters": {"window_s": 5.0, "min_window_s": 5.0, "ratio": 3}}}
        )
    )
    node_a = graph.ident(fast_params(window_s=10.0), namespace="a")
    lis = graph.node("names_listener")
    got: dict[str, list] = {"/a/mr_ident": [], "/b/ident": []}
    status: set[str] = set()
    for name, msgs in got.items():
        lis.create_subscription(EstimateMsg, f"{name}/estimate", msgs.append, RESULT_QOS)
    lis.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: status.update(s.name for s in m.status), 10
    )
    # the sims outlive every check below (300 s of data at 10x: 30 s), the context ends them
    sim = ("mr-ident-sim", "--rate", "10", "--wait", "20", "--duration", "300")
    b_args = ("--ros-args", "-r", "__ns:=/b", "-r", "output:=y_meas")
    with (
        child(graph, *sim[:1], str(PAPER), *sim[1:], "--ros-args", "-r", "__ns:=/a", **QUIET),
        child(
            graph,
            "mr-ident-node",
            *b_args,
            "-p",
            "autostart:=true",
            "-r",
            "__node:=ident",
            "--params-file",
            str(params),
            **QUIET,
        ),
        child(graph, *sim[:1], str(path_b), *sim[1:], *b_args, "-r", "__node:=sim", **QUIET),
    ):
        wait_for(lambda: all(len(v) >= 2 for v in got.values()), 60, "estimates of both nodes")
        names = lis.get_node_names_and_namespaces()
        assert sorted(n for n in names if n[1] in ("/a", "/b") and not n[0].startswith("_")) == [
            ("ident", "/b"),
            ("mr_ident", "/a"),
            ("mr_ident_sim", "/a"),
            ("sim", "/b"),
        ], names
        for topic in ("/a/mr_ident/estimate", "/b/ident/estimate", "/b/y_meas"):
            assert lis.count_publishers(topic) == 1, topic
        assert node_a.set_parameters([Parameter("window_s", value=12.0)])[0].successful
        cli = lis.create_client(GetParameters, "/b/ident/get_parameters")
        assert cli.wait_for_service(timeout_sec=10)
        future = cli.call_async(GetParameters.Request(names=["window_s"]))
        wait_for(future.done, 10, "b's parameters")
        assert future.result().values[0].double_value == 5.0  # its own, from the /** file
        wait_for(
            lambda: {"/a/mr_ident: identification", "/b/ident: identification"} <= status,
            10,
            "both statuses",
        )
    a, b = estimate_arrays(got["/a/mr_ident"][0]), estimate_arrays(got["/b/ident"][-1])
    assert b.window_last - b.window_first + 1 == 1200  # 5 s: b's file, not a's
    assert _relative_error(a, model_a) < 1e-3, _relative_error(a, model_a)
    assert _relative_error(b, model_b) < 1e-3, _relative_error(b, model_b)
    assert _relative_error(b, model_a) > 0.3  # the two loops differ: no cross-talk passes


def test_relative_sources_follow_the_namespace_and_remaps_and_the_helper_is_its_own(graph):
    """mr-ident-node renamed and put in /c by global arguments, with a relative source
    ``js.position{...}`` and ``-r js:=joint_states``: it subscribes /c/joint_states, the
    only node named ident in /c; its sources' helper node is hidden, in /c, of another name,
    and serves no service (no parameters)."""
    from sensor_msgs.msg import JointState

    pub = graph.node("robot").create_publisher(JointState, "/c/joint_states", 10)
    source = 'js.position{name=="j1"}'
    args = [
        *("--ros-args", "-r", "__ns:=/c", "-r", "__node:=ident", "-r", "js:=joint_states"),
        *("-p", "autostart:=true"),
        *("-p", f"r_source:=['{source}']", "-p", f"u_source:=['{source}']"),
        *("-p", f"y_source:=['{source}']"),
    ]
    lis = graph.node("names_listener")
    with child(graph, "mr-ident-node", *args, **QUIET):
        wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node subscribing")
        time.sleep(1.0)
        names = [n for n in lis.get_node_names_and_namespaces() if n[1] == "/c"]
        helpers = [n for n, _ in names if n.startswith("_ident_sources_")]
        assert [n for n, _ in names if not n.startswith("_")] == ["ident"], names
        assert len(helpers) == 1, names
        services = {s for s, _ in lis.get_service_names_and_types()}
        assert "/c/ident/get_parameters" in services
        assert not any(s.startswith(f"/c/{helpers[0]}/") for s in services), services
