# SPDX-License-Identifier: Apache-2.0
"""Progress of a long command on stderr (cli.common.Progress): only steps that outlast
``after``, only on a terminal, never with ``quiet``."""

from __future__ import annotations

import io
import time
from pathlib import Path

import pytest

from mr_ident.cli.common import Progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _run(monkeypatch, stream, quiet=False):
    monkeypatch.setattr("sys.stderr", stream)
    monkeypatch.setattr(Progress, "after", 0.05)
    with Progress(quiet=quiet) as progress:
        progress("a quick step")
        progress("a slow step")  # the quick one ends here, before 0.05 s
        time.sleep(1.0)
        progress("the last step")  # ends at once with the context
    time.sleep(0.1)
    return stream.getvalue()


def test_a_step_that_outlasts_its_time_is_told_once_and_a_quick_one_never(monkeypatch):
    out = _run(monkeypatch, _Terminal())
    assert out.count("\n") == 1 and "a slow step ..." in out and out.startswith("mr-ident: ")


def test_quiet_or_not_a_terminal_tells_nothing(monkeypatch):
    assert _run(monkeypatch, _Terminal(), quiet=True) == ""
    assert _run(monkeypatch, io.StringIO()) == ""


def test_a_long_step_is_told_again_while_it_lasts(monkeypatch):
    stream = _Terminal()
    monkeypatch.setattr("sys.stderr", stream)
    monkeypatch.setattr(Progress, "after", 0.05)
    monkeypatch.setattr(Progress, "every", 0.2)
    with Progress() as progress:
        progress("a long step")
        time.sleep(0.55)
    time.sleep(0.3)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 3 and all("a long step ..." in line for line in lines)


@pytest.mark.parametrize("command", ["identify", "replay", "diagnose", "fit", "batch"])
def test_every_long_command_takes_quiet(command):
    from mr_ident.cli.parser import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert "--quiet" in sub.choices[command].format_help()  # type: ignore[union-attr]


def test_identify_tells_its_steps_on_a_terminal_and_nothing_with_quiet(
    monkeypatch, tmp_path, capsys
):
    """The steps of ``identify`` reach the one progress display (the steps outlast 0 s)."""
    from mr_ident.cli import main

    paper = Path(__file__).resolve().parents[1] / "config" / "paper_example.yaml"
    data = tmp_path / "d.npz"
    assert main(["simulate", str(paper), "--duration", "10", "--out", str(data)]) == 0
    told = []
    monkeypatch.setattr(Progress, "__call__", lambda self, step: told.append(step))
    argv = ["identify", str(data), "--out", str(tmp_path / "r.npz")]
    assert main(argv) == 0
    assert told[0] == f"reading {data}" and told[1].startswith("identifying P_h from 2400 ")
    assert told[-1] == f"writing {tmp_path / 'r.npz'}"
    capsys.readouterr()
    monkeypatch.undo()
    monkeypatch.setattr("sys.stderr", _Terminal())
    monkeypatch.setattr(Progress, "after", 0.0)
    assert main([*argv, "--quiet"]) == 0
    assert "mr-ident:" not in capsys.readouterr().err


def test_replay_tells_its_steps_and_the_monitoring_as_one(monkeypatch, tmp_path, capsys):
    """``replay`` with ``monitor_model``: the replay, then the watch of the plant, each
    window a step of the display (silent for half a minute on a long bag before)."""
    from bagmaker import joint_state_bag, stamps

    from mr_ident.cli import main
    from mr_ident.io.datafile import read_data

    root = Path(__file__).resolve().parents[1]
    data = tmp_path / "d.npz"
    robot = root / "config" / "tutorial_robot.yaml"
    assert main(["simulate", str(robot), "--duration", "20", "--out", str(data)]) == 0
    sim = read_data(data)
    bag = joint_state_bag(tmp_path / "js", sim, stamps(sim.n_samples, 240.0))
    told: list[str] = []
    monkeypatch.setattr(Progress, "__call__", lambda self, step: told.append(step))
    monkeypatch.chdir(root)  # the params file names the model relative to the repository
    argv = ["replay", str(bag), "--params", "config/tutorial_monitor.yaml"]
    argv += ["--r", '/ident/reference.position{name=="j1"}']
    argv += [
        "--u",
        '/joint_states.effort{name=="j1"}',
        "--y",
        '/joint_states.position{name=="j1"}',
    ]
    assert main([*argv, "--out", str(tmp_path / "w.npz")]) == 0
    assert told[0] == f"replaying {bag} through the node's steps"
    watched = [t for t in told if t.startswith("monitoring: window ")]
    assert watched[0] == "monitoring: window 1 of 3, at 10 s of the recording", told
    assert watched[-1] == "monitoring: window 3 of 3, at 20 s of the recording"
    assert "plant gain 1.2" in capsys.readouterr().out
