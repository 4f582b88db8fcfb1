# SPDX-License-Identifier: Apache-2.0
"""Where the vocabulary ends: a low-order correction, applied only when it validates.

The loop: a damped second-order plant at 500 Hz under a low-rate (F = 2) lag controller.
Outside the vocabulary: a lightly damped pole-zero pair in series with the plant (zero
60 Hz ζ 0.03, pole 83 Hz ζ 0.04). With one cause allowed the additive mode at 83 Hz is
found and the zero stays unexplained; a correction fitted on the estimation record
validates on a second record; the model file holding it loads and simulates.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from mr_ident import simulate
from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.report import report_dict
from mr_ident.errors import ModelError
from mr_ident.io.modelfile import load_model, model_from_dict, model_to_dict
from mr_ident.numerics.systems.modal import ModalPlant
from mr_ident.numerics.systems.model import Model

FS = 500.0


def _model() -> Model:
    return model_from_dict(
        {
            "fs_high": FS,
            "ratio": 2,
            "plant": {"num": [1000.0], "den": [1.0, 60.0, 2000.0]},
            "controller": {"num": [0.5], "den": [1.0, -0.3]},
        }
    )


def _pole_zero_pair(model: Model) -> Model:
    wz, wp, zz, zp = 2 * np.pi * 60.0, 2 * np.pi * 83.0, 0.03, 0.04
    k = wp * wp / (wz * wz)  # unit gain at DC
    plant = model.plant.times([k, k * 2 * zz * wz, wp * wp], [1.0, 2 * zp * wp, wp * wp])
    return dataclasses.replace(model, plant=plant, noise_std=5e-4)


@pytest.fixture(scope="module")
def out_of_vocabulary(tmp_path_factory):
    """The loop with the pair, diagnosed once, by the command line: ``diagnose nominal data
    --validate val --max-causes 1`` with its JSON, HTML and model files. (true model,
    validation record, the diagnosis the command computed (kept by a wrapper around
    diagnose), its output directory, what it printed)."""
    import contextlib
    import io

    import mr_ident.diagnosis
    from mr_ident.cli import main

    true = _pole_zero_pair(_model())
    data = simulate(true, duration=10.0, rng=np.random.default_rng(0))
    val = simulate(true, duration=10.0, rng=np.random.default_rng(1))
    d = tmp_path_factory.mktemp("vocabulary")
    for name, rec in (("data", data), ("val", val)):
        np.savez(d / f"{name}.npz", r=rec.r, u=rec.u, y=rec.y, fs_high=FS, ratio=2)
    (d / "nominal.yaml").write_text(yaml.safe_dump(model_to_dict(_model())))
    made, printed = [], io.StringIO()

    def kept(*args, **kwargs):
        made.append(diagnose(*args, **kwargs))
        return made[-1]

    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(printed):
        mp.setattr(mr_ident.diagnosis, "diagnose", kept)
        code = main(
            ["diagnose", str(d / "nominal.yaml"), str(d / "data.npz"),
             "--validate", str(d / "val.npz"), "--max-causes", "1",
             "--json", str(d / "r.json"), "--report", str(d / "r.html"),
             "--out-model", str(d / "ext.yaml")]
        )  # fmt: skip
    assert code == 0
    (diagnosis,) = made
    return true, val, diagnosis, d, printed.getvalue()


def test_a_pole_zero_pair_outside_the_vocabulary_gets_a_correction_that_validates(
    out_of_vocabulary,
):
    """The correction is accepted on the validation record: its criterion beats the
    nominal's and the cause's by far more than the margin, the fit of y rises above the
    cause's (measured 98.5 % -> 99.4 %, the true model's 99.4 %), and the corrected P_h
    is the true one at 40-100 Hz to 5 % of the nominal's error there."""
    true, val, d, _, _ = out_of_vocabulary
    c = d.correction
    assert c is not None and c.accepted and c.best is not None, c and c.text()
    assert c.gain > 100.0, c.text()
    assert min(c.z_nominal, c.z_causes) > c.z_critical
    assert c.best.fit_y > c.fit_causes > c.fit_nominal
    assert d.extended.plant_corrections == c.best.model.plant_corrections
    assert d.fit_after.y == pytest.approx(c.best.fit_y)
    from mr_ident.diagnosis.criterion.prediction import time_fit

    assert d.fit_after.y > time_fit(true, val, d.traces["start"]).y - 0.5
    text = c.text()
    assert text.startswith("not a listed cause") and "correction of the plant" in text
    assert "not applied" not in text
    f = np.linspace(40.0, 100.0, 61)
    P, P_true = (m.plant_discrete().freqresp(f)[:, 0, 0] for m in (d.extended, true))
    P_nom = _model().plant_discrete().freqresp(f)[:, 0, 0]
    err, err_nom = np.abs(P - P_true), np.abs(P_nom - P_true)
    assert np.max(err) < 0.05 * np.max(err_nom), (np.max(err), np.max(err_nom))
    summary = report_dict(d, extended_model=None, alpha=0.01)
    assert summary["correction"]["accepted"] and text in summary["findings"]


