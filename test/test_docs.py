# SPDX-License-Identifier: Apache-2.0
"""The documentation keeps its promises: every page's commands run, the README stays short.

Every shell command of every page of ``docs/`` (its fenced ``bash`` and ``console`` blocks;
in a ``console`` block a command is a line starting with ``$ `` and the lines after it are
what it prints) is run in a temporary directory, in the page's order, with the
environment's programs on PATH and ``config/`` and ``scripts/`` of the repository beside
it: each must exit 0 within its timeout (2 where the page shows its ``error:``), print
every line the page shows with each figure within 2 % or one unit of the page's last digit
(compute times and round-off levels are illustrative: :data:`ILLUSTRATIVE`), and leave
every file under ``out/<page>/`` it names. ``text`` blocks (set-up on a robot, synopses, a
server that runs until Ctrl-C) are not run; figures shown outside a ``console`` block are
measured tables with the command that makes them (benchmarks, robustness, the method's
tables) or say that they vary from run to run (the demo's line).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIAL = DOCS / "tutorial.md"
README = ROOT / "README.md"
README_MAX_LINES = 250
COMMAND_TIMEOUT_S = 120.0  # each command takes seconds; this bounds a hang

FENCE = re.compile(r"^```(\w*)\s*$")
OUT_PATH = re.compile(r"out/[a-z]+/[\w./-]*\w")


@dataclass
class Command:
    """One shell command of a page and the output lines the page shows after it."""

    text: str
    line: int
    shown: list[str] = field(default_factory=list)


def fenced_blocks(text: str) -> list[tuple[str, int, list[str]]]:
    """``(info, first line number, lines)`` of every fenced block of a Markdown text."""
    blocks: list[tuple[str, int, list[str]]] = []
    info: str | None = None
    start, body = 0, []
    for number, line in enumerate(text.splitlines(), 1):
        m = FENCE.match(line)
        if info is None and m:
            info, start, body = m.group(1), number + 1, []
        elif info is not None and line.startswith("```"):
            blocks.append((info, start, body))
            info = None
        elif info is not None:
            body.append(line)
    if info is not None:
        raise ValueError(f"a fenced block opened at line {start - 1} is never closed")
    return blocks


def shell_commands(text: str) -> list[Command]:
    """The commands of a page's ``bash`` and ``console`` blocks, continuation lines
    (ending in a backslash) joined, in the page's order."""
    commands: list[Command] = []
    for info, start, body in fenced_blocks(text):
        if info not in ("bash", "console"):
            continue
        pending: Command | None = None
        for offset, line in enumerate(body):
            if pending is not None and pending.text.endswith("\\"):
                pending.text = pending.text[:-1].rstrip() + " " + line.strip()
                continue
            if info == "bash" and line.strip() and not line.lstrip().startswith("#"):
                pending = Command(line.strip(), start + offset)
                commands.append(pending)
            elif info == "console" and line.startswith("$ "):
                pending = Command(line[2:].strip(), start + offset)
                commands.append(pending)
            elif info == "console" and pending is not None and line.strip():
                pending.shown.append(line.rstrip())
    return commands


def test_the_parser_joins_continuations_and_keeps_what_a_command_prints():
    page = (
        "```console\n$ echo a \\\n    b\nwrote x\n$ true\n```\n"
        "```text\nnot run\n```\n```bash\n# a comment\nls\n```\n"
    )
    commands = shell_commands(page)
    assert [c.text for c in commands] == ["echo a b", "true", "ls"]
    assert commands[0].shown == ["wrote x"] and commands[1].shown == []
    with pytest.raises(ValueError, match="never closed"):
        fenced_blocks("```bash\nls\n")


