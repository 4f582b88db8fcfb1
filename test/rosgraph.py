# SPDX-License-Identifier: Apache-2.0
"""Helpers of the tests that start ROS nodes: a graph in its own domain, publishers, feeds.

Every graph gets its own DDS domain (ros-jazzy-domain-coordinator) and rclpy context;
discovery is localhost-only; every wait is bounded. Importing this module skips the
importing test module where rclpy is absent.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import console_script, domain_env, ros_settings

os.environ.update(ros_settings())  # the nodes of this process too

rclpy = pytest.importorskip("rclpy")
from domain_coordinator import domain_id  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

from mr_ident.numerics.excitation.sources import SimSource  # noqa: E402
from mr_ident.ros.messages import BLOCK_QOS, BODE_TOPICS, RESULT_QOS, block_msg  # noqa: E402
from mr_ident.ros.node import IdentNode  # noqa: E402
from mr_ident.ros.outputs import EstimateMsg, estimate_arrays  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"
CONTROLLER = [
    Parameter("controller_num", value=[6000.0, -5400.0]),
    Parameter("controller_den", value=[1.0, -0.3]),
]


def wait_for(pred, timeout: float, what: str, step: float = 0.05):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = pred()
        if v:
            return v
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def await_estimate_ending_at(
    node, end: int, timeout: float = 30.0, what: str = "the estimate of the final window"
):
    """Until ``node``'s last estimate ends at sample ``end`` (bounded); that estimate."""

    def done() -> bool:
        est = node.last_estimate  # read once: the node's thread replaces it
        return est is not None and est.first + est.n_samples == end

    wait_for(done, timeout, what)
    return node.last_estimate


class Graph:
    """A context in its own domain, with nodes spun by one executor thread."""

    def __init__(self, dom: int):
        self.domain = dom
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=dom)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.nodes = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self.ctx.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # context shut down under us
                if self.ctx.ok():
                    raise
                return

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name: str):
        return self.add(rclpy.create_node(name, context=self.ctx))

    def ident(self, params, **kwargs):
        """An IdentNode, configured and activated as mr-ident-node does with ``autostart``
        (given first: ``params`` may set it false)."""
        params = [Parameter("autostart", value=True), *params]
        node = self.add(IdentNode(context=self.ctx, parameter_overrides=params, **kwargs))
        assert node.autostart(), node.configure_error
        return node

    def close(self):
        for n in self.nodes:
            if isinstance(n, IdentNode):
                n.shutdown()
        self.ctx.try_shutdown()
        self._thread.join(5)
        for n in self.nodes:
            n.destroy_node()


@pytest.fixture
def graph():
    with domain_id() as dom:
        g = Graph(dom)
        try:
            yield g
        finally:
            g.close()


class Listener:
    def __init__(self, g: Graph):
        self.node = g.node("listener")
        self.msgs: dict[str, Float64MultiArray] = {}
        self.estimates: list = []
        self.diag = []
        names = ("frequencies", "plant_frf", "plant_frf_std", "pfg", "pfg_std", "pfg_data")
        for name in (*names, "pfg_data_std", *BODE_TOPICS):
            self.node.create_subscription(
                Float64MultiArray,
                f"/mr_ident/{name}",
                lambda m, name=name: self.msgs.__setitem__(name, m),
                RESULT_QOS,
            )
        from diagnostic_msgs.msg import DiagnosticArray

        self.node.create_subscription(
            DiagnosticArray, "/diagnostics", lambda m: self.diag.append(m.status[0]), 10
        )
        if EstimateMsg is not None:  # the node's ~/estimate (mr_ident_msgs)
            self.node.create_subscription(
                EstimateMsg, "/mr_ident/estimate", self.estimates.append, RESULT_QOS
            )

    @property
    def estimate(self):
        """The latest ~/estimate as arrays (outputs.EstimateArrays), or None."""
        return estimate_arrays(self.estimates[-1]) if self.estimates else None

    def plant(self):
        """(f, P) of the latest estimate: ~/estimate, else the legacy arrays."""
        if self.estimates:
            e = self.estimate
            return e.frequency, e.response
        return self.plant_arrays()

    def plant_arrays(self):
        """(f, P) of the legacy arrays (legacy_array_topics)."""
        m = self.msgs["plant_frf"]
        P = np.frombuffer(m.data).reshape([d.size for d in m.layout.dim])
        return np.frombuffer(self.msgs["frequencies"].data), np.transpose(
            P[:, :, 0] + 1j * P[:, :, 1], (2, 0, 1)
        )

    def last_diag(self):
        s = self.diag[-1]
        return s.level, s.message, {kv.key: kv.value for kv in s.values}