def test_the_corrected_model_is_written_and_loads_back(tmp_path, out_of_vocabulary):
    """Written as ``plant_corrections`` (discrete modal form), read back with the same P_h
    to rounding, and simulated."""
    _, _, d, _, _ = out_of_vocabulary
    path = tmp_path / "extended.yaml"
    path.write_text(yaml.safe_dump(model_to_dict(d.extended), sort_keys=False))
    back = load_model(path)
    assert [k for k, _ in back.plant_corrections] == [k for k, _ in d.extended.plant_corrections]
    f = np.linspace(1.0, 249.0, 50)
    a, b = back.plant_discrete().freqresp(f), d.extended.plant_discrete().freqresp(f)
    assert np.allclose(a, b, rtol=1e-9, atol=1e-12)
    assert np.all(np.isfinite(simulate(back, duration=1.0, rng=np.random.default_rng(2)).y))


def test_the_cli_writes_the_correction_to_the_model_file_and_the_report(out_of_vocabulary):
    import json

    _, _, _, tmp_path, printed = out_of_vocabulary
    assert "found: not a listed cause" in printed
    rep = json.loads((tmp_path / "r.json").read_text())
    corr = rep["correction"]
    assert corr["accepted"] and corr["z_causes"] > corr["z_critical"]
    bb = corr["broadband"]  # the broadband test on the estimation data, reported beside
    assert bb["n_terms"] > 0 and bb["sd"] > 0
    assert bb["significant"] == (bb["total"] > bb["threshold"])
    text = (tmp_path / "ext.yaml").read_text()
    assert "a plant correction" in text.splitlines()[1] and "plant_corrections:" in text
    assert load_model(tmp_path / "ext.yaml").plant_corrections
    assert "not a listed cause" in (tmp_path / "r.html").read_text()


def test_a_loop_matching_its_model_gets_no_correction():
    model = dataclasses.replace(_model(), noise_std=5e-4)
    data = simulate(model, duration=10.0, rng=np.random.default_rng(3))
    d = diagnose(_model(), data, max_causes=1)
    assert d.correction is None and not d.extended.plant_corrections
    assert report_dict(d, extended_model=None, alpha=0.01)["correction"] is None


def _pair(dt: float | None = 1 / FS) -> ModalPlant:
    p = np.exp(complex(-0.04 * 2 * np.pi * 83, 2 * np.pi * 83) / FS)
    return ModalPlant(np.array([p]), np.array([[[0.01 + 0.02j]]]), np.zeros((1, 1)), dt)


