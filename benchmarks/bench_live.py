# SPDX-License-Identifier: Apache-2.0
"""Live benchmark (`make bench-live`): node throughput and estimate latency over localhost DDS.

1. Throughput: a publisher process streams 1000-sample blocks on reference,
   input and output at a set rate (samples/s per topic) to ``mr-ident-node`` (a
   separate process, identifying a 1.44 M-sample window every 2 s meanwhile);
   the rate is raised step by step. A step passes when the node's /diagnostics
   count every sample sent on every topic with no gap. Reports the highest
   passing rate.
2. Latency: 1.44 M samples are streamed at 1 M samples/s to a fresh node; the
   time from the last block's publication to the arrival of the estimate of the
   window ending with it (update_period_s = 0.05 s). Three runs, each with a new
   node; the worst and the median are reported, and the node's CPU time over the run.
   Run at the default settings (n = auto) and with n = 8 (the fixed window that was the
   default before the automatic one), one after the other.

3. Per-sample messages: a publisher process streams ``sensor_msgs/JointState`` on two
   topics (``/joint_states`` with y and u, ``/ident/reference`` with r; stamps on a
   1 kHz grid) to a node configured with sources, at rising message rates per topic.
   A step passes when every message became a sample (no gap, none off the grid).

Not a test: prints figures for docs/benchmarks.md.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
BLOCK = 1000
WINDOW = 1_440_000
FS = 1e6  # the node is told 1 MHz so that 1 M samples/s is real time
LATENCY_RUNS = 3  # each with a fresh node (its first estimate, after the warm-up)


def _signals(n: int) -> np.ndarray:
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.systems.simulate import simulate

    m = load_model(Path(__file__).resolve().parents[1] / "config" / "paper_example.yaml")
    sim = simulate(m, n_samples=n, rng=np.random.default_rng(0))
    return np.stack([sim.r[:, 0], sim.u[:, 0], sim.y[:, 0]])


def publisher(rate: float, seconds: float) -> None:
    """Child process: publish ``seconds`` worth of blocks at ``rate`` samples/s per topic."""
    import rclpy
    from std_msgs.msg import Float64MultiArray

    from mr_ident.ros.messages import BLOCK_QOS, block_msg

    rclpy.init()
    node = rclpy.create_node("bench_pub")
    pubs = [
        node.create_publisher(Float64MultiArray, t, BLOCK_QOS)
        for t in ("reference", "input", "output")
    ]
    x = _signals(WINDOW)
    t_end = time.monotonic() + 10
    while any(p.get_subscription_count() == 0 for p in pubs) and time.monotonic() < t_end:
        time.sleep(0.01)
    time.sleep(0.5)
    n_blocks = int(rate * seconds / BLOCK)
    t0 = time.monotonic()
    for b in range(n_blocks):
        k = (b * BLOCK) % WINDOW
        if rate > 0:
            due = t0 + (b + 1) * BLOCK / rate
            while (d := due - time.monotonic()) > 0:
                time.sleep(d)
        for s, p in enumerate(pubs):
            p.publish(block_msg(b * BLOCK, x[s, k : k + BLOCK]))
    print(f"{n_blocks * BLOCK} {time.time():.6f} {time.monotonic() - t0:.3f}", flush=True)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()


JS_FS = 1000.0  # the stamps' grid of the per-sample phase
JS_SOURCES = (
    'r_source:=["/ident/reference.position[0]"]',
    'u_source:=["/joint_states.effort[0]"]',
    'y_source:=["/joint_states.position[0]"]',
)


def js_publisher(rate: float, seconds: float) -> None:
    """Child process: JointState at ``rate`` messages/s per topic (stamps on a 1 kHz grid)."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("bench_js")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    js = node.create_publisher(JointState, "/joint_states", qos)
    ref = node.create_publisher(JointState, "/ident/reference", qos)
    x = _signals(60_000)
    t_end = time.monotonic() + 10
    while (
        js.get_subscription_count() == 0 or ref.get_subscription_count() == 0
    ) and time.monotonic() < t_end:
        time.sleep(0.01)
    time.sleep(0.5)
    n = int(rate * seconds)
    t0_stamp = 1_700_000_000_000_000_000
    a, b = JointState(), JointState()
    a.name, b.name = ["j1"], ["j1"]
    t0 = time.monotonic()
    for k in range(n):
        due = t0 + k / rate
        while (d := due - time.monotonic()) > 0:
            time.sleep(d)
        sec, nsec = divmod(t0_stamp + round(k * 1e9 / JS_FS), 1_000_000_000)
        for m in (a, b):
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nsec
        i = k % x.shape[1]
        a.position, a.effort = [float(x[2, i])], [float(x[1, i])]
        b.position = [float(x[0, i])]
        js.publish(a)
        ref.publish(b)
    print(f"{n} {time.time():.6f} {time.monotonic() - t0:.3f}", flush=True)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()


