# SPDX-License-Identifier: Apache-2.0
"""mr_ident.numerics.fit and ``mr-ident fit``: a stable modal model of an identified FRF.

Truths are modal plants sampled behind a zero-order hold (exact: the hold-equivalent of
each partial fraction) with circular Gaussian noise of known std.
"""

from __future__ import annotations

import importlib.util
import json
import re
import runpy
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import console_script

from mr_ident.errors import ConfigError, DataError, ModelError
from mr_ident.io.control_export import control_path, export_control, require_control
from mr_ident.io.fitfile import fitted_model, side_path, write_fit
from mr_ident.io.modelfile import load_model, model_from_dict, model_to_dict
from mr_ident.numerics.fit.frf_fit import (
    correlation_length,
    fit_frf,
    hold_response,
    lpm_kernel,
)
from mr_ident.numerics.results import FRF
from mr_ident.numerics.systems.modal import ModalPlant

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"
FS = 1000.0


def _mode(f: float, z: float) -> complex:
    w = 2 * np.pi * f
    return complex(-z * w, w * np.sqrt(1 - z * z))


def _siso() -> ModalPlant:
    poles = np.array([_mode(20, 0.05), _mode(150, 0.02), -2 * np.pi * 5 + 0j])
    R = np.array([[[-500j]], [[30 - 200j]], [[400.0]]])
    return ModalPlant(poles, R, np.zeros((1, 1)))


def _mimo() -> ModalPlant:
    poles = np.array([_mode(20, 0.05), _mode(150, 0.02)])
    R = np.array([[[-500j, 50], [20 - 10j, -300j]], [[30 - 200j, 10j], [5, 40 - 100j]]])
    return ModalPlant(poles, R, np.zeros((2, 2)))


def _data(truth, delay, seed, *, K=500, rel=0.05, domain="continuous"):
    f = np.arange(1, K + 1) * FS / (2 * K + 2)
    P = hold_response(truth, delay, domain, FS, f)
    sd = rel * np.abs(P).mean(axis=0)[None] * np.ones(P.shape)
    rng = np.random.default_rng(seed)
    noise = sd * (rng.standard_normal(P.shape) + 1j * rng.standard_normal(P.shape)) / np.sqrt(2)
    return FRF(f, P + noise, sd, "test")


def _sorted(fit):
    o = np.argsort(np.abs(fit.plant.poles))
    return fit.plant.poles[o], fit.plant.residues[o], fit.pole_std[o], fit.residue_std[o]


def test_the_order_and_a_fractional_delay_come_from_the_data():
    truth, tau = _siso(), 1.3 / FS
    fit = fit_frf(_data(truth, tau, 1, K=1000, rel=0.02), fs=FS, order="auto", delay="auto")
    assert fit.order == 5  # two modes and a real pole
    assert [r.order for r in fit.orders][:5] == [1, 2, 3, 4, 5]
    assert all(r.cost > r.expected + 2 * r.sd for r in fit.orders[:4])
    assert abs(fit.cost - fit.expected) < 2 * fit.expected_sd
    assert abs(fit.delay - tau) < 4 * fit.delay_std
    p, R, ps, rs = _sorted(fit)
    t = truth.poles[np.argsort(np.abs(truth.poles))]
    assert np.all(np.abs(p.real - t.real) < 4 * ps[:, 0] + 1e-12)
    assert np.all(np.abs(p.imag - t.imag) < 4 * ps[:, 1] + 1e-12)
    assert fit.dof == 2 * fit.n_data - fit.n_params
    assert fit.residual.shape == (fit.frequency.size, 1, 1)


def test_a_2x2_plant_gets_its_order_and_common_poles():
    truth = _mimo()
    fit = fit_frf(_data(truth, 0.4 / FS, 11), fs=FS, order="auto", delay="auto", max_order=8)
    assert fit.order == 4 and fit.plant.shape == (2, 2) and fit.in_band
    p, R, ps, rs = _sorted(fit)
    np.testing.assert_array_less(np.abs((R - truth.residues).real), 4 * rs[..., 0] + 1e-12)
    np.testing.assert_array_less(np.abs((R - truth.residues).imag), 4 * rs[..., 1] + 1e-12)


