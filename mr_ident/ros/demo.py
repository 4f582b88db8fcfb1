# SPDX-License-Identifier: Apache-2.0
"""``mr-ident demo`` (``make demo``): the live pipeline end to end on localhost DDS.

Starts ``mr-ident-sim`` (paper example, accelerated, output noise) and
``mr-ident-node`` (recording to MCAP) as separate processes in a DDS domain of
their own, listens to the node's estimates until they have converged (two
successive estimates of a full window agree to 2 % in median), stops the
simulator, lets the node finish its last estimate, stops the node (the
recording is finalised), replays the recording offline over the same window, and
writes the Bode and PFG plots of the live estimate against the model and the
replay. Prints the paths and a one-line accuracy summary.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import MrIdentError
from ..io.config import load_params, share_file
from ..io.modelfile import load_model
from ..numerics.results import FRF, PFG
from .program import Stop, handle_signals, ros_context

SIM_NOISE_STD = 1e-7  # output noise of the demo loop (the paper example's |y| is ~1e-5)


def _stop(proc: subprocess.Popen, timeout: float = 20.0) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def run_demo(
    out_dir: Path, *, rate: float = 20.0, timeout: float = 120.0, stop: Stop | None = None
) -> int:
    """Run the demo (module docstring).

    A stop (SIGINT/SIGTERM) ends it early with exit 0, the children stopped and the node's
    recording finalised.
    """
    import yaml
    from domain_coordinator import domain_id

    stop = stop if stop is not None else handle_signals()
    out_dir.mkdir(parents=True, exist_ok=True)
    model_path = share_file("config/paper_example.yaml")
    params_path = share_file("config/node.yaml")
    cfg = load_params(params_path)
    model = load_model(model_path)
    # the demo's model: the paper example with output noise, so the ±2σ bands mean something
    noisy = yaml.safe_load(model_path.read_text())
    noisy["noise_std"] = SIM_NOISE_STD
    demo_model = out_dir / "demo_model.yaml"
    demo_model.write_text(yaml.safe_dump(noisy, sort_keys=False))
    recording = out_dir / "live.mcap"
    recording.unlink(missing_ok=True)
    bindir = Path(sys.executable).parent
    live = _Live()
    procs: dict[str, subprocess.Popen] = {}
    with domain_id() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.setdefault("ROS_LOG_DIR", str((out_dir / "ros_log").resolve()))
        os.environ.update(
            {k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR")}
        )
        logs = {name: open(out_dir / f"{name}.log", "w") for name in ("node", "sim")}
        try:
            procs["node"] = subprocess.Popen(
                [
                    str(bindir / "mr-ident-node"),
                    "--ros-args",
                    "-p",
                    "autostart:=true",
                    "--params-file",
                    str(params_path),
                    "-p",
                    f"record_path:={recording}",
                    "-p",
                    "update_period_s:=0.5",
                ],
                env=env,
                stdout=logs["node"],
                stderr=subprocess.STDOUT,
            )
            procs["sim"] = subprocess.Popen(
                [
                    str(bindir / "mr-ident-sim"),
                    str(demo_model),
                    "--rate",
                    str(rate),
                    "--wait",
                    "10",
                ],
                env=env,
                stdout=logs["sim"],
                stderr=subprocess.STDOUT,
            )
            with ros_context() as rclpy:
                listener = _listener(rclpy, live)
                try:
                    try:
                        _listen(
                            rclpy,
                            listener,
                            live,
                            cfg,
                            node_proc=procs["node"],
                            sim_proc=procs["sim"],
                            timeout=timeout,
                            stop=stop,
                        )
                    finally:
                        _stop(procs["sim"])
                        stop.wait(0.5)
                    _settle(rclpy, listener, live, 20.0, stop)
                finally:
                    listener.destroy_node()
        finally:
            for proc in procs.values():  # the node finalises its recording on SIGINT
                _stop(proc)
            for f in logs.values():
                f.close()
    if stop.requested:
        print(
            f"demo stopped by signal {stop.signal}; the node's recording {recording} is finalised"
            if recording.exists()
            else f"demo stopped by signal {stop.signal}"
        )
        return 0
    return _report(out_dir, cfg, model, recording, live, procs["node"].returncode)


class _Live:
    """The latest estimate as received from the node's topics and /diagnostics."""

    def __init__(self) -> None:
        self.freq: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.P_std: np.ndarray | None = None
        self.pfg: np.ndarray | None = None
        self.pfg_std: np.ndarray | None = None
        self.diag: dict[str, str] = {}
        self.window: tuple[int, int] | None = None  # (first, samples) of the latest estimate
        self.history: list[np.ndarray] = []
        self.t_converged: float | None = None


def _listener(rclpy, live: _Live):
    """A node that keeps the node's latest estimate (~/estimate) and diagnostics in ``live``."""
    from diagnostic_msgs.msg import DiagnosticArray

    from .messages import RESULT_QOS, status_values
    from .outputs import EstimateMsg, estimate_arrays

    if EstimateMsg is None:
        raise MrIdentError("mr_ident_msgs is not installed (make venv builds it)")
    n = rclpy.create_node("mr_ident_demo")

    def estimate(m) -> None:
        e = estimate_arrays(m)
        live.freq, live.P, live.P_std, live.pfg, live.pfg_std = (
            e.frequency, e.response, e.std, e.pfg, e.pfg_std
        )  # fmt: skip
        live.window = (e.window_first, e.window_last + 1 - e.window_first)
        live.history.append(live.P)

    def diag(m: DiagnosticArray) -> None:
        for s in m.status:
            if s.name == "/mr_ident: identification":
                live.diag = status_values(s)

    n.create_subscription(EstimateMsg, "/mr_ident/estimate", estimate, RESULT_QOS)
    n.create_subscription(DiagnosticArray, "/diagnostics", diag, 10)
    return n


