# SPDX-License-Identifier: Apache-2.0
"""Soak (`make soak`, not in `make test`): sim + node + recorder at a high rate for a long time.

Three processes over localhost DDS in a domain of their own:

* ``mr-ident-sim config/paper_example.yaml --rate R`` publishes 1000-sample blocks
  (R x 240 samples/s per topic; it starts once the node and the recorder both
  subscribe, ``--subscribers 2``);
* ``mr-ident-node`` identifies a sliding window every ``update_period_s``;
* ``mr-ident record`` writes the three topics to MCAP.

Meanwhile this script samples every process's resident memory (VmRSS) and
records when each estimate arrives. Afterwards it checks, by sample index, that
the node received every sample with no gap and that the recording holds every
block exactly once, and reports RSS at start (the node's window full) and end,
and the estimate intervals. Prints the figures for docs/benchmarks.md and writes
them to ``out/soak/soak.json``.

    .venv/bin/python benchmarks/soak.py [--minutes 30] [--rate 400] [--out-dir out/soak]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
MODEL = ROOT / "config" / "paper_example.yaml"
FS = 240.0
BLOCK = 1000
STREAMS = ("reference", "input", "output")


def rss_mb(pid: int) -> float:
    """Resident set size of a process (MB), 0 once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


class Monitor:
    """In-process listener: estimate arrival times and the latest /diagnostics."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray

        from mr_ident.ros.messages import RESULT_QOS
        from mr_ident_msgs.msg import Estimate

        self.rclpy = rclpy
        rclpy.init()
        self.node = rclpy.create_node("soak_monitor")
        self.estimates: list[float] = []
        self.diag: dict[str, str] = {}
        self.level = 0
        self.levels: dict[int, int] = {}
        self.reasons: dict[str, int] = {}
        self.node.create_subscription(  # the node's one message per estimate
            Estimate,
            "/mr_ident/estimate",
            lambda m: self.estimates.append(time.monotonic()),
            RESULT_QOS,
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 10)

    def _diag(self, m) -> None:  # type: ignore[no-untyped-def]
        st = m.status[0]
        self.diag = {kv.key: kv.value for kv in st.values}
        self.level = st.level[0]
        self.levels[self.level] = self.levels.get(self.level, 0) + 1
        if self.level:
            self.reasons[st.message] = self.reasons.get(st.message, 0) + 1

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.shutdown()


def check_recording(path: Path) -> dict[str, object]:
    """Per topic: messages, samples, and whether the blocks' indices are contiguous from 0."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, dict[str, int]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, channel, _message, msg in reader.iter_decoded_messages(log_time_order=False):
            st = out.setdefault(
                channel.topic.strip("/"),
                {"messages": 0, "samples": 0, "out_of_place": 0, "next": 0},
            )
            first, n = int(msg.data[0]), msg.layout.dim[0].size
            if first != st["next"]:
                st["out_of_place"] += 1
            st["next"] = max(st["next"], first + n)
            st["messages"] += 1
            st["samples"] += n
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--minutes",
        type=float,
        default=float(os.environ.get("SOAK_MINUTES", 30)),
        help="wall-clock length (default 30, or $SOAK_MINUTES)",
    )
    ap.add_argument(
        "--rate",
        type=float,
        default=400.0,
        help="simulation speed-up: R x 240 samples/s per topic",
    )
    ap.add_argument(
        "--window-s", type=float, default=600.0, help="node window, s of loop time (default 600)"
    )
    ap.add_argument(
        "--update-s", type=float, default=2.0, help="node update period, wall s (default 2)"
    )
    ap.add_argument("--out-dir", type=Path, default=ROOT / "out" / "soak")
    args = ap.parse_args()

    from domain_coordinator import domain_id

    args.out_dir.mkdir(parents=True, exist_ok=True)
    rec_path = args.out_dir / "soak.mcap"
    rec_path.unlink(missing_ok=True)
    seconds = args.minutes * 60.0
    loop_s = seconds * args.rate
    with domain_id() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        os.environ.update(ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        log = open(args.out_dir / "soak.log", "w")
        node = subprocess.Popen(
            [
                str(BIN / "mr-ident-node"),
                "--ros-args",
                "-p",
                "autostart:=true",
                "--params-file",
                str(ROOT / "config" / "node.yaml"),
                "-p",
                f"window_s:={args.window_s}",
                "-p",
                f"min_window_s:={args.window_s}",
                "-p",
                f"update_period_s:={args.update_s}",
                "-p",
                "reorder_blocks:=64",
            ],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        recorder = subprocess.Popen(
            [str(BIN / "mr-ident"), "record", str(rec_path)],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        mon = Monitor()
        mon.spin(2.0)
        sim = subprocess.Popen(
            [
                str(BIN / "mr-ident-sim"),
                str(MODEL),
                "--rate",
                str(args.rate),
                "--block",
                str(BLOCK),
                "--duration",
                str(loop_s),
                "--subscribers",
                "2",
                "--wait",
                "20",
            ],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        procs = {"sim": sim, "node": node, "recorder": recorder}
        print(
            f"# soak: {args.minutes:g} min wall, paper example at {args.rate:g}x real time "
            f"({args.rate * FS / 1e3:g} k samples/s per topic, {BLOCK}-sample blocks), node "
            "window "
            f"{args.window_s:g} s of loop time, update every {args.update_s:g} s; domain {dom}",
            flush=True,
        )
        rss: dict[str, list[tuple[float, float]]] = {k: [] for k in procs}
        t0 = time.monotonic()
        fill_s = args.window_s / args.rate + 5.0  # the node's window is full after this (wall)
        next_print = 60.0
        try:
            while sim.poll() is None and time.monotonic() - t0 < seconds + 120:
                mon.spin(5.0)
                t = time.monotonic() - t0
                for k, p in procs.items():
                    rss[k].append((t, rss_mb(p.pid)))
                if t >= next_print:
                    next_print += 300.0
                    d = mon.diag
                    print(
                        f"  {t / 60:5.1f} min: node RSS {rss['node'][-1][1]:.0f} MB, recorder "
                        f"{rss['recorder'][-1][1]:.0f} MB, sim {rss['sim'][-1][1]:.0f} MB; "
                        "aligned to "
                        f"{d.get('window_end_index')}, estimates {len(mon.estimates)}, gaps "
                        f"{[d.get(s + '.gaps') for s in STREAMS]}",
                        flush=True,
                    )
            sim_rc = sim.wait(60)
            mon.spin(max(3.0, 2 * args.update_s))
            final = dict(mon.diag)
            final_level = mon.level
        finally:
            for p in (node, recorder, sim):
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            for p in (node, recorder, sim):
                try:
                    p.wait(60)
                except subprocess.TimeoutExpired:
                    p.kill()
            mon.close()
            log.close()
    wall = time.monotonic() - t0
    sent = (
        -(-int(round(loop_s * FS)) // BLOCK) * BLOCK
    )  # the sim sends whole blocks until it has enough
    node_in = {s: int(final.get(f"{s}.samples", -1)) for s in STREAMS}
    node_gaps = {s: int(final.get(f"{s}.gaps", -1)) for s in STREAMS}
    rec = check_recording(rec_path)
    ticks = np.diff(mon.estimates)

    def first_last(k: str) -> tuple[float, float, float]:
        pts = [(t, v) for t, v in rss[k] if t >= fill_s and v > 0] or rss[k]
        vals = [v for _, v in pts]
        return vals[0], vals[-1], max(vals)

    result = {
        "minutes_wall": wall / 60,
        "rate_x": args.rate,
        "samples_per_s_per_topic": args.rate * FS,
        "samples_sent_per_topic": sent,
        "sim_exit": sim_rc,
        "node_exit": node.returncode,
        "recorder_exit": recorder.returncode,
        "node_samples": node_in,
        "node_gaps": node_gaps,
        "node_level_at_end": final_level,
        "diagnostic_levels_seen": mon.levels,
        "warn_reasons": dict(list(mon.reasons.items())[:10]),
        "recording": {k: {kk: vv for kk, vv in v.items() if kk != "next"} for k, v in rec.items()},
        "recording_bytes": rec_path.stat().st_size,
        "estimates": len(mon.estimates),
        "estimate_interval_s": {
            "median": float(np.median(ticks)) if ticks.size else None,
            "p99": float(np.percentile(ticks, 99)) if ticks.size else None,
            "max": float(ticks.max()) if ticks.size else None,
        },
        "rss_mb": {
            k: dict(zip(("start", "end", "max"), first_last(k), strict=False)) for k in procs
        },
        "rss_start_at_s": next((t for t, _ in rss["node"] if t >= fill_s), None),
    }
    lost_node = {s: sent - node_in[s] for s in STREAMS}
    lost_rec = {s: sent - rec.get(s, {}).get("samples", 0) for s in STREAMS}
    ok = (
        all(v == 0 for v in lost_node.values())
        and all(v == 0 for v in node_gaps.values())
        and all(v == 0 for v in lost_rec.values())
        and all(rec.get(s, {}).get("out_of_place", 1) == 0 for s in STREAMS)
    )
    result.update(lost_samples_node=lost_node, lost_samples_recording=lost_rec, zero_loss=ok)
    (args.out_dir / "soak.json").write_text(json.dumps(result, indent=2))
    r = result["rss_mb"]
    print(
        f"soak: {wall / 60:.1f} min wall, {sent} samples per topic ({sent / FS / 3600:.1f} h of "
        "loop time) "
        f"at {args.rate * FS / 1e3:g} k samples/s per topic"
    )
    print(
        f"  lost samples by index: node {lost_node} (gaps {node_gaps}), recording {lost_rec}; "
        f"{'ZERO LOSS' if ok else 'LOSS'}"
    )
    print(
        "  RSS MB (start after the window filled -> end, max): "
        + ", ".join(
            f"{k} {v['start']:.0f} -> {v['end']:.0f} (max {v['max']:.0f})" for k, v in r.items()
        )
    )
    iv = result["estimate_interval_s"]
    print(
        f"  estimates: {len(mon.estimates)}, interval median {iv['median']:.2f} s, p99 "
        f"{iv['p99']:.2f} s, "
        f"max {iv['max']:.2f} s (update_period_s {args.update_s:g})"
        if ticks.size
        else "  estimates: none"
    )
    print(
        f"  recording {rec_path} {rec_path.stat().st_size / 1e9:.2f} GB; exits: sim {sim_rc}, "
        "node "
        f"{node.returncode}, recorder {recorder.returncode}; wrote {args.out_dir / 'soak.json'}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
