# SPDX-License-Identifier: Apache-2.0
"""The node as a managed node over DDS: every lifecycle request answered, a finalized node
holding nothing of its own, an unconfigured one saying that it waits, configure refused
without the interfaces, and every parameter readable in one call.

Own domain, localhost only, every wait bounded (test/rosgraph.py).
"""

from __future__ import annotations

import os
import subprocess
import time

import pytest
from conftest import domain_env

pytest.importorskip("rclpy")
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rcl_interfaces.srv import GetParameters, ListParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph import fast_params, publishers, venv_bin, wait_for  # noqa: E402
from rosgraph import graph as graph  # noqa: E402  (the fixture)

from mr_ident.io.config import PARAMETERS  # noqa: E402
from mr_ident.ros import node as node_module  # noqa: E402
from mr_ident.ros.node import IdentNode  # noqa: E402

NS = "/mr_ident"


class Caller:
    """Service calls to the node and its statuses, from a node of the test's own."""

    def __init__(self, graph):
        self.node = graph.node("caller")
        self.status: list = []
        self.node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: self.status.extend(s for s in m.status if s.name.startswith(NS + ":")),
            10,
        )

    def call(self, kind, name: str, request, timeout: float = 20.0):
        cli = self.node.create_client(kind, f"{NS}/{name}")
        assert cli.wait_for_service(timeout_sec=10), f"no service {name}"
        future = cli.call_async(request)
        wait_for(future.done, timeout, f"the response of {name}")
        self.node.destroy_client(cli)
        return future.result()

    def change(self, *, label: str = "", id: int = 0) -> bool:
        req = ChangeState.Request()
        req.transition.id, req.transition.label = id, label
        return self.call(ChangeState, "change_state", req).success

    def state(self) -> str:
        return self.call(GetState, "get_state", GetState.Request()).current_state.label

    def services(self) -> set[str]:
        return {
            name.removeprefix(NS + "/")
            for name, _ in self.node.get_service_names_and_types()
            if name.startswith(NS + "/")
        }


LIFECYCLE_SERVICES = {
    "change_state",
    "get_state",
    "get_available_states",
    "get_available_transitions",
    "get_transition_graph",
}


def test_every_lifecycle_request_is_answered_and_the_node_lives_on(graph):
    """Requests the state has no transition for (by id, as launch's event handlers and
    lifecycle managers send them, and by label) are answered success false, the node stays
    where it was and goes on; the valid ones work; finalized, it holds nothing of its own."""
    node = graph.ident(fast_params(window_s=5.0))
    c = Caller(graph)
    pubs = publishers(graph)
    assert c.state() == "active"
    for request in (
        {"id": Transition.TRANSITION_CONFIGURE},  # what a lifecycle manager sends
        {"label": "configure"},
        {"id": Transition.TRANSITION_CLEANUP},
        {"id": 42},  # no transition at all
    ):
        assert c.change(**request) is False, request
        assert c.state() == "active", request
    wait_for(lambda: all(p.get_subscription_count() for p in pubs), 10, "its subscriptions")
    assert c.change(id=Transition.TRANSITION_DEACTIVATE) and c.state() == "inactive"
    assert c.change(label="deactivate") is False and c.state() == "inactive"
    assert c.change(label="activate") and c.state() == "active"
    mine = c.services() - LIFECYCLE_SERVICES
    assert {"reset", "snapshot", "start_recording", "stop_recording", "diagnose"} <= mine

    assert c.change(id=Transition.TRANSITION_ACTIVE_SHUTDOWN) and c.state() == "finalized"
    for request in ({"label": "configure"}, {"id": Transition.TRANSITION_CONFIGURE}):
        assert c.change(**request) is False and c.state() == "finalized"
    wait_for(lambda: not (c.services() & mine - PARAMETER_SERVICES), 10, "its services gone")
    assert c.services() - PARAMETER_SERVICES == LIFECYCLE_SERVICES
    wait_for(lambda: not any(p.get_subscription_count() for p in pubs), 10, "no subscription")
    assert list(node.timers) == [] and list(node.subscriptions) == []
    assert {p.topic_name for p in node.publishers} <= {"/parameter_events"}
    c.status.clear()
    time.sleep(2.5)  # the 1 Hz status is gone with the rest
    assert c.status == []


PARAMETER_SERVICES = {
    "describe_parameters",
    "get_parameter_types",
    "get_parameters",
    "list_parameters",
    "set_parameters",
    "set_parameters_atomically",
    "get_type_description",
}


