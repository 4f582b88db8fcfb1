# SPDX-License-Identifier: Apache-2.0
"""Signal each ROS program of mr_ident at random moments; every run must exit 0, print no
traceback and leave its outputs finalised.

    .venv/bin/python scripts/stress_signals.py [--runs 50] [--programs record,node,sim,demo]
                                               [--seed 0] [--out-dir out/stress]

Programs and what "finalised" means:

* ``record``: ``mr-ident record`` while a simulator publishes; the MCAP file exists and
  has its summary (``mcap`` reader), whatever moment the signal came.
* ``node``: ``mr-ident-node`` with ``record_path`` while a simulator publishes; same
  check on the node's recording.
* ``sim``: ``mr-ident-sim`` publishing (with a listener); exit 0, no traceback.
* ``demo``: ``mr-ident demo``; exit 0, no traceback; its ``live.mcap``, when the node
  got to create it, has its summary.

Each run gets its own DDS domain (localhost only); the delay before the signal is
uniform over [start-up, the program's span] and the signal SIGINT or SIGTERM at random.
"start-up" is the measured time the interpreter needs before any of our code runs
(about 0.1 s here: the ROS wheels' ``ros_wheels_bootstrapper.pth`` re-executes the
interpreter to set LD_LIBRARY_PATH): a signal before that meets no handler of ours,
whatever the program does, and has the default effect.
Not part of ``make test`` (it takes minutes); the suite runs a few of these runs
(``test/test_signals.py``).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PAPER = ROOT / "config" / "paper_example.yaml"

#: Seconds after the start within which each program is signalled (its interesting life).
SPAN = {"record": 4.0, "node": 6.0, "sim": 4.0, "demo": 25.0}

#: Seconds a run waits for its output file to hold messages (``after_output``).
READY_TIMEOUT = 60.0


@dataclass(frozen=True)
class Outcome:
    """One signalled run."""

    program: str
    delay: float
    signal: int
    returncode: int | None
    problem: str  # "" when the run passed

    @property
    def ok(self) -> bool:
        return not self.problem


def interpreter_start(repeat: int = 5) -> float:
    """Seconds from exec until this venv's interpreter has imported mr_ident's signal
    handling (the median of ``repeat`` runs): the earliest a handler can exist."""
    times = []
    for _ in range(repeat):
        t0 = time.monotonic()
        subprocess.run([sys.executable, "-c", "import mr_ident.ros.program"], check=True)
        times.append(time.monotonic() - t0)
    return sorted(times)[len(times) // 2]


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.setdefault("ROS_LOG_DIR", str(ROOT / "out" / "ros_log"))
    return env


def _finalised(path: Path) -> str:
    """ "" when ``path`` is an MCAP file with its summary, else what is wrong."""
    from mcap.reader import make_reader

    if not path.exists():
        return f"{path.name} does not exist"
    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception as err:  # noqa: BLE001 - any reader failure is the finding
        return f"{path.name} unreadable: {type(err).__name__}: {err}"
    return "" if summary is not None else f"{path.name} has no summary (not finalised)"


def _feeder(env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "mr-ident-sim"), str(PAPER), "--rate", "20", "--wait", "20", "--block", "240"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def _command(program: str, work: Path) -> tuple[list[str], Path | None]:
    if program == "record":
        out = work / "rec.mcap"
        return [str(BIN / "mr-ident"), "record", str(out)], out
    if program == "node":
        out = work / "node.mcap"
        return [
            str(BIN / "mr-ident-node"),
            "--ros-args",
            "-p",
            "autostart:=true",
            "-p",
            f"record_path:={out}",
            "-p",
            "window_s:=5.0",
            "-p",
            "min_window_s:=5.0",
            "-p",
            "update_period_s:=0.2",
        ], out
    if program == "sim":
        return [
            str(BIN / "mr-ident-sim"),
            str(PAPER),
            "--rate",
            "20",
            "--wait",
            "0",
            "--block",
            "240",
        ], None
    if program == "demo":
        return [
            str(BIN / "mr-ident"),
            "demo",
            "--out-dir",
            str(work),
            "--timeout",
            "60",
        ], work / "live.mcap"
    raise ValueError(f"program must be one of {sorted(SPAN)}, got {program!r}")


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float) -> None:
    """Until ``path`` exists (the program is past its start-up: its subscriptions made, its
    writer open; the writer buffers, so the size tells nothing yet), ``proc`` ended or
    ``timeout`` s passed, polling every 20 ms."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if path.exists():
            return
        time.sleep(0.02)


def signal_run(
    program: str,
    delay: float,
    sig: int,
    work: Path,
    domain: int,
    *,
    after_output: bool = False,
) -> Outcome:
    """Start ``program`` in ``domain``, signal it with ``sig`` after ``delay`` s, check it.

    ``after_output``: the delay counts from when the program's output file exists (waited
    for at most :data:`READY_TIMEOUT` s), not from its start: a signal "mid-stream"
    then meets the program mid-stream however slowly it started.
    """
    work.mkdir(parents=True, exist_ok=True)
    env = _env(domain)
    argv, output = _command(program, work)
    feeder = _feeder(env) if program in ("record", "node", "sim") else None
    try:
        proc = subprocess.Popen(
            argv,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )  # the signal reaches this process only
        if after_output and output is not None:
            _wait_for(output, proc, READY_TIMEOUT)
        time.sleep(delay)
        proc.send_signal(sig)
        try:
            _, stderr = proc.communicate(timeout=90)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            return Outcome(program, delay, sig, None, "did not exit within 90 s of the signal")
    finally:
        if feeder is not None:
            feeder.send_signal(signal.SIGINT)
            try:
                feeder.wait(30)
            except subprocess.TimeoutExpired:
                feeder.kill()
                feeder.wait()
    problems = []
    if proc.returncode != 0:
        problems.append(f"exit {proc.returncode}")
    if "Traceback" in stderr:
        problems.append("traceback: " + stderr.strip().splitlines()[-1])
    if output is not None and (program != "demo" or output.exists()):
        what = _finalised(output)
        if what:
            problems.append(what)
    if problems and stderr.strip():
        problems.append("stderr tail: " + " / ".join(stderr.strip().splitlines()[-3:]))
    return Outcome(program, delay, sig, proc.returncode, "; ".join(problems))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=50, help="runs per program (default 50)")
    p.add_argument("--programs", default="record,node,sim,demo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out-dir", type=Path, default=ROOT / "out" / "stress")
    args = p.parse_args(argv)
    from domain_coordinator import domain_id

    rng = random.Random(args.seed)
    start = interpreter_start()
    print(f"interpreter start (no handler can exist before): {start:.3f} s", flush=True)
    failures = 0
    for program in args.programs.split(","):
        outcomes = []
        t0 = time.monotonic()
        for k in range(args.runs):
            delay = rng.uniform(start, SPAN[program])
            sig = rng.choice([signal.SIGINT, signal.SIGTERM])
            with domain_id() as dom:
                o = signal_run(program, delay, sig, args.out_dir / program / str(k), dom)
            outcomes.append(o)
            if not o.ok:
                print(
                    f"  FAIL {program} run {k}: {signal.Signals(sig).name} after {delay:.3f} s: "
                    f"{o.problem}",
                    flush=True,
                )
        bad = [o for o in outcomes if not o.ok]
        failures += len(bad)
        print(
            f"{program:7s} {len(outcomes) - len(bad)}/{len(outcomes)} runs exited 0 with "
            "finalised outputs "
            f"(signals after {start:.2f}-{SPAN[program]:g} s; {time.monotonic() - t0:.0f} s)",
            flush=True,
        )
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
