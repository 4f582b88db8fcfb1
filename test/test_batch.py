# SPDX-License-Identifier: Apache-2.0
"""``mr-ident batch``: many recordings of different kinds, one table; a bad one is a row.

The recordings: NPZ and CSV files of the paper's loop with the plant gain drawn at random
(seeded), a rosbag2 JointState bag written by ``rosbags``, a file that is not loop data.
Noise-free, so the identified P_h is g P_0 and the drift against the nominal model is
|g - 1| at every frequency (tolerance 1e-3: the LPM's bias for a 60 s record is ~1e-6).
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from bagmaker import joint_state_bag, stamps

from mr_ident.cli import main
from mr_ident.io.datafile import read_identification, read_result, write_data
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"
R = '/ident/reference.position{name=="j1"}'
U = '/joint_states.effort{name=="j1"}'
Y = '/joint_states.position{name=="j1"}'
AT = "2,10,30,80"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """A directory of recordings and the gain hidden in each (None: not loop data)."""
    d = tmp_path_factory.mktemp("recs")
    model = load_model(PAPER)
    rng = np.random.default_rng(2026)
    gains: dict[str, float | None] = {}
    for k, suffix in enumerate(("npz", "csv", "npz")):
        g = float(rng.uniform(0.7, 1.3))
        num = tuple(tuple(tuple(g * c for c in e) for e in row) for row in model.plant.num)
        m = replace(model, plant=replace(model.plant, num=num))
        sim = simulate(m, duration=60.0, rng=np.random.default_rng(k))
        write_data(d / f"run{k}.{suffix}", sim.r, sim.u, sim.y, fs_high=240.0, ratio=3)
        gains[f"run{k}.{suffix}"] = g
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(9))
    joint_state_bag(d / "robot_bag", sim, stamps(sim.n_samples, 240.0))
    gains["robot_bag"] = 1.0
    (d / "notes.csv").write_text("t,r,u,y\n0,1,2\n")
    gains["notes.csv"] = None
    return d, gains


def _table(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _run_batch(recs: Path, out: Path, *extra: str) -> int:
    argv = [str(recs), "--model", str(PAPER), "--out-dir", str(out), "--at", AT]
    argv += ["--r", R, "--u", U, "--y", Y, *extra]
    return main(["batch", *argv])


@pytest.fixture(scope="module")
def pool_batch(recordings, tmp_path_factory):
    """The recordings' batch on the local pool of 2 workers: (exit code, what it printed
    on stderr, its output directory); run once, read by the two tests below."""
    import contextlib
    import io

    recs, _ = recordings
    out = tmp_path_factory.mktemp("pool") / "out"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = _run_batch(recs, out, "--workers", "2")
    return code, err.getvalue(), out


def test_a_batch_gives_a_row_per_recording_with_the_drift_and_a_result_each(
    recordings, pool_batch
):
    _, gains = recordings
    code, err, out = pool_batch
    assert code == 1  # one recording failed; the others are all there
    rows = {Path(r["recording"]).name: r for r in _table(out / "summary.csv")}
    assert sorted(rows) == sorted(gains)
    bad = rows["notes.csv"]
    assert bad["status"] == "error" and "header names 4 columns" in bad["error"]
    assert "notes.csv: error" in err  # the progress names the failure
    for name, g in gains.items():
        if g is None:
            continue
        row = rows[name]
        assert row["status"] == "ok", row["error"]
        assert float(row["drift_max"]) == pytest.approx(abs(g - 1), abs=1e-3)
        for f in AT.split(","):
            assert float(row[f"drift@{f}Hz"]) == pytest.approx(abs(g - 1), abs=1e-3)
        res = read_result(row["result"])  # the table's values are the result file's
        k = int(np.argmin(np.abs(res.frequency - 10.0)))
        assert float(row["mag@10Hz"]) == pytest.approx(abs(res.response[k, 0, 0]), rel=1e-5)
        pfg = read_identification(row["result"]).pfg_data  # the PFG from data, no model needed
        assert float(row["pfg_data@10Hz"]) == pytest.approx(pfg.gain[k], rel=1e-5)
    assert rows["robot_bag"]["n_samples"] == "14400"


def test_the_local_pool_and_a_dask_cluster_write_identical_tables(
    recordings, pool_batch, tmp_path
):
    """The same table, but for the output directory named in its result column."""
    distributed = pytest.importorskip(
        "distributed", reason="Dask distributed (the optional 'cluster' extra) not installed"
    )
    recs, _ = recordings
    pool_out = pool_batch[2]
    pool_table = (pool_out / "summary.csv").read_text()
    out = tmp_path / "out"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        _run_batch(recs, out, "--scheduler", cluster.scheduler_address)
    table = (out / "summary.csv").read_text()
    assert str(out) in table and str(pool_out) not in table
    assert table.replace(str(out), str(pool_out)) == pool_table


def test_diagnose_rows_carry_the_cause(tmp_path, capsys):
    model = load_model(PAPER)
    sim = simulate(replace(model, noise_std=1e-7), duration=60.0, rng=np.random.default_rng(3))
    write_data(tmp_path / "a.npz", sim.r, sim.u, sim.y, fs_high=240.0, ratio=3)
    out = tmp_path / "out"
    code = main(
        ["batch", str(tmp_path / "*.npz"), "--task", "diagnose", "--model", str(PAPER)]
        + ["--out-dir", str(out), "--workers", "1"]
    )
    assert code == 0, capsys.readouterr().err
    (row,) = _table(out / "summary.csv")
    assert row["status"] == "ok" and row["cause"] == "none" and (out / "a.json").exists()
    assert row["mag@0.8Hz"]  # the default frequencies: fs_low / 100 .. 0.4 fs_high


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["nothing-here-*.npz"], "no recording found for 'nothing-here-"),
        (["{d}", "--task", "diagnose", "--at", "1"], "diagnose needs a model"),
        (["{d}"], "pass --at"),
        (
            ["{d}", "--at", "1", "--model", "{paper}", "--scheduler", "tcp://127.0.0.1:1"],
            "no Dask scheduler answered",
        ),
    ],
    ids=["no-match", "diagnose-without-model", "no-frequencies", "no-scheduler"],
)
def test_a_batch_that_cannot_start_is_an_error_with_exit_2(
    recordings, tmp_path, capsys, monkeypatch, argv, match
):
    if "--scheduler" in argv:
        distributed = pytest.importorskip("distributed", reason="Dask distributed not installed")

        class QuickClient(distributed.Client):
            """The real client, giving up on a scheduler after 1 s instead of the CLI's 10 s
            (the same OSError: "Timed out trying to connect ... after 1 s")."""

            def __init__(self, address, timeout=None, **kw):
                super().__init__(address, timeout=1, **kw)

        monkeypatch.setattr(distributed, "Client", QuickClient)
    recs, _ = recordings
    argv = [a.format(d=recs, paper=PAPER) for a in argv]
    code = main(["batch", *argv, "--out-dir", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and match in err


def test_a_failure_is_told_always_and_the_count_only_as_progress(capsys):
    from mr_ident.cli.offline import batch_progress

    steps: list[str] = []
    show = batch_progress(steps.append, "on 2 worker(s)")
    show(1, 3, {"recording": "/x/a.npz", "status": "ok", "error": ""})
    show(2, 3, {"recording": "/x/b.npz", "status": "error", "error": "bad"})
    show(3, 3, {"recording": "/x/c.npz", "status": "ok", "error": ""})
    assert capsys.readouterr().err == "b.npz: error: bad\n"
    assert steps == ["3 recordings on 2 worker(s), 1 done", "3 recordings on 2 worker(s), 2 done"]