def _listen(
    rclpy,
    n,
    live: _Live,
    cfg,
    *,
    node_proc,
    sim_proc,
    timeout: float,
    stop: Stop,
) -> None:
    """Spin until two successive full-window estimates agree to 2 % (median), or a stop."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if stop.requested:
            return
        rclpy.spin_once(n, timeout_sec=0.1)
        if node_proc.poll() is not None or sim_proc.poll() is not None:
            raise MrIdentError(
                f"{'node' if node_proc.poll() is not None else 'simulator'} exited early; "
                "see its log in the demo directory"
            )
        full = live.window is not None and live.window[1] == cfg.window_samples
        if full and len(live.history) >= 2 and live.history[-1].shape == live.history[-2].shape:
            a, b = live.history[-1], live.history[-2]
            change = float(np.median(np.abs(a - b) / np.abs(b)))
            if change < 0.02:
                live.t_converged = time.monotonic() - t0
                return
    raise MrIdentError(
        f"no converged estimate within {timeout:g} s (last diagnostics: "
        f"{live.diag.get('message')})"
    )


def _settle(rclpy, n, live: _Live, timeout: float, stop: Stop) -> None:
    """After the simulator stopped: wait until the node's last estimate covers the final window."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout and not stop.requested:
        rclpy.spin_once(n, timeout_sec=0.1)
        d, w = live.diag, live.window
        if w is not None and d.get("window_end_index") and sum(w) == int(d["window_end_index"]):
            # one more diagnostics round so the published estimate is the one described
            t1 = time.monotonic()
            while time.monotonic() - t1 < 1.5 and not stop.requested:
                rclpy.spin_once(n, timeout_sec=0.1)
            return


def _report(out_dir: Path, cfg, model, recording: Path, live: _Live, node_rc: int) -> int:
    from ..io.units import load_units
    from ..live.replay import replay
    from ..numerics.lifted.pfg import pfg_of_model
    from ..plots import plot_bode, plot_pfg

    units = load_units(share_file("config/paper_example.yaml"))  # the model's
    if live.P is None or live.freq is None or live.P_std is None or live.window is None:
        raise MrIdentError("no estimate was received from the node")
    first, count = live.window
    res = replay(recording, cfg, stop=first + count)
    est = res.estimate
    if (est.first, est.n_samples) != (first, count):
        raise MrIdentError(
            f"replay found window [{est.first}, {est.first + est.n_samples}), the node "
            f"published [{first}, {first + count})"
        )
    plant = est.identification.plant
    picks = np.searchsorted(plant.frequency, live.freq)
    replay_diff = float(np.max(np.abs(plant.response[picks] - live.P)) / np.max(np.abs(live.P)))
    P_true = model.plant_frf(count)[1:][picks]
    rel = np.abs(live.P - P_true) / np.abs(P_true)
    live_frf = FRF(live.freq, live.P, live.P_std, "live " + cfg.method)
    model_frf = FRF(live.freq, P_true, np.zeros(P_true.shape), "model")
    files = {
        "bode": plot_bode(
            live_frf,
            out_dir / "live_bode.png",
            model=model_frf,
            nyquist_low=cfg.fs_high / cfg.ratio / 2,
            title="mr-ident-node live estimate vs model",
            units=units,
        ),
        "recording": recording,
    }
    files["replay_bode"] = plot_bode(
        plant,
        out_dir / "replay_bode.png",
        model=model.plant_result(count),
        nyquist_low=cfg.fs_high / cfg.ratio / 2,
        title="offline replay of the recording",
        units=units,
    )
    if live.pfg is not None and live.pfg_std is not None and est.identification.pfg is not None:
        ref = pfg_of_model(model, count)
        live_pfg = PFG(live.freq, live.pfg, live.pfg_std, "live")
        ref_at = PFG(live.freq, ref.gain[picks], np.zeros(picks.size), "model")
        files["pfg"] = plot_pfg(
            live_pfg,
            out_dir / "live_pfg.png",
            model=ref_at,
            title="live PFG vs model",
            nyquist_low=cfg.fs_high / cfg.ratio / 2,
        )
    for name, path in files.items():
        print(f"{name:12s} {path}")
    within = float(np.mean(np.abs(live.P - P_true) <= 2 * live.P_std + 1e-300))
    print(
        f"live estimate after {live.t_converged:.1f} s wall ({count / cfg.fs_high:g} s of data, "
        f"{live.P.shape[0]} published bins): median |P-P_true|/|P_true| = {np.median(rel):.2e}, "
        f"{100 * within:.0f} % of bins within 2 sigma; replay equals live to {replay_diff:.1e}; "
        f"node exit {node_rc}"
    )
    print(
        "see it live (docs/monitoring.md, 'Live view'): with mr-ident-node and mr-ident-sim "
        "running, start\n"
        "  mr-ident view --model config/paper_example.yaml    and open http://127.0.0.1:8765/\n"
        f"or replay this demo's recording there:\n  mr-ident view {recording} "
        "--model config/paper_example.yaml --speed 20"
    )
    return 0
