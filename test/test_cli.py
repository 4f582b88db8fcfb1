# SPDX-License-Identifier: Apache-2.0
"""The command line: round trips and argument errors (bad files: test_corpus.py).

`error:`, exit 2, no traceback.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mr_ident.cli import main

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("suffix", ["csv", "npz"])
def test_simulate_then_identify_round_trips_with_the_pfg(tmp_path, capsys, suffix):
    data = tmp_path / f"d.{suffix}"
    assert run(capsys, "simulate", PAPER, "--duration", 30, "--seed", 1, "--out", data)[0] == 0
    res = tmp_path / "r.npz"
    extra = ["--ratio", 3] if suffix == "csv" else []
    code, out, err = run(
        capsys,
        "identify",
        data,
        "--model",
        PAPER,
        *extra,
        "--out",
        res,
        "--plot",
        tmp_path / "bode.png",
    )
    assert code == 0, err
    z = np.load(res)
    K = 7200 // 2
    assert (
        z["frequency"].shape == (K,)
        and z["P"].shape == (K, 1, 1)
        and z["P_std"].shape == (K, 1, 1)
    )
    assert z["pfg"].shape == (K,) and z["pfg_std"].shape == (K,)
    assert z["pfg_data"].shape == (K,) and z["pfg_data_std"].shape == (K,)
    assert z["frequency"][0] > 0 and z["frequency"][-1] == pytest.approx(120.0)
    assert (tmp_path / "bode.png").stat().st_size > 10_000
    assert (tmp_path / "bode_pfg.png").stat().st_size > 10_000
    assert "PFG from data" in out and "PFG from P_h and K_l" in out
    assert "the two PFGs differ by more than 3 std over" in out
    assert "controller on the machine differs" not in out


def test_identify_without_a_model_gives_the_pfg_from_data(tmp_path, capsys):
    """No controller model: the result still holds the PFG (from the lifted r -> y map),
    marked as from data, and the plot draws it."""
    data = tmp_path / "d.npz"
    assert run(capsys, "simulate", PAPER, "--duration", 30, "--seed", 1, "--out", data)[0] == 0
    res = tmp_path / "r.npz"
    code, out, err = run(capsys, "identify", data, "--out", res, "--plot", tmp_path / "bode.png")
    assert code == 0, err
    z = np.load(res)
    assert "pfg" not in z and z["pfg_data"].shape == (3600,)
    assert str(z["pfg_data_source"]).startswith("data")
    assert np.all(np.isfinite(z["pfg_data"])) and np.all(z["pfg_data_std"] > 0)
    assert "PFG from data (lifted r->y): peak" in out
    assert (tmp_path / "bode_pfg.png").stat().st_size > 10_000


def _csv(path, rows, header="t,r,u,y"):
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def _rows(n=300):
    rng = np.random.default_rng(0)
    return [f"{i / 240},{a},{b},{c}" for i, (a, b, c) in enumerate(rng.standard_normal((n, 3)))]


@pytest.mark.parametrize(
    "name,make,extra,match",
    [
        (
            "extra column",
            lambda p: _csv(p, [x + ",1" for x in _rows()], "t,r,u,y,z"),
            [],
            "unexpected column 'z'",
        ),
        ("not multiple of F", lambda p: _csv(p, _rows(301)), [], "not a multiple of ratio F=3"),
        ("too short", lambda p: _csv(p, _rows(30)), [], "too few samples for the LPM window"),
    ],
)
def test_bad_csv_input_is_an_error_with_exit_2(tmp_path, capsys, name, make, extra, match):
    data = make(tmp_path / "bad.csv")
    code, out, err = run(
        capsys, "identify", data, "--ratio", 3, *extra, "--out", tmp_path / "r.npz"
    )
    assert code == 2
    assert err.startswith("error: ") and match in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "r.npz").exists()


def test_ratio_below_one_is_rejected_by_the_parser(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["identify", "x.csv", "--ratio", "0", "--out", str(tmp_path / "r.npz")])
    assert exc.value.code == 2
    assert "expected an integer >= 1" in capsys.readouterr().err


def test_fs_disagreement_between_file_and_model_is_an_error(tmp_path, capsys):
    p = tmp_path / "d.npz"
    np.savez(p, r=np.zeros(300), u=np.zeros(300), y=np.zeros(300), fs_high=1000.0, ratio=3)
    code, _, err = run(capsys, "identify", p, "--model", PAPER, "--out", tmp_path / "r.npz")
    assert code == 2 and "fs_high disagrees" in err


def test_the_console_script_prints_no_traceback(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "mr_ident.cli",
            "identify",
            str(tmp_path / "none.csv"),
            "--ratio",
            "3",
            "--out",
            str(tmp_path / "r.npz"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and "Traceback" not in proc.stderr


_LOADED = """
import sys
{setup}
heavy = sorted(m for m in {heavy} if m in sys.modules)
print(",".join(heavy))
"""


@pytest.mark.parametrize(
    ("setup", "heavy"),
    [
        (  # mr-ident --help: the parser alone, no numpy at all
            "from mr_ident.cli.parser import build_parser; build_parser()",
            ("numpy", "scipy"),
        ),
        (  # mr-ident identify: numpy, never the slow scipy subpackages
            "from mr_ident.cli import offline; from mr_ident.io import datafile, modelfile; "
            "from mr_ident.numerics import identify",
            ("scipy.signal", "scipy.fft", "scipy.linalg", "scipy.special", "scipy.stats"),
        ),
    ],
    ids=["help", "identify"],
)
def test_start_up_imports_only_what_the_command_needs(setup, heavy):
    """Start-up is kept fast by what is imported, checked here without timing anything
    (figures: docs/benchmarks.md, Start-up)."""
    code = _LOADED.format(setup=setup, heavy=heavy)
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", f"imported at start-up: {proc.stdout.strip()}"


_RUN_AND_LIST = """
import sys
from mr_ident.cli.parser import build_parser
from mr_ident.cli.offline import cmd_identify
code = cmd_identify(build_parser().parse_args(sys.argv[1:]))
loaded = [m for m in sys.modules if m.startswith(("mr_ident.diagnosis", "scipy"))]
print("exit", code, "loaded", ",".join(sorted(loaded)))
"""


def test_identify_with_a_model_imports_no_diagnosis_and_no_scipy(tmp_path, paper_model):
    """A whole run of ``identify --model`` (P_h, the PFGs, their comparison, the result file)
    loads neither the diagnosis nor any part of scipy: what is in ``sys.modules`` after it."""
    import numpy as np

    from mr_ident.numerics.systems.simulate import simulate

    sim = simulate(paper_model, duration=30.0, rng=np.random.default_rng(0))
    np.savez(tmp_path / "d.npz", r=sim.r, u=sim.u, y=sim.y, fs_high=240.0, ratio=3)
    args = [str(tmp_path / "d.npz"), "--out", str(tmp_path / "o.npz")]
    proc = subprocess.run(
        [sys.executable, "-c", _RUN_AND_LIST, "identify", *args, "--model",
         str(ROOT / "config" / "paper_example.yaml")],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    last = proc.stdout.strip().splitlines()[-1]
    assert last == "exit 0 loaded", last


def test_paper_writes_figures_and_a_table(tmp_path, capsys):
    code, out, err = run(capsys, "paper", "--duration", 30, "--out-dir", tmp_path)
    assert code == 0, err
    for name in (
        "paper_plant_error.png",
        "paper_pfg_error.png",
        "paper_errors.md",
        "paper_bode_freq_lifted.png",
        "paper_pfg_freq_lifted.png",
    ):
        assert (tmp_path / name).is_file()
    assert "| freq-lifted |" in out
