# SPDX-License-Identifier: Apache-2.0
"""SIGINT/SIGTERM at chosen moments: every ROS program exits 0 with its outputs finalised.

A few runs of ``scripts/stress_signals.py`` (which runs >= 50 per program, outside the suite),
including a signal at the start (before rclpy is even imported) and one mid-stream.
"""

from __future__ import annotations

import importlib.util
import signal
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
from domain_coordinator import domain_id  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "stress_signals", ROOT / "scripts" / "stress_signals.py"
)
assert _spec is not None and _spec.loader is not None
stress = importlib.util.module_from_spec(_spec)
sys.modules["stress_signals"] = stress  # dataclasses look their module up there
_spec.loader.exec_module(stress)


@pytest.mark.parametrize(
    ("program", "delay", "sig", "after_output"),
    [
        ("record", 0.25, signal.SIGTERM, False),  # before rclpy is imported: a finalised file
        ("record", 1.5, signal.SIGTERM, True),  # while messages are written
        ("node", 0.3, signal.SIGTERM, False),  # during start-up (warm-up running)
        ("node", 2.5, signal.SIGINT, True),  # while estimating and recording
        ("sim", 2.5, signal.SIGTERM, False),  # while publishing
    ],
)
def test_program_signalled_exits_0_with_its_outputs_finalised(
    tmp_path, program, delay, sig, after_output
):
    """A mid-stream signal comes ``delay`` s after the program's output file appeared (its
    start-up done, however slow the machine), not after a fixed time from its start.

    A program killed by the signal with nothing on stderr got it before its interpreter
    reached the handler (no program can handle that: on a loaded machine, start-up alone
    can outlast the delay); such a run is repeated with twice the delay, twice at most. A
    program that never installs its handler dies so at every delay and fails."""
    for attempt in range(3):
        with domain_id() as dom:
            outcome = stress.signal_run(
                program, delay, sig, tmp_path / str(attempt), dom, after_output=after_output
            )
        too_early = outcome.returncode == -sig and "stderr tail" not in outcome.problem
        if not too_early:
            break
        delay *= 2
    assert outcome.ok, outcome.problem


def test_a_signal_while_the_interpreter_finalises_does_not_kill_a_finished_program():
    """The program's work is done, its interpreter is tearing down (here a destructor that
    takes 2 s, as DDS teardown can): a SIGINT then leaves the exit status 0 (it was -2: the
    interpreter resets Python-level handlers to the default before clearing modules)."""
    import subprocess
    import time

    code = (
        "import time\n"
        "from mr_ident.ros.program import handle_signals\n"
        "class Slow:\n"
        "    def __del__(self):\n"
        "        time.sleep(2.0)\n"  # a destructor at module teardown, after the handlers
        "keep = Slow()\n"  # were reset (as rclpy's and DDS's objects)
        "handle_signals()\n"
        "print('done', flush=True)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "done"
    time.sleep(0.7)  # inside the destructor
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