def test_the_reported_std_is_the_spread_over_seeds_mimo():
    truth, tau = _mimo(), 0.7 / FS
    t = truth.poles[np.argsort(np.abs(truth.poles))]
    truth_x = np.concatenate([t.real, t.imag, [tau], truth.residues.real.ravel()])
    est, std = [], []
    for seed in range(20):
        fit = fit_frf(_data(truth, tau, seed), fs=FS, order=4, delay="auto")
        p, R, ps, rs = _sorted(fit)
        est.append(np.concatenate([p.real, p.imag, [fit.delay], R.real.ravel()]))
        std.append(np.concatenate([ps[:, 0], ps[:, 1], [fit.delay_std], rs[..., 0].ravel()]))
    err = np.array(est) - truth_x
    ratio = np.sqrt(np.mean(err**2, axis=0)) / np.mean(std, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio
    assert 0.8 < np.sqrt(np.mean(ratio**2)) < 1.25  # pooled over the 13 parameters


def test_the_discrete_domain_fits_the_hold_equivalent_with_whole_sample_delays():
    truth = _siso()
    data = _data(truth, 2 / FS, 3, K=800, rel=0.02)
    fit = fit_frf(data, fs=FS, order="auto", domain="discrete", delay="auto")
    assert fit.order == 5 and fit.plant.dt == 1 / FS
    assert fit.delay == pytest.approx(2 / FS)
    # the hold adds no pole: the z-poles are e^{p h} of the continuous ones
    lam = np.sort_complex(fit.plant.poles)
    ref = np.sort_complex(np.exp(truth.poles / FS))
    assert np.all(np.abs(lam - ref) < 4 * np.hypot(*fit.pole_std.T)[np.argsort(fit.plant.poles)])
    assert abs(fit.cost - fit.expected) < 2 * fit.expected_sd


@pytest.mark.parametrize("domain", ["continuous", "discrete"])
def test_no_fit_is_unstable_even_far_past_the_true_order(domain):
    for seed in range(3):
        data = _data(_mimo(), 0.0, seed, rel=0.3)
        fit = fit_frf(data, fs=FS, order=12, domain=domain, delay=0.0)
        p = fit.plant.poles
        assert np.all(p.real < 0) if domain == "continuous" else np.all(np.abs(p) < 1)


def test_the_model_file_reproduces_the_fit_exactly(tmp_path):
    truth, tau = _mimo(), 1.4 / FS
    fit = fit_frf(_data(truth, tau, 5), fs=FS, order=4, delay=tau)
    model = fitted_model(fit, ratio=4)
    out, side = write_fit(tmp_path / "m.yaml", model, fit)
    m = load_model(out)
    assert m.input_delay == pytest.approx(tau) and m.controller is None
    f = np.arange(1, 2000) * FS / 4000
    P = m.plant_discrete().freqresp(f)  # the simulator's P_h: ZOH and delay in state space
    np.testing.assert_allclose(P, fit.response(f), rtol=1e-9, atol=1e-12 * np.abs(P).max())
    s = yaml.safe_load(side.read_text())
    assert s["order"] == 4 and len(s["poles"]) == 2 and s["poles"][0]["frequency_hz_std"] > 0
    assert side == side_path(out)


@pytest.mark.parametrize("domain", ["continuous", "discrete"])
def test_the_python_control_export_reproduces_the_fit(tmp_path, domain):
    control = pytest.importorskip("control")
    tau = (1.4 if domain == "continuous" else 2.0) / FS
    fit = fit_frf(_data(_mimo(), tau, 5), fs=FS, order=4, domain=domain, delay=tau)
    path = export_control(control_path(tmp_path / "m.yaml"), fitted_model(fit, ratio=4))
    assert path.name == "m_control.py"
    ns = runpy.run_path(str(path))
    f = np.array([0.5, 20.0, 149.0, 400.0])
    P = control.frequency_response(ns["P_h"], 2 * np.pi * f, squeeze=False).complex
    np.testing.assert_allclose(P.transpose(2, 0, 1), fit.response(f), rtol=1e-9)
    G = control.frequency_response(ns["G"], 2 * np.pi * f, squeeze=False).complex
    np.testing.assert_allclose(G.transpose(2, 0, 1), fit.plant.freqresp(f), rtol=1e-9)
    assert ns["P_h"].dt == 1 / FS and ns["input_delay_s"] == pytest.approx(tau)
    assert (ns["G"].dt == 0) if domain == "continuous" else ns["G"].dt == 1 / FS


def test_the_export_without_python_control_names_its_pip_install(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "control" else real(name)
    )
    with pytest.raises(ConfigError, match=r"needs python-control: pip install control"):
        require_control()


def test_the_modal_form_round_trips_and_moves_a_mode_under_mode_changes():
    P = _mimo()
    np.testing.assert_allclose(
        P.state_space().freqresp([3.0, 20.0, 149.0]), P.freqresp([3.0, 20.0, 149.0]), rtol=1e-12
    )
    base = model_from_dict({"fs_high": FS, "ratio": 2, "plant": {"num": [1.0], "den": [1, 1]}})
    m = replace(base, plant=P)
    d = model_to_dict(m)
    assert set(d["plant"]) == {"domain", "direct", "modes"}
    back = model_from_dict(d)
    np.testing.assert_allclose(back.plant_frf(256), m.plant_frf(256), rtol=1e-12, atol=1e-15)
    moved = replace(back, mode_changes=((150.0, 160.0, 0.02, 1.0),))
    poles = moved.plant_ss().poles()
    assert np.isclose(np.abs(poles), 2 * np.pi * 160).sum() == 4  # 2 inputs, a pair each
    assert not np.isclose(np.abs(poles), 2 * np.pi * 150).any()


def test_a_bad_modal_plant_in_a_model_file_names_its_key():
    d = {"fs_high": FS, "ratio": 1, "plant": {"direct": [[0.0]], "modes": [{"c1": 1}]}}
    with pytest.raises(ModelError, match=r"plant.modes\[0\] must be a mapping with"):
        model_from_dict(d)
    d["plant"]["modes"] = [{"frequency_hz": 5.0, "damping": 0.1, "c1": [[1.0, 2.0]], "c0": 1.0}]
    with pytest.raises(ModelError, match=r"plant.modes\[0\].c1 has shape \(1, 2\), expected"):
        model_from_dict(d)


def test_options_and_data_errors_name_what_came():
    data = _data(_siso(), 0.0, 0)
    with pytest.raises(ConfigError, match='domain must be "continuous" or "discrete", got'):
        fit_frf(data, fs=FS, domain="laplace")
    with pytest.raises(ConfigError, match=r"order must be \"auto\" or an integer >= 1, got 0"):
        fit_frf(data, fs=FS, order=0)
    with pytest.raises(ConfigError, match="whole samples"):
        fit_frf(data, fs=FS, domain="discrete", delay=0.5 / FS)
    with pytest.raises(DataError, match="bins with a positive finite std"):
        fit_frf(FRF(data.frequency, data.response, 0 * data.std, "m"), fs=FS)
    fit = fit_frf(data, fs=FS, order=5, delay=0.0, band=(10.0, 200.0))
    assert fit.frequency.min() >= 10 and fit.frequency.max() <= 200
    with pytest.raises(ModelError, match="the controller model has fs_high"):
        fitted_model(fit, ratio=3, controller=load_model(PAPER))


def test_the_lpm_kernel_is_one_at_zero_lag_and_spans_the_window():
    k = lpm_kernel(12)
    assert k.size == 25 and k[0] == pytest.approx(1.0) and abs(k[-1]) < 0.1
    assert correlation_length(None) == 1.0 == correlation_length(lpm_kernel(0))
    assert 5 < correlation_length(k) < 25


def _run(*args, cwd):
    return subprocess.run(
        [console_script("mr-ident"), *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_identify_fit_diagnose_on_the_paper_loop(tmp_path):
    model = tmp_path / "paper.yaml"
    model.write_text(PAPER.read_text().replace("noise_std: 0.0", "noise_std: 0.0001"))
    for args in (
        ("simulate", model, "--duration", 60, "--out", "rec.npz"),
        ("identify", "rec.npz", "--model", model, "--out", "res.npz"),
    ):
        assert _run(*args, cwd=tmp_path).returncode == 0
    r = _run(
        "fit", "res.npz", "--controller", model, "--out", "fit.yaml", "--plot", "fit.png",
        *(["--export", "python-control"] if importlib.util.find_spec("control") else []),
        cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "wrote fit.yaml" in r.stdout and (tmp_path / "fit_residual.png").is_file()
    if importlib.util.find_spec("control"):
        assert "wrote fit_control.py" in r.stdout
    side = yaml.safe_load((tmp_path / "fit.fit.yaml").read_text())
    assert side["order"] == 4  # the two modes of the paper's plant
    # the plant falls as 1/s^2: a small delay trades with the residues (its std was 21
    # samples), so it is fixed at 0 and said to be undetermined
    assert side["delay_determined"] is False and side["delay_s"] == 0.0
    assert "delay: not determined by the data" in r.stdout
    assert abs(side["cost"] - side["expected_cost"]) < 2 * side["expected_cost_sd"]
    truth = [(7.0694, 0.2183), (55.370, 0.04686)]
    for mode, (f, z) in zip(side["poles"], truth, strict=True):
        assert abs(mode["frequency_hz"] - f) < 3 * mode["frequency_hz_std"]
        assert abs(mode["damping"] - z) < 3 * mode["damping_std"]
    fitted = load_model(tmp_path / "fit.yaml")
    assert fitted.controller == load_model(model).controller
    # a fresh record of the true loop: the fitted model shows no cause
    assert _run("simulate", model, "--duration", 60, "--seed", 9, "--out", "new.npz",
                cwd=tmp_path).returncode == 0  # fmt: skip
    r = _run("diagnose", "fit.yaml", "new.npz", "--json", "d.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "cause: none" in r.stdout
    assert json.loads((tmp_path / "d.json").read_text())


@pytest.mark.parametrize(
    "args, match",
    [
        (["--delay", "-1"], r"argument --delay: expected \"auto\" or samples >= 0, got '-1'"),
        (["--order", "x"], r"argument --order: expected \"auto\" or an integer >= 1, got 'x'"),
        (["--band", "5,1"], r"argument --band: expected 0 <= LO < HI, got '5,1'"),
    ],
)
def test_bad_fit_options_exit_2_with_an_error(tmp_path, args, match):
    r = _run("fit", "res.npz", "--out", "m.yaml", *args, cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert re.search(match, r.stderr), r.stderr


def test_a_missing_result_file_is_an_error_with_exit_2(tmp_path):
    r = _run("fit", "nothing.npz", "--out", "m.yaml", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr


def test_a_discrete_pair_at_full_damping_stays_a_pair_with_two_columns():
    """At ζ -> 1 (the damping parameter at its bound) a discrete pair's radius underflowed to
    0: the pole became real, its columns one instead of two, and a refinement indexed past
    them (seen fitting a correction to a dead zone's BLA). The radius is floored (5e-131)."""
    from mr_ident.numerics.fit.basis import columns, from_params

    u = np.array([40.0, 2.0, 0.5])  # pair: ζ at its bound, angle π σ(2); one real pole
    poles = from_params(u, [True, False], "discrete", 1e-3, 2 * np.pi * 10.0)
    assert poles[0].imag > 0 and abs(poles[0]) < 1e-100
    z = np.exp(1j * np.linspace(0.1, 3.0, 50))
    assert columns(poles, z, "discrete", 1e-3).shape == (50, 3)
