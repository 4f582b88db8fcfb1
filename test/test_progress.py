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