@pytest.mark.parametrize("kind", ["additive", "multiplicative"])
def test_a_correction_acts_on_p_h_as_its_kind_says(kind):
    model = _model()
    C = _pair()
    m = dataclasses.replace(model, plant_corrections=((kind, C),))
    f = np.linspace(1.0, 249.0, 40)
    P0, Cf = model.plant_discrete().freqresp(f), C.freqresp(f)
    want = P0 + Cf if kind == "additive" else P0 * (1.0 + Cf)
    assert np.allclose(m.plant_discrete().freqresp(f), want, rtol=1e-10, atol=1e-14)
    back = model_from_dict(yaml.safe_load(yaml.safe_dump(model_to_dict(m))))
    assert np.allclose(back.plant_discrete().freqresp(f), want, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"kind": "series"}, "kind must be one of additive, multiplicative"),
        ({"domain": "continuous"}, "domain must be discrete"),
        ({"modes": [{"frequency_hz": 83.0, "damping": -0.01, "c1": 0.0, "c0": 1.0}]},
         "outside the unit circle"),
        ({"direct": [[0.0, 0.0]], "modes": []}, "must be 1x1"),
    ],
)  # fmt: skip
def test_a_bad_correction_in_a_model_file_is_refused(change, match):
    d = model_to_dict(dataclasses.replace(_model(), plant_corrections=(("additive", _pair()),)))
    d["plant_corrections"][0].update(change)
    with pytest.raises(ModelError, match=match):
        model_from_dict(d)


def test_a_dead_zones_distortion_gets_no_correction():
    """A dead zone (level 1: 2 σ_u wide) in a random loop under a periodic odd multisine,
    a second realization as the validation record: whatever is fitted to what the causes
    leave does not hold over the validation bins (the distortion is no linear effect), so
    no correction is applied."""
    from mr_bench.beyond import draw_beyond

    b = draw_beyond("dead_zone", np.random.default_rng(7), level=1.0, realizations=2)
    d = diagnose(b.nominal, b.data, b.validation, max_causes=1)
    assert d.correction is None or not d.correction.accepted, d.correction.text()
    assert not d.extended.plant_corrections


def test_a_gain_on_few_bins_validates_on_the_causes_test():
    """A second delay path (u + c u[n - 3], c -0.31) on a loop near its stability margin
    (a benchmark case): the nominal fits the validation record 0.5 %, no listed cause
    validates, a third-order multiplicative correction 80 %. Its gain sits on the few bins
    of the loop's resonance: the mean per-bin drop of the residual was within 1.7 of its
    standard error there (refused before); the causes' test, on the known difference of
    the two residuals, gives z 10.0 > 2.33: applied.

    One cause allowed: no cause validates at any count, so the correction starts from the
    nominal either way and every asserted figure equals the default search's (measured:
    z 10.0 > 2.33 on both tests, fit of y 0.5 % -> 89.3 %) at a fifth of its time (2.7 s
    instead of 14 s of CPU)."""
    from mr_bench.beyond import draw_beyond

    b = draw_beyond("second_delay_path", np.random.default_rng(5025002), duration=10.0)
    d = diagnose(b.nominal, b.data, b.validation, max_causes=1)
    assert d.cause == "none"
    c = d.correction
    assert c is not None and c.accepted and c.best is not None, c and c.text()
    assert min(c.z_nominal, c.z_causes) > c.z_critical
    assert d.fit_after.y > d.fit_before.y + 50.0


def test_a_correction_that_could_not_be_fitted_says_so():
    from mr_ident.diagnosis.selection.correction import Correction

    c = Correction([(1.0, 2.0)], None, (), False, *(np.nan,) * 4)
    assert c.model is None and c.text().endswith("no stable correction could be fitted")
    assert c.summary()["kind"] is None and c.summary()["fit_nominal"] is None


def test_a_correction_found_by_the_broadband_test_alone_says_so():
    from mr_ident.diagnosis.criterion.broadband import Broadband
    from mr_ident.diagnosis.selection.correction import Correction

    bb = Broadband(1300.0, 1100.0, 80.0, 1000, 5.9, 1286.0)
    assert bb.significant and bb.z == pytest.approx(2.5)
    c = Correction([(1.0, 2.0)], None, (), False, *(np.nan,) * 4, broadband=bb, per_bin=False)
    assert c.thin and "spread thinly: no bin significant alone, the total 2.5 sd" in c.text()
    s = c.summary()["broadband"]
    assert s is not None and s["significant"] and s["z"] == pytest.approx(2.5)
