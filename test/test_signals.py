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
    ("program", "delay", "sig"),
    [
        ("record", 0.25, signal.SIGTERM),  # before rclpy is imported: still a finalised file
        ("record", 2.0, signal.SIGTERM),  # while messages are written
        ("node", 0.3, signal.SIGTERM),  # during start-up (warm-up running)
        ("node", 4.0, signal.SIGINT),  # while estimating and recording
        ("sim", 2.5, signal.SIGTERM),  # while publishing
    ],
)
def test_program_signalled_exits_0_with_its_outputs_finalised(tmp_path, program, delay, sig):
    with domain_id() as dom:
        outcome = stress.signal_run(program, delay, sig, tmp_path, dom)
    assert outcome.ok, outcome.problem
