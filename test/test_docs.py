# SPDX-License-Identifier: Apache-2.0
"""The documentation keeps its promises: the tutorial's commands run, the README stays short.

Every shell command of ``docs/tutorial.md`` (its fenced ``bash`` and ``console`` blocks; in a
``console`` block a command is a line starting with ``$ `` and the lines after it are what it
prints) is run in a temporary directory, in the page's order, with the environment's
programs on PATH and ``config/`` and ``scripts/`` of the repository beside it: each must
exit 0 within its timeout, print every ``wrote ...`` line the page shows, and leave every
file under ``out/tutorial/`` that the page names. ``text`` blocks (set-up, the robot, a
server that runs until Ctrl-C) are not run.
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
OUT_PATH = re.compile(r"out/tutorial/[\w./-]*\w")


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


def test_every_command_of_the_tutorial_runs_and_writes_what_the_page_says(tmp_path):
    commands = shell_commands(TUTORIAL.read_text())
    assert len(commands) >= 8, f"docs/tutorial.md: expected at least 8 commands, got {commands}"
    env = tutorial_environment(tmp_path)
    for command in commands:
        where = f"docs/tutorial.md line {command.line}: {command.text}"
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
        assert done.returncode == 0, f"{where}: exit {done.returncode}\n{done.stderr}"
        printed = done.stdout.splitlines()
        for line in command.shown:
            if line.startswith("wrote "):
                assert line in printed, f"{where}: the page shows {line!r}, it printed {printed}"
        named = OUT_PATH.findall(command.text) + OUT_PATH.findall("\n".join(command.shown))
        for path in named:
            assert (tmp_path / path).exists(), f"{where}: {path} was not written"
    assert (tmp_path / "out/tutorial/robot_found.yaml").read_text().count("plant_gain") == 1


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