def tutorial_environment(tmp: Path) -> dict[str, str]:
    """The tutorial's working directory (``config/``, ``scripts/`` linked) and its env."""
    for name in ("config", "scripts"):
        (tmp / name).symlink_to(ROOT / name, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_DOMAIN")}
    bin_dir = str(Path(sys.executable).parent)
    env["PATH"] = bin_dir + os.pathsep + env.get("PATH", "")
    env["MPLBACKEND"] = "Agg"
    env["ROS_LOG_DIR"] = str(tmp / "ros_log")
    return env


#: A number as a page prints it: 14400, -64.7, 0.0088, 1.4e-05, 1.1999766501546003.
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?![\w])")
#: Figures a page shows for illustration only, not compared: a compute time at the end of
#: a line (``0.142 s``), a round-off level (``to 8e-16 of it``), the bands of a drift (their
#: edges are bins where the test statistic crosses its threshold: ``drift 1.6 dB at ...``).
ILLUSTRATIVE = [
    re.compile(r"\d+(?:\.\d+)? s$"),
    re.compile(r"to \S+ of it"),
    re.compile(r"(?<=dB at ).*Hz$"),
]
#: How close a printed figure must come to the page's: 2 % of it, or one unit in the page's
#: last digit where that is more (the page rounds; other BLAS kernels move the last digit).
REL_TOL = 0.02


def _masked(line: str) -> str:
    for pattern in ILLUSTRATIVE:
        line = pattern.sub("#", line)
    return line


def _skeleton(line: str) -> str:
    return NUMBER.sub("N", _masked(line)).strip()


def _close(shown: str, printed: str) -> bool:
    a, b = float(shown), float(printed)
    mantissa = shown.lower().split("e")[0]
    digits = len(mantissa.split(".")[1]) if "." in mantissa else 0
    unit = 10.0**-digits * (
        10.0 ** int(shown.lower().split("e")[1]) if "e" in shown.lower() else 1
    )
    return abs(a - b) <= max(REL_TOL * abs(a), unit) * (1 + 1e-9)


def figures_differ(shown: str, printed: list[str]) -> str | None:
    """Why the page's line ``shown`` is not among the ``printed`` ones within the tolerance,
    or None: a printed line of its words, every figure within :data:`REL_TOL` or the page's
    last digit (:data:`ILLUSTRATIVE` figures aside)."""
    same = [p for p in printed if _skeleton(p) == _skeleton(shown)]
    if not same:
        return f"the page shows {shown!r}; nothing printed reads so: {printed}"
    want = NUMBER.findall(_masked(shown))
    for p in same:
        got = NUMBER.findall(_masked(p))
        if all(_close(w, g) for w, g in zip(want, got, strict=True)):
            return None
    return f"the page shows {shown!r}; it printed {same[0]!r} (beyond {REL_TOL:.0%})"


def test_the_figure_check_takes_the_pages_rounding_and_its_tolerance():
    printed = ["PFG from data: peak -64.71 dB at 15.31 Hz, median std 0.121 %, 0.9 s"]
    assert (
        figures_differ(
            "PFG from data: peak -64.7 dB at 15.28 Hz, median std 0.12 %, 0.1 s", printed
        )
        is None
    )
    assert "beyond" in figures_differ(
        "PFG from data: peak -64.7 dB at 15.28 Hz, median std 0.29 %, 0.1 s", printed
    )
    assert "nothing printed" in figures_differ("PFG from P_h: peak -64.7 dB", printed)
    assert _close("1.4e-05", "1.5e-05") and not _close("1.4e-05", "1.7e-05")


def run_page(page: Path, tmp_path: Path) -> None:
    """Run every command of ``page`` in order; each prints the page's lines (figures within
    the tolerance) and writes the files under out/ it names."""
    commands = shell_commands(page.read_text())
    env = tutorial_environment(tmp_path)
    for command in commands:
        where = f"docs/{page.name} line {command.line}: {command.text}"
        try:
            done = subprocess.run(
                ["bash", "-c", command.text],
                cwd=tmp_path,
                env=env,
                capture_output=True,
                text=True,
                timeout=COMMAND_TIMEOUT_S,
                stdin=subprocess.DEVNULL,
            )
        except subprocess.TimeoutExpired:
            pytest.fail(f"{where}: still running after {COMMAND_TIMEOUT_S} s")
        refused = any(line.startswith("error: ") for line in command.shown)
        if refused:  # the page shows the error a wrong command gets: exit 2, nothing else
            assert done.returncode == 2, (
                f"{where}: the page shows an error, exit {done.returncode}"
            )
        else:
            assert done.returncode == 0, f"{where}: exit {done.returncode}\n{done.stderr}"
        printed = done.stdout.splitlines() + done.stderr.splitlines()
        for line in command.shown:
            problem = figures_differ(line, printed)
            assert problem is None, f"{where}: {problem}"
        named = OUT_PATH.findall(command.text) + OUT_PATH.findall("\n".join(command.shown))
        for path in named:
            assert (tmp_path / path).exists(), f"{where}: {path} was not written"