def test_an_unconfigured_node_says_on_diagnostics_that_it_waits_and_why_configure_failed(
    graph,
):
    """Started without autostart (its default), the node waits unconfigured and says so
    (OK); a configure that fails leaves it unconfigured with the reason (ERROR); corrected,
    it configures."""
    node = graph.add(
        IdentNode(context=graph.ctx, parameter_overrides=[Parameter("lifting_phase", value="7")])
    )
    assert node.get_parameter("autostart").value is False
    assert node.autostart()  # nothing to do: it waits
    c = Caller(graph)
    assert c.state() == "unconfigured"
    first = wait_for(lambda: c.status and c.status[-1], 10, "a status of the unconfigured node")
    assert first.level == DiagnosticStatus.OK and "waiting for configure" in first.message
    assert c.change(label="configure") is False and c.state() == "unconfigured"
    c.status.clear()
    failed = wait_for(lambda: c.status and c.status[-1], 10, "a status after configure")
    assert failed.level == DiagnosticStatus.ERROR, failed
    assert "configure failed" in failed.message and "lifting_phase" in failed.message
    assert node.set_parameters([Parameter("lifting_phase", value="auto")])[0].successful
    assert c.change(id=Transition.TRANSITION_CONFIGURE) and c.state() == "inactive"


def test_without_its_interfaces_the_node_refuses_to_configure_saying_how_to_build_them(
    graph, monkeypatch, tmp_path
):
    """In a process where mr_ident_msgs does not import: mr-ident-node with autostart exits
    2 naming the package and the build; a node asked to configure stays unconfigured, the
    same reason on /diagnostics."""
    hidden = tmp_path / "hide" / "mr_ident_msgs"
    hidden.mkdir(parents=True)
    (hidden / "__init__.py").write_text("raise ImportError('hidden by the test')\n")
    env = domain_env(graph.domain)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(hidden.parent), env.get("PYTHONPATH", "")) if p
    )
    proc = subprocess.run(
        [venv_bin("mr-ident-node"), "--ros-args", "-p", "autostart:=true"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    assert "error: the interface package mr_ident_msgs" in proc.stderr, proc.stderr
    assert "colcon build" in proc.stderr and "Traceback" not in proc.stderr

    monkeypatch.setattr(node_module, "EstimateMsg", None)  # this process's node alike
    node = graph.add(IdentNode(context=graph.ctx))
    c = Caller(graph)
    assert c.change(label="configure") is False and c.state() == "unconfigured"
    assert "mr_ident_msgs" in node.configure_error
    c.status.clear()
    st = wait_for(lambda: c.status and c.status[-1], 10, "the status")
    assert st.level == DiagnosticStatus.ERROR and "mr_ident_msgs" in st.message


def test_every_parameter_is_readable_in_one_call(graph):
    """ListParameters then one GetParameters: every value set (none NOT_SET), the sources
    as string arrays (empty, or as given), the controller as double arrays; read-only ones
    stay so."""
    source = 'js.position{name=="j1"}'
    overrides = [Parameter("u_source", value=[source])]
    node = graph.add(IdentNode(context=graph.ctx, parameter_overrides=overrides))
    c = Caller(graph)
    names = c.call(ListParameters, "list_parameters", ListParameters.Request()).result.names
    assert set(PARAMETERS) | {"autostart", "legacy_array_topics", "use_sim_time"} <= set(names)
    values = dict(
        zip(
            names,
            c.call(GetParameters, "get_parameters", GetParameters.Request(names=names)).values,
            strict=True,
        )
    )
    unset = [n for n, v in values.items() if v.type == ParameterType.PARAMETER_NOT_SET]
    assert not unset, unset
    for name in ("r_source", "y_source"):
        assert values[name].type == ParameterType.PARAMETER_STRING_ARRAY
        assert list(values[name].string_array_value) == []
    assert list(values["u_source"].string_array_value) == [source]
    for name in ("controller_num", "controller_den"):
        assert values[name].type == ParameterType.PARAMETER_DOUBLE_ARRAY
    assert values["autostart"].bool_value is False
    refused = node.set_parameters([Parameter("r_source", value=["x.data"])])[0]
    assert not refused.successful and "read-only" in refused.reason
    ok = node.set_parameters_atomically(
        [
            Parameter("controller_num", value=[1.0, 0.5]),
            Parameter("controller_den", value=[1.0, -0.5]),
        ]
    )
    assert ok.successful, ok.reason


def test_the_descriptions_say_the_clock_update_period_s_runs_on():
    assert "ROS clock" in PARAMETERS["update_period_s"].description
    assert "wall" not in PARAMETERS["update_period_s"].description
