# SPDX-License-Identifier: Apache-2.0
"""A user's first hour: commands work as the pages write them, every program answers
``--help``, and an error names the user's path and leaves none of the outputs behind.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest
from conftest import console_script

from mr_ident.cli import main
from mr_ident.cli.parser import build_parser
from mr_ident.io.atomic import atomic_write

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "d.npz"
    assert main(["simulate", str(PAPER), "--duration", "20", "--out", str(path)]) == 0
    return path


def command_options() -> dict[str, set[str]]:
    """Every ``mr-ident`` command and the options it takes."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return {
        name: {o for a in p._actions for o in a.option_strings} for name, p in sub.choices.items()
    }


def test_every_option_a_page_gives_a_command_is_one_the_command_takes():
    """``mr-ident diagnose --model M --data D`` on a page is caught (no such options)."""
    options = command_options()
    wrong = []
    for page in PAGES:
        text = re.sub(r"\\\n\s*", " ", page.read_text())  # continuation lines joined
        for number, line in enumerate(text.splitlines(), 1):
            for m in re.finditer(r"mr-ident ([a-z]+)([^`|\n]*)", line):
                if m.group(1) not in options:
                    continue
                for flag in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", m.group(2)):
                    if flag not in options[m.group(1)]:
                        wrong.append(f"{page.name}:{number}: mr-ident {m.group(1)} {flag}")
    assert not wrong, "options the commands do not take:\n" + "\n".join(wrong)


def test_the_readme_puts_the_programs_on_path_before_its_tour_uses_them():
    text = (ROOT / "README.md").read_text()
    tour = text[text.index("## A five-minute tour") :]
    activate = tour.find("source .venv/bin/activate")
    first = re.search(r"^mr-ident", tour, flags=re.M)
    assert activate >= 0 and first is not None and activate < first.start()


@pytest.mark.parametrize("program", ["mr-ident-node", "mr-ident-sim", "mr-ident"])
def test_every_program_answers_help_and_exits_without_starting(program, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env["ROS_LOG_DIR"] = str(tmp_path)
    done = subprocess.run(
        [console_script(program), "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: {program}"), done.stdout[:200]
    assert "[INFO]" not in done.stdout + done.stderr  # the node did not start (no ROS log)


def test_the_nodes_help_names_every_parameter():
    from mr_ident.io.config import PARAMETERS
    from mr_ident.ros.entry import node_usage, wants_help

    text = node_usage()
    assert all(re.search(rf"^  {name} ", text, flags=re.M) for name in PARAMETERS)
    assert wants_help(["--help"]) and wants_help(["-h", "--ros-args"])
    assert not wants_help(["--ros-args", "-p", "x:=1", "--help"])  # ROS's own


def test_diagnose_prints_its_verdict_without_json_and_writes_nothing(
    monkeypatch, data, tmp_path, capsys
):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "diagnose", PAPER, data)
    assert code == 0, err
    assert out.startswith("cause: none") and "verdict:" in out
    assert "wrote" not in out and list(tmp_path.iterdir()) == []


def test_an_output_in_a_missing_folder_is_one_line_naming_it(monkeypatch, data, tmp_path, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "simulate", PAPER, "--duration", 5, "--out", "nodir/x.npz")
    assert code == 2
    assert err == "error: nodir/x.npz: cannot write it: the folder 'nodir' does not exist\n"
    assert ".tmp" not in err


IDENTIFY = ["identify", "{data}", "--ratio", "3"]
DIAGNOSE = ["diagnose", str(PAPER), "{data}"]


@pytest.mark.parametrize(
    "argv",
    [
        [*IDENTIFY, "--out", "r.npz", "--plot", "no/p.png"],
        [*IDENTIFY, "--out", "no/r.npz", "--plot", "p.png"],
        [*IDENTIFY, "--out", "r.npz", "--plot", "no/p.xyz"],
        [*DIAGNOSE, "--report", "r.html", "--json", "no/r.json"],
        [*DIAGNOSE, "--json", "r.json", "--out-model", "no/m.yaml"],
    ],
)
def test_a_command_that_cannot_write_an_output_writes_none_of_them(
    monkeypatch, data, tmp_path, capsys, argv
):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *[a.replace("{data}", str(data)) for a in argv])
    assert code == 2 and "the folder 'no' does not exist" in err, err
    assert out == ""  # refused before anything was computed
    assert list(tmp_path.iterdir()) == []


def test_a_plot_in_an_unknown_format_is_refused_before_anything_is_written(
    monkeypatch, data, tmp_path, capsys
):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(
        capsys, *IDENTIFY[:1], data, *IDENTIFY[2:], "--out", "r.npz", "--plot", "p.xyz"
    )
    assert code == 2 and err.startswith("error: --plot must be an image file (.png, "), err
    assert out == "" and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_model_file_that_is_not_yaml_is_refused_before_anything_is_computed(
    monkeypatch, data, tmp_path, capsys, command
):
    monkeypatch.chdir(tmp_path)
    argv = {
        "fit": ["fit", data, "--out", "m.txt"],
        "diagnose": ["diagnose", PAPER, data, "--out-model", "m.txt"],
    }[command]
    code, out, err = run(capsys, *argv)
    assert code == 2 and "must be a model file (.yaml or .yml), got 'm.txt'" in err, err
    assert out == "" and list(tmp_path.iterdir()) == []


def test_atomic_write_names_the_users_path_never_its_temporary_file(tmp_path):
    target = tmp_path / "nodir" / "x.npz"
    with pytest.raises(FileNotFoundError, match="the folder .* does not exist") as info:
        atomic_write(target, lambda fh: fh.write(b"x"), binary=True)
    assert info.value.filename == str(target)


@pytest.mark.parametrize("sources", [True, False])
def test_a_recording_that_does_not_exist_is_said_so(monkeypatch, tmp_path, capsys, sources):
    monkeypatch.chdir(tmp_path)
    given = ["--r", "/a.x", "--u", "/a.y", "--y", "/a.z"] if sources else []
    code, out, err = run(capsys, "identify", "run2", "--ratio", 3, *given, "--out", "r.npz")
    assert code == 2
    assert err.startswith("error: 'run2' does not exist (a data file"), err
    assert "is a data file" not in err