RUN_PAGES = sorted(p for p in DOCS.glob("*.md") if shell_commands(p.read_text()))


@pytest.mark.parametrize("page", RUN_PAGES, ids=[p.name for p in RUN_PAGES])
def test_every_command_of_every_page_runs_and_prints_what_the_page_says(page, tmp_path):
    """The ``console`` and ``bash`` blocks of every page (``text`` blocks: set-up on a
    robot, synopses, a server that runs until Ctrl-C; not run)."""
    run_page(page, tmp_path)
    if page == TUTORIAL:
        assert len(shell_commands(TUTORIAL.read_text())) >= 8
        found = (tmp_path / "out/tutorial/robot_found.yaml").read_text()
        fitted = (tmp_path / "out/tutorial/fitted.yaml").read_text()
        assert found.count("plant_gain") == 1 and "fs_high: 240\n" in fitted
        assert found.endswith("units:\n  u: N\n  y: m\n") and "units:\n  u: N\n" in fitted


def test_the_tutorial_and_the_pages_with_examples_are_run():
    pages = {
        TUTORIAL.name,
        "setpoint.md",
        "sources.md",
        "excitation.md",
        "diagnose.md",
        "monitoring.md",
    }
    assert pages | {"commands.md"} <= {p.name for p in RUN_PAGES}


def test_every_page_of_the_docs_is_in_the_site_and_every_linked_image_exists():
    nav = (ROOT / "mkdocs.yml").read_text()
    for page in sorted(DOCS.glob("*.md")):
        assert f": {page.name}" in nav, f"mkdocs.yml: nav lacks docs/{page.name}"
        for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text()):
            assert (DOCS / image).is_file(), f"docs/{page.name}: image {image} missing"


def test_module_paths_are_named_on_the_architecture_page_only():
    module = re.compile(
        r"mr_ident/(numerics|io|live|diagnosis|ros|view|cli)\b"
        r"|mr_ident\.(numerics|io|live|diagnosis|ros|view|cli)\."
        r"|`(numerics|io|live|diagnosis|ros|view|cli|app)/[\w/]*\.py`"  # the package's own
        r"|`(allocator|threads|budget|catalog|lti|simulate|objective)\.py`"
    )
    for page in [README, *sorted(DOCS.glob("*.md"))]:
        if page.name == "architecture.md":
            continue
        hits = [
            n for n, line in enumerate(page.read_text().splitlines(), 1) if module.search(line)
        ]
        assert not hits, f"{page.name}: module paths on lines {hits}; name them in architecture.md"


def test_the_readme_stays_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md: at most {README_MAX_LINES} lines, got {len(lines)}; move the material "
        "into a page under docs/"
    )


def makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text()
    return set(re.findall(r"^([A-Za-z0-9_-]+)\s*:(?!=)", text, flags=re.M))


def test_every_make_command_of_the_readme_and_the_docs_is_a_target_of_the_makefile():
    targets = makefile_targets()
    assert {"demo", "test", "docs", "lint"} <= targets
    for page in [README, *sorted(DOCS.glob("*.md"))]:
        named = set(re.findall(r"(?:^|`)make ([a-z][a-z0-9-]*)", page.read_text(), flags=re.M))
        missing = named - targets
        assert not missing, f"{page.name}: `make {sorted(missing)}` is not a Makefile target"


def test_the_readme_links_to_pages_that_exist():
    links = re.findall(r"\]\((docs/[^)#]+)(?:#[^)]*)?\)", README.read_text())
    assert len(links) >= 10
    for link in links:
        assert (ROOT / link).is_file(), f"README.md links to {link}, which does not exist"