def _node(env: dict, update: float, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            str(Path(sys.executable).parent / "mr-ident-node"),
            "--ros-args",
            "-p",
            "autostart:=true",
            "-p",
            f"fs_high:={FS}",
            "-p",
            f"window_s:={WINDOW / FS}",
            "-p",
            f"min_window_s:={WINDOW / FS}",
            "-p",
            f"update_period_s:={update}",
            "-p",
            "reorder_blocks:=64",
            *[a for e in extra for a in ("-p", e)],
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


class _Listen:
    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray

        from mr_ident.ros.messages import RESULT_QOS
        from mr_ident_msgs.msg import Estimate

        self.rclpy = rclpy
        rclpy.init()
        self.node = rclpy.create_node("bench_listen")
        self.diag: dict[str, str] = {}
        self.frf_times: list[float] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 10)
        self.node.create_subscription(
            Estimate,
            "/mr_ident/estimate",
            lambda m: self.frf_times.append(time.time()),
            RESULT_QOS,
        )

    def _diag(self, m) -> None:  # type: ignore[no-untyped-def]
        self.diag = {kv.key: kv.value for kv in m.status[0].values}

    def spin(self, seconds: float) -> None:
        t = time.monotonic()
        while time.monotonic() - t < seconds:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.shutdown()