def publishers(g: Graph):
    n = g.node("blocks")
    return [
        n.create_publisher(Float64MultiArray, t, BLOCK_QOS)
        for t in ("reference", "input", "output")
    ]


def fast_params(window_s=20.0, **extra):
    d = dict(window_s=window_s, min_window_s=window_s, update_period_s=0.2)
    d.update(extra)
    return [Parameter(k, value=v) for k, v in d.items()] + CONTROLLER


def await_subscribers(pubs, timeout: float = 10.0):
    """Until every publisher has a subscriber (bounded), then a moment for the other side."""
    wait_for(lambda: all(p.get_subscription_count() > 0 for p in pubs), timeout, "subscribers")
    time.sleep(0.5)  # matching is not symmetric: let the subscriber side match the writer too


class Feed:
    """Clean simulated blocks on the three topics, remembering what each run published."""

    def __init__(self, pubs, model, seed: int, block: int = 120):
        self.pubs, self.model, self.block = pubs, model, block
        self.runs: list[list[tuple]] = []  # per run: (first, r, u, y) of every block taken
        self.restart(seed)

    def restart(self, seed: int):
        """The publisher starts over from index 0 (another run of the loop)."""
        self.src = SimSource(self.model, block=self.block, seed=seed)
        self.runs.append([])

    def take(self):
        first, r, u, y = self.src.next()
        self.runs[-1].append((first, r, u, y))
        return first, [r, u, y]

    def send(self, n: int, pause: float = 0.002, skip=None):
        """Publish the next ``n`` blocks (``skip``: (stream, block) not sent); return them."""
        sent = []
        for b in range(n):
            first, xs = self.take()
            for s, (p, x) in enumerate(zip(self.pubs, xs, strict=False)):
                if skip != (s, b):
                    p.publish(block_msg(first, x))
            sent.append((first, *xs))
            time.sleep(pause)
        return sent

    def truth_of(self, first: int, r, u, y) -> bool:
        """Whether (r, u, y) at [first, ...) is exactly what one run published there."""
        n = r.shape[0]
        for run in self.runs:
            whole = [np.concatenate([blk[i] for blk in run]) for i in (1, 2, 3)]
            if whole[0].shape[0] >= first + n and all(
                np.array_equal(a, b[first : first + n])
                for a, b in zip((r, u, y), whole, strict=False)
            ):
                return True
        return False


def publish_sim(pubs, model, seconds: float, *, block=1000, skip=None, seed=3, wait=10.0):
    """Publish ``seconds`` of the simulated loop, once subscribed (waiting at most ``wait`` s);
    ``skip`` = (stream, block number) not sent."""
    await_subscribers(pubs, wait)
    return Feed(pubs, model, seed, block).send(
        int(np.ceil(seconds * model.fs_high / block)), skip=skip
    )


def venv_bin(name: str) -> str:
    """Where this package's console script ``name`` is installed (conftest.console_script)."""
    return console_script(name)


@contextlib.contextmanager
def child(graph: Graph, *argv: str, **popen):
    """A console script of this venv in ``graph``'s domain, killed if still running at the end."""
    proc = subprocess.Popen(
        [venv_bin(argv[0]), *argv[1:]], env=domain_env(graph.domain), text=True, **popen
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
