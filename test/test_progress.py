# SPDX-License-Identifier: Apache-2.0
"""Progress of a long command on stderr (cli.common.Progress): only steps that outlast
``after``, only on a terminal, never with ``quiet``."""

from __future__ import annotations

import io
import time

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
