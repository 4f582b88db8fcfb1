# SPDX-License-Identifier: Apache-2.0
"""The application layer (``mr_ident.app``): a request in, a result out, nothing printed.

The command line, ``batch`` and ``view --bag`` go through it; here the layer itself: what
an outcome holds, that notices are heard as they come and kept, that a batch job and a
single ``identify`` give the same result, how diagnose's two rules settle the rates.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mr_ident import batch
from mr_ident.app.identify import Identified, identify_recording
from mr_ident.app.reading import read_for_diagnosis, read_settled
from mr_ident.app.requests import IdentifyRequest, Notice, Reading, ignore, source_specs
from mr_ident.cli import main
from mr_ident.cli.common import flag
from mr_ident.errors import ConfigError
from mr_ident.io.datafile import read_result
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"


@pytest.fixture(scope="module")
def record(paper_model, tmp_path_factory):
    """30 s of the paper's loop (240 Hz, F = 3), and the same with y at the low rate."""
    d = tmp_path_factory.mktemp("app")
    sim = simulate(paper_model, duration=30.0, rng=np.random.default_rng(4))
    np.savez(d / "d.npz", r=sim.r, u=sim.u, y=sim.y, fs_high=240.0, ratio=3)
    np.savez(d / "slow.npz", r=sim.r, u=sim.u, y=sim.y[::3], fs_high=240.0, ratio=3)
    return d


def test_an_identification_comes_back_with_what_was_read_and_nothing_is_printed(record, capsys):
    req = IdentifyRequest(Reading(record / "d.npz"), model=PAPER, n=8)
    got = identify_recording(req)
    assert isinstance(got, Identified)
    assert (got.fs_high, got.ratio, got.first, got.n_samples) == (240.0, 3, 0, 7200)
    assert got.model is not None and got.model.ratio == 3 and got.notices == ()
    assert got.identification.pfg is not None  # the model's controller gave the PFG
    assert capsys.readouterr() == ("", "")
    with pytest.raises(dataclasses.FrozenInstanceError):
        req.method = "lifted"  # type: ignore[misc]


def test_notices_are_heard_as_they_come_and_kept_in_the_outcome(record, capsys):
    heard: list[Notice] = []
    got = identify_recording(IdentifyRequest(Reading(record / "slow.npz"), n=8), heard.append)
    assert isinstance(got, Identified)
    assert heard == list(got.notices) and len(heard) == 1
    (note,) = heard
    assert (note.kind, note.about) == ("note", "result")
    assert note.line().startswith("note: y has 2400 samples, r and u 7200")
    assert capsys.readouterr() == ("", "")


def test_the_sources_are_checked_where_a_bag_would_read_them(record):
    assert source_specs({"r": [], "u": [], "y": []}) is None
    with pytest.raises(ConfigError, match="missing u, y") as err:
        source_specs({"r": ["/a.x"], "u": [], "y": []})
    assert err.value.told(flag).endswith("missing --u, --y")  # the command line's words
    sources = {"r": ["/a.x"], "u": ["/a.y"], "y": ["/a.z"]}
    with pytest.raises(ConfigError, match="^r/u/y name sources in a bag") as err:
        identify_recording(IdentifyRequest(Reading(record / "d.npz", sources), n=8))
    assert err.value.told(flag).startswith("--r/--u/--y name sources in a bag")
    with pytest.raises(ConfigError, match="^excitation_index goes with period") as err:
        identify_recording(IdentifyRequest(Reading(record / "d.npz"), excitation_index="/x"))
    assert err.value.told(flag).startswith("--excitation-index goes with --period")


def test_a_batch_job_and_a_single_identify_write_the_same_result(record, tmp_path, capsys):
    assert (
        main(["identify", str(record / "d.npz"), "--n", "8", "--out", str(tmp_path / "one.npz")])
        == 0
    )
    opts = batch.BatchOptions(
        task="identify", out_dir=str(tmp_path), frequencies=(10.0,), n=8, threads=1
    )
    row = batch.run_job(batch.Job(str(record / "d.npz"), str(tmp_path / "job.npz")), opts)
    assert row["status"] == "ok", row["error"]
    one, job = read_result(tmp_path / "one.npz"), read_result(tmp_path / "job.npz")
    np.testing.assert_array_equal(one.frequency, job.frequency)
    np.testing.assert_allclose(job.response, one.response, rtol=1e-12, atol=0)


def test_diagnose_takes_a_files_own_rates_and_batch_asks_them_to_agree(paper_model, tmp_path):
    """``diagnose`` reads a data file at its own rates (the model's where it gives none);
    ``batch --task diagnose`` (``rates="agree"``) wants file and model to agree."""
    sim = simulate(paper_model, duration=5.0, rng=np.random.default_rng(1))
    np.savez(tmp_path / "d.npz", r=sim.r, u=sim.u, y=sim.y, fs_high=480.0, ratio=3)
    reading = Reading(tmp_path / "d.npz")
    data = read_for_diagnosis(reading, paper_model, None, None, ignore)
    assert data.rates() == (480.0, 3)
    with pytest.raises(ConfigError, match="fs_high disagrees"):
        read_settled(reading, None, None, None, paper_model, ignore)