def _run_publisher(
    env: dict, rate: float, seconds: float, lis: _Listen, kind: str = "--publisher"
) -> tuple[int, float]:
    """Run the publisher process; the listener keeps spinning meanwhile, so that a result
    published before the publisher has exited is received (and timed) when it arrives."""
    with tempfile.TemporaryFile("w+") as errors:  # a file, not a pipe: it never fills up
        proc = subprocess.Popen(
            [sys.executable, __file__, kind, str(rate), str(seconds)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=errors,
            text=True,
        )
        deadline = time.monotonic() + seconds * 10 + 60
        while proc.poll() is None:
            if time.monotonic() > deadline:
                proc.kill()
                raise RuntimeError("publisher did not finish in time")
            lis.spin(0.05)
        out, _ = proc.communicate()
        if proc.returncode != 0:
            errors.seek(0)
            raise RuntimeError(errors.read())
    n, t_last, elapsed = out.split()
    print(
        f"  publisher: {int(n)} samples per topic in {float(elapsed):.2f} s "
        f"({int(n) / float(elapsed) / 1e3:.1f} k per second)",
        flush=True,
    )
    _run_publisher.elapsed = float(elapsed)  # type: ignore[attr-defined]
    return int(n), float(t_last)


def latency(env: dict, label: str, extra: tuple[str, ...]) -> None:
    """Part 2 for one setting: three fresh nodes, latency and the node's CPU time each."""
    import psutil

    latencies, cpus = [], []
    for run in range(LATENCY_RUNS):
        node = _node(env, 0.05, *extra)
        lis = _Listen()
        try:
            lis.spin(1.0)
            sent, t_last = _run_publisher(env, 1e6, WINDOW / 1e6, lis)
            t_wait = time.monotonic()
            while time.monotonic() - t_wait < 60 and not [t for t in lis.frf_times if t > t_last]:
                lis.spin(0.1)
            after = [t for t in lis.frf_times if t > t_last]
            lis.spin(1.5)
            d = lis.diag
            latencies.append((after[0] - t_last) if after else float("nan"))
            ct = psutil.Process(node.pid).cpu_times()
            cpus.append(ct.user + ct.system)
            print(
                f"  (diagnostics: {d.get('window_end_index')} aligned, gaps "
                f"{[d.get(s + '.gaps') for s in ('reference', 'input', 'output')]}, "
                f"warm-up {d.get('warm_up_s')} s)"
            )
            print(
                f"{label}: latency {run + 1}/{LATENCY_RUNS}, last block published -> estimate "
                f"of the {WINDOW}-sample window received: {latencies[-1]:.2f} s (identification "
                f"{d.get('compute_s')} s, window [{d.get('estimate_first_index')}, "
                f"+{d.get('estimate_samples')}); node CPU {cpus[-1]:.1f} s",
                flush=True,
            )
        finally:
            lis.close()
            node.terminate()
            node.wait(30)
    print(
        f"{label}: latency over {LATENCY_RUNS} fresh nodes: worst {np.max(latencies):.2f} s, "
        f"median {float(np.median(latencies)):.2f} s; node CPU median "
        f"{float(np.median(cpus)):.1f} s (load {os.getloadavg()[0]:.2f})",
        flush=True,
    )


def main() -> None:
    from domain_coordinator import domain_id

    with domain_id() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        os.environ["ROS_DOMAIN_ID"] = str(dom)
        print(
            f"# live benchmark: blocks of {BLOCK} samples, 3 topics, window {WINDOW} samples, "
            f"SingleThreadedExecutor, localhost DDS (domain {dom})"
        )
        if "--latency" in sys.argv:  # part 2 alone
            for label, extra in (("default settings (n = auto)", ()), ("n = 8", ("n:=8",))):
                latency(env, label, extra)
            return
        best = 0.0
        for rate in (250e3, 500e3, 1e6, 2e6, 3e6, 4e6, 6e6):
            node = _node(env, update=2.0)
            lis = _Listen()
            try:
                lis.spin(1.0)
                sent, _ = _run_publisher(env, rate, 6.0, lis)
                lis.spin(3.0)
                d = lis.diag
                got = [int(d.get(f"{s}.samples", 0)) for s in ("reference", "input", "output")]
                gaps = sum(int(d.get(f"{s}.gaps", 0)) for s in ("reference", "input", "output"))
                ok = all(g == sent for g in got) and gaps == 0
                print(
                    f"rate {rate / 1e6:5.2f} MS/s per topic: sent {sent}, received {got}, gaps "
                    f"{gaps}, "
                    f"estimates {d.get('estimates')} -> {'OK' if ok else 'LOSS'}",
                    flush=True,
                )
            finally:
                lis.close()
                node.terminate()
                node.wait(30)
            if not ok:
                break
            best = rate
        print(
            f"highest sustained rate with zero lost samples: {best / 1e6:.2f} M samples/s per "
            "topic"
        )

        for label, extra in (("default settings (n = auto)", ()), ("n = 8", ("n:=8",))):
            latency(env, label, extra)

        best_js = 0.0
        for rate in (1e3, 2e3, 4e3, 8e3, 16e3):
            node = subprocess.Popen(
                [
                    str(Path(sys.executable).parent / "mr-ident-node"),
                    "--ros-args",
                    "-p",
                    "autostart:=true",
                    "-p",
                    f"fs_high:={JS_FS}",
                    "-p",
                    "window_s:=20.0",
                    "-p",
                    "min_window_s:=20.0",
                    "-p",
                    "update_period_s:=1.0",
                    *[a for e in JS_SOURCES for a in ("-p", e)],
                ],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            lis = _Listen()
            try:
                lis.spin(3.0)
                sent, _ = _run_publisher(env, rate, 6.0, lis, kind="--js-publisher")
                lis.spin(3.0)
                d = lis.diag
                got = [int(d.get(f"{s}.samples", 0)) for s in ("reference", "input", "output")]
                gaps = sum(int(d.get(f"{s}.gaps", 0)) for s in ("reference", "input", "output"))
                ok = all(g == sent for g in got) and gaps == 0
                print(
                    f"JointState {rate / 1e3:5.1f} k messages/s per topic: sent {sent}, samples "
                    f"{got}, gaps "
                    f"{gaps} -> {'OK' if ok else 'LOSS'} ({d.get('source.y0', '')})",
                    flush=True,
                )
            finally:
                lis.close()
                node.terminate()
                node.wait(30)
            if not ok:
                break
            achieved = sent / _run_publisher.elapsed  # type: ignore[attr-defined]
            best_js = max(best_js, achieved)
            if achieved < 0.9 * rate:
                print(
                    f"  the publisher reached only {achieved / 1e3:.1f} k messages/s: it is the "
                    "limit"
                )
                break
        print(
            f"highest per-sample message rate with every message a sample: {best_js / 1e3:.1f} "
            "k messages/s per topic (JointState, two topics)"
        )


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--publisher":
        publisher(float(sys.argv[2]), float(sys.argv[3]))
    elif len(sys.argv) == 4 and sys.argv[1] == "--js-publisher":
        js_publisher(float(sys.argv[2]), float(sys.argv[3]))
    else:
        main()
