# SPDX-License-Identifier: Apache-2.0
"""Diagnose on a record with missing samples (NaN in u or y) uses the whole record.

The missing residual samples are unknowns of the criterion, eliminated by projection
(``mr_ident.diagnosis.criterion.holes``); the controller's equation leaves a missing u's
equation out and eliminates a missing sampled y's effect the same way; beyond the limits
identification derives, the longest complete stretch is diagnosed, with a note.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml

from mr_ident import simulate
from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.controller.relation import EXACT, relate
from mr_ident.diagnosis.criterion.holes import Holes, check_missing, diagnosable
from mr_ident.errors import DataError
from mr_ident.io.modelfile import model_from_dict, model_to_dict

FS, F = 100.0, 2


def _model(controller=True):
    spec = {"fs_high": FS, "ratio": F, "plant": {"num": [10.0], "den": [1.0, 10.0]}}
    if controller:
        spec["controller"] = {"num": [0.5], "den": [1.0]}
    return model_from_dict(spec)


def _bursts(n, share, rng, burst=5):
    """Separate bursts of 1..burst samples at random, ``share`` of n in all."""
    mask = np.zeros(n, bool)
    while mask.mean() < share:
        start = rng.integers(1, n - burst - 1)
        stop = start + rng.integers(1, burst + 1)
        if not mask[start - 1 : stop + 1].any():
            mask[start:stop] = True
    return mask


def _holed(data, seed, share=0.01):
    rng = np.random.default_rng(seed)
    u, y = data.u.copy(), data.y.copy()
    y[_bursts(data.n_samples, share, rng)] = np.nan
    u[_bursts(data.n_samples, share, rng)] = np.nan
    return dataclasses.replace(data, u=u, y=y)


@pytest.fixture(scope="module")
def holed():
    """20 s of a loop whose plant gain is 1.3, 1 % of y and of u dropped in bursts of 1-5."""
    true = dataclasses.replace(_model(), plant_gain=1.3, noise_std=0.01)
    data = simulate(true, duration=20.0, rng=np.random.default_rng(0))
    return true, _holed(data, 3)


def test_the_projection_of_the_holes_equals_least_squares_on_their_columns():
    rng = np.random.default_rng(1)
    for N in (64, 65):
        W = rng.uniform(0.1, 3.0, (N // 2 + 1, 2))
        miss = rng.random((N, 2)) < 0.1
        cols = []
        for j in range(2):
            for m in np.flatnonzero(miss[:, j]):
                z = np.zeros((N, 2))
                z[m, j] = 1.0
                E = np.fft.rfft(z, axis=0, norm="ortho") * W
                cols.append(np.concatenate([E.real.ravel(), E.imag.ravel()]))
        A = np.array(cols).T
        v = rng.standard_normal((A.shape[0], 3))
        want = v - A @ np.linalg.lstsq(A, v, rcond=None)[0]
        np.testing.assert_allclose(Holes(miss, W).project(v), want, atol=1e-12)
        np.testing.assert_allclose(Holes(miss, W).project(v[:, 0]), want[:, 0], atol=1e-12)


def test_the_true_model_on_a_record_with_holes_has_no_cause(holed):
    true, rec = holed
    used, note = diagnosable(rec, true)
    assert used is rec and not note
    d = diagnose(dataclasses.replace(true, noise_std=0.0), rec)
    assert d.cause == "none", d.cause
    assert d.criterion is not None and d.criterion.holes.count > 0
    assert d.relation is not None and d.relation.exact  # u from y, its holes unknowns
    assert d.segments is not None and not d.time_varying  # its segments, holes in them


def test_the_controllers_equation_holds_exactly_over_holes_and_finds_a_delay():
    true = dataclasses.replace(_model(), control_delay=1, noise_std=0.01)
    rec = _holed(simulate(true, duration=10.0, rng=np.random.default_rng(2)), 5)
    rel = relate(_model(), rec)
    assert rel is not None and rel.error_after <= EXACT
    assert [c.cause for c in rel.choices] == ["control_delay"]
    assert rel.samples < rec.n_samples - int(np.isnan(rec.u).sum())  # u's holes left out


def test_open_loop_the_plant_is_driven_by_us_estimates():
    true = dataclasses.replace(_model(False), plant_gain=1.3, noise_std=0.01)
    rec = _holed(simulate(true, duration=20.0, rng=np.random.default_rng(0)), 5)
    assert diagnose(dataclasses.replace(true, noise_std=0.0), rec).cause == "none"
    d = diagnose(_model(False), rec)
    assert d.cause == "gain_error" and abs(d.parameters["gain"] - 1.3) < 5e-3


def test_r_missing_is_recovered_and_more_than_a_fit_takes_is_refused(holed):
    """r at the plant input: u - r is held, so a lost r whose u came is recovered exactly;
    lost with its u, it is guessed, and beyond 0.1 % of the record refused, naming it."""
    from mr_ident.diagnosis.criterion.records import with_r

    true, rec = holed
    r = rec.r.copy()
    lost = np.flatnonzero(np.isfinite(rec.u[:, 0]))[7::50]
    r[lost] = np.nan
    got = with_r(true, dataclasses.replace(rec, r=r))
    np.testing.assert_allclose(got.r, rec.r, rtol=0, atol=1e-12 * np.abs(rec.r).max())
    d = diagnose(dataclasses.replace(true, noise_std=0.0), dataclasses.replace(rec, r=r))
    assert d.cause == "none", d.cause
    r[np.flatnonzero(np.isnan(rec.u[:, 0]))] = np.nan  # lost with u: about 1 %
    with pytest.raises(DataError, match="d.npz: r has .* read samples missing where the loop"):
        with_r(true, dataclasses.replace(rec, r=r), "d.npz")


def test_periodic_holes_and_holes_beyond_the_limits_are_refused(holed):
    true, rec = holed
    with pytest.raises(DataError, match="d.npz: u or y miss .* periodic data"):
        check_missing(dataclasses.replace(rec, period=200), 8, "d.npz")
    many = _holed(rec, 9, share=0.2)
    with pytest.raises(DataError, match="too many missing samples for diagnose"):
        check_missing(many, 8, "d.npz")
    part, note = diagnosable(many, true)
    assert "diagnosed on the longest stretch without a missing sample" in note
    assert not np.isnan(part.u).any() and part.n_samples % F == 0


def test_a_wrong_gain_is_named_from_a_data_file_with_nan_diagnosed_whole(
    holed, tmp_path, capsys, monkeypatch
):
    """The record with holes written to a file, diagnosed by the command line: the
    diagnosis it computes (kept by a wrapper around diagnose) names the gain from the whole
    record, holes and all, and the text, the JSON and the page say so."""
    import mr_ident.diagnosis
    from mr_ident.cli import main

    true, rec = holed
    made = []

    def kept(*args, **kwargs):
        made.append(diagnose(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(mr_ident.diagnosis, "diagnose", kept)
    np.savez(tmp_path / "d.npz", r=rec.r, u=rec.u, y=rec.y, fs_high=FS, ratio=F)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(model_to_dict(_model())))
    args = [str(tmp_path / x) for x in ("m.yaml", "d.npz")]
    args += ["--json", str(tmp_path / "r.json"), "--report", str(tmp_path / "r.html")]
    code = main(["diagnose", *args])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "longest stretch" not in err
    n_y, n_u = int(np.isnan(rec.y).sum()), int(np.isnan(rec.u).sum())
    assert (
        f"{n_y} samples of y and {n_u} of u missing (NaN) of {rec.n_samples}: diagnosed whole"
        in (out + err)
    )
    assert json.loads((tmp_path / "r.json").read_text())["cause"] == "gain_error"
    assert "gain_error" in (tmp_path / "r.html").read_text()  # measured y drawn with its gaps
    (d,) = made
    assert d.cause == "gain_error"
    gain, std = d.parameters["gain"], d.applied[0].std["gain"]
    assert abs(gain - 1.3) < max(4.0 * std, 2e-3), (gain, std)
    assert d.criterion is not None and d.criterion.rec.n_samples == int(0.7 * rec.n_samples)
    assert np.isnan(d.criterion.rec.y).any()  # the estimation part, its holes in it
    assert d.fit_after.y > d.fit_before.y and np.isfinite(d.fit_after.u)


def test_the_nodes_diagnose_service_takes_a_window_with_holes_whole(holed):
    from mr_ident.app.diagnose import window_report

    true, rec = holed
    window = dataclasses.replace(rec, first=1000, fs_high=None, ratio=None)
    report = window_report(dataclasses.replace(true, noise_std=0.0), window)
    assert (report["window_first"], report["window_samples"]) == (1000, rec.n_samples)
    assert report["cause"] == "none" and "window_note" not in report


def test_the_drift_diagnosis_takes_a_window_with_holes_whole(holed):
    from mr_ident.diagnosis.monitoring.drift import Reference
    from mr_ident.diagnosis.monitoring.monitor import PlantWatch
    from mr_ident.io.config import IdentConfig
    from mr_ident.live.estimate import estimate

    true, rec = holed
    window = dataclasses.replace(rec, first=4000, fs_high=None)
    cfg = IdentConfig(fs_high=FS, ratio=F, window_s=20.0, monitor_model="m")
    watch = PlantWatch(Reference.of_model(_model()), _model(), cfg)
    found = watch.diagnose(window, estimate(window, cfg))
    assert found is not None and found.cause == "gain_error"
    assert abs(found.parameters["gain"] - 1.3) < 0.01
    assert (found.window_first, found.window_samples) == (4000, rec.n_samples)
