# SPDX-License-Identifier: Apache-2.0
"""A loop excited at its setpoint: simulation, the derivation, identification, its std.

The derivation (``mr_ident.numerics.lifted.setpoint``): with r the controller's setpoint,
``r_up -> [y_h; u_h]`` is LTI at the high rate (r_up: the setpoint's samples the controller
takes, zeros between), ``G_y = P_h G_u``, and P_h is determined on every bin but the hold's
zeros (multiples of fs_high/F).
"""

from dataclasses import replace

import numpy as np
import pytest
from conftest import brute_force_loop
from scipy import signal

from mr_ident.errors import ConfigError, DimensionError, ModelError
from mr_ident.io.modelfile import model_from_dict, model_to_dict
from mr_ident.numerics.identify import identify
from mr_ident.numerics.lifted.setpoint import hold_zero_bins, hold_zone, sampled_setpoint
from mr_ident.numerics.systems.simulate import simulate


@pytest.fixture(scope="module")
def setpoint_model(paper_model):
    return replace(paper_model, injection="setpoint")


def _errors(res, model, N):
    P = model.plant_frf(N)[1:]
    return np.abs(res.plant.response - P) / np.abs(P), P


@pytest.mark.parametrize("phase,delay", [(0, 0), (1, 0), (2, 1), (0, 4)])
def test_the_simulated_setpoint_loop_equals_its_definition_sample_by_sample(
    setpoint_model, phase, delay
):
    model = replace(setpoint_model, sample_phase=phase, control_delay=delay)
    rng = np.random.default_rng(1)
    r, v = rng.standard_normal((1200, 1)), 0.1 * rng.standard_normal((1200, 1))
    sim = simulate(model, reference=r, noise=v)
    u, y = brute_force_loop(model, r, v)
    # round-off of two recursions over 400 periods, relative to each signal's scale
    np.testing.assert_allclose(sim.u, u, atol=1e-9 * np.abs(u).max())
    np.testing.assert_allclose(sim.y, y, atol=1e-9 * np.abs(y).max())
    # only the samples the controller takes act: the others of r change nothing
    r2 = r.copy()
    r2[np.arange(1200) % 3 != phase] = 0.0
    np.testing.assert_allclose(simulate(model, reference=r2, noise=v).u, sim.u, atol=1e-12)


def test_a_periodic_setpoint_gives_P_h_as_y_over_u_except_at_the_hold_zeros(setpoint_model):
    """The derivation, noise-free: Y_h = P_h U_h on every bin; U_h = 0 at the hold's zeros."""
    period, F = 2400, 3
    one = np.random.default_rng(2).standard_normal((period, 1))
    sim = simulate(setpoint_model, reference=np.tile(one, (6, 1)))
    U, Y = (np.fft.fft(x[-period:, 0]) for x in (sim.u, sim.y))
    P = setpoint_model.plant_frf(period)[:, 0, 0]
    k = np.arange(period // 2 + 1)
    zero = (k % (period // F) == 0) & (k > 0)
    # round-off relative to |U|'s scale: the zeros are exact, the rest is P_h
    assert np.abs(U[: period // 2 + 1][zero]).max() < 1e-9 * np.abs(U).max()
    with np.errstate(divide="ignore", invalid="ignore"):  # 0/0 at the zeros themselves
        rel = np.abs(Y[k] / U[k] - P) / np.abs(P)
    assert rel[~zero].max() < 1e-8


def test_the_sampled_setpoint_takes_the_controllers_samples_at_either_rate():
    r = np.arange(12.0)[:, None]
    up = sampled_setpoint(r, 3, 1, 12)
    np.testing.assert_array_equal(up[:, 0], [0, 1, 0, 0, 4, 0, 0, 7, 0, 0, 10, 0])
    np.testing.assert_array_equal(sampled_setpoint(r[1::3], 3, 1, 12), up)
    with pytest.raises(DimensionError, match="neither N = 12"):
        sampled_setpoint(r[:5], 3, 1, 12)


def test_the_hold_zone_flags_the_bins_whose_window_reaches_a_zero():
    N, F = 3000, 3  # zeros at 1000 (and 2000 > N/2)
    np.testing.assert_array_equal(hold_zero_bins(N, F), [1000])
    flagged = np.flatnonzero(hold_zone(N, F, np.full(N // 2, 4))) + 1
    np.testing.assert_array_equal(flagged, np.arange(996, 1005))


def test_noise_free_the_setpoint_estimate_is_exact_away_from_the_hold_zeros(setpoint_model):
    sim = simulate(setpoint_model, duration=120.0, rng=np.random.default_rng(3))
    N = sim.n_samples
    res = identify(
        sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, injection="setpoint", degree=4, n=None
    )
    err, _ = _errors(res, setpoint_model, N)
    ok = ~res.undetermined
    assert res.injection == "setpoint" and res.pfg_data is None
    # the local polynomial of degree 4 leaves 2.4e-9 at worst (resonance); 1e-8 the claim
    assert np.nanmax(err[ok, 0, 0]) < 1e-8
    zeros = hold_zero_bins(N, 3) - 1
    assert np.isnan(res.plant.response[zeros]).all() and res.undetermined[zeros].all()
    assert res.undetermined.sum() == 2 * res.n_used[zeros[0]] + 1
    # the default (degree 2, auto): the same bias as the plant-input loop's LPM
    res2 = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, injection="setpoint")
    assert np.median(_errors(res2, setpoint_model, N)[0][~res2.undetermined]) < 1e-6


def test_with_noise_the_setpoint_std_is_honest(setpoint_model):
    """|error|/std over every bin off the flagged zone: rms 1 up to the variance estimate's.

    n = 8: q = 2n + 1 - 6 = 11 residual degrees of freedom per window, E|e|^2/std^2 about
    q/(q - 1) = 1.1 (rms 1.05); about 4 200 independent windows at 300 s, whose mean's sd is
    about 0.01: the bounds 0.9 and 1.2 are beyond 10 sd on either side of 1.0 - 1.05.
    """
    model = replace(setpoint_model, noise_std=0.02)
    sim = simulate(model, duration=300.0, rng=np.random.default_rng(4))
    res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, injection="setpoint", n=8)
    err = np.abs(res.plant.response - model.plant_frf(sim.n_samples)[1:])
    z = (err / res.plant.std)[~res.undetermined]
    assert 0.9 < np.sqrt(np.mean(z**2)) < 1.2


def test_with_noise_the_setpoint_estimate_beats_welchs_indirect_estimate(setpoint_model):
    """Median relative error over the bins 1 Hz or more from the hold's zeros (600 s, 0.02).

    Welch's indirect estimate ``S_ry / S_ru`` at its best of five segment lengths on the
    same data (1.7 % at 600 samples here) against the default identification (1.1 %).
    """
    model = replace(setpoint_model, noise_std=0.02)
    sim = simulate(model, duration=600.0, rng=np.random.default_rng(3))
    res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, injection="setpoint")
    err, _ = _errors(res, model, sim.n_samples)
    f = res.plant.frequency
    away = np.minimum(f % 80.0, 80.0 - f % 80.0) > 1.0
    ours = np.median(err[away, 0, 0])
    welch = []
    for nper in (300, 600, 1200, 2400, 4800):
        fw, Sry = signal.csd(sim.r[:, 0], sim.y[:, 0], fs=240.0, nperseg=nper)
        _, Sru = signal.csd(sim.r[:, 0], sim.u[:, 0], fs=240.0, nperseg=nper)
        Pw = model.plant_discrete().freqresp(fw)[:, 0, 0]
        aw = (np.minimum(fw % 80.0, 80.0 - fw % 80.0) > 1.0) & (fw > 0)
        welch.append(np.median(np.abs(Sry / Sru - Pw)[aw] / np.abs(Pw[aw])))
    assert ours < min(welch)


def test_a_setpoint_at_the_controllers_rate_gives_the_same_estimate(setpoint_model):
    model = replace(setpoint_model, sample_phase=1)
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(5))
    kw = dict(fs_high=240.0, ratio=3, injection="setpoint", phase=1, n=8)
    high = identify(sim.r, sim.u, sim.y, **kw)
    low = identify(sim.r[1::3], sim.u, sim.y, **kw)
    np.testing.assert_array_equal(low.plant.response, high.plant.response)


def test_a_mimo_setpoint_loop_is_identified_as_exactly_as_with_r_at_the_plant_input(
    mimo_model,
):
    """Noise-free, 200 s: the worst bin of either is the slow plant's (0.5 Hz, the local
    model's transient bias, about 1e-5 of the scale); elsewhere round-off."""
    errors = []
    for injection in ("setpoint", "plant_input"):
        model = replace(mimo_model, injection=injection)
        sim = simulate(model, duration=200.0, rng=np.random.default_rng(6))
        res = identify(
            sim.r,
            sim.u,
            sim.y,
            fs_high=100.0,
            ratio=2,
            injection=injection,
            degree=4,
            method="lpm",
            n=None,
        )
        P = model.plant_frf(sim.n_samples)[1:]
        err = np.abs(res.plant.response - P).max(axis=(1, 2)) / np.abs(P).max()
        errors.append(err if res.undetermined is None else err[~res.undetermined])
    setpoint, plant_input = errors
    assert np.median(setpoint) < 1e-9
    assert np.max(setpoint) < 2.0 * np.max(plant_input)


def test_missing_samples_of_a_setpoint_loop_are_unknowns_of_its_fit(setpoint_model):
    sim = simulate(setpoint_model, duration=120.0, rng=np.random.default_rng(7))
    y = sim.y.copy()
    y[np.random.default_rng(8).choice(sim.n_samples, sim.n_samples // 100, replace=False)] = np.nan
    res = identify(sim.r, sim.u, y, fs_high=240.0, ratio=3, injection="setpoint")
    err, _ = _errors(res, setpoint_model, sim.n_samples)
    assert res.n_missing[0] == sim.n_samples // 100
    assert np.median(err[~res.undetermined]) < 1e-5


@pytest.mark.parametrize("method", ["time-lifted", "structured", "etfe"])
def test_a_setpoint_loop_refuses_the_methods_that_need_r_at_the_plant_input(
    setpoint_model, method
):
    sim = simulate(setpoint_model, duration=20.0, rng=np.random.default_rng(9))
    with pytest.raises(ConfigError, match="freq-lifted or lpm"):
        identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, injection="setpoint", method=method)


def test_the_models_injection_is_read_written_and_checked(paper_model):
    d = model_to_dict(replace(paper_model, injection="setpoint"))
    assert d["injection"] == "setpoint"
    assert model_from_dict(d).injection == "setpoint"
    assert "injection" not in model_to_dict(paper_model)
    with pytest.raises(ModelError, match="injection must be one of plant_input, setpoint"):
        model_from_dict(d | {"injection": "reference"})
    with pytest.raises(ModelError, match="needs a controller"):
        model_from_dict({k: v for k, v in d.items() if k != "controller"})
    # the plant alone (a diagnosis simulates it so): r is its input whatever the loop's is
    alone = replace(paper_model, injection="setpoint", controller=None)
    assert not alone.setpoint and alone.n_r == alone.n_u


def test_diagnose_simulates_the_model_with_r_at_the_setpoint_and_finds_the_plants_gain(
    paper_model, tmp_path
):
    """The model file says nothing of where r enters: the data do (the held u)."""
    from mr_ident.app.diagnose import diagnose_recording
    from mr_ident.app.requests import DiagnoseRequest, Reading
    from mr_ident.io.datafile import write_data

    true = replace(paper_model, injection="setpoint", noise_std=0.02, plant_gain=1.2)
    paths = []
    for seed in (1, 2):
        sim = simulate(true, duration=60.0, rng=np.random.default_rng(seed))
        paths.append(tmp_path / f"run{seed}.npz")
        write_data(paths[-1], sim.r, sim.u, sim.y, fs_high=240.0, ratio=3)
    got = diagnose_recording(
        DiagnoseRequest(Reading(paths[0]), paper_model, validate=paths[1], max_causes=1)
    )
    d = got.diagnosis
    assert got.model.injection == "setpoint"
    assert [a.cause for a in d.applied] == ["gain_error"]
    assert abs(d.applied[0].parameters["gain"] - 1.2) < 0.01
    assert d.relation is not None and d.relation.exact  # u is K (r - y), to round-off


def test_a_live_windows_diagnosis_takes_r_where_the_window_shows_it(paper_model):
    from mr_ident.diagnosis.monitoring.monitor import diagnose_window

    true = replace(paper_model, injection="setpoint", noise_std=0.02, plant_gain=1.2)
    sim = simulate(true, duration=60.0, rng=np.random.default_rng(11))
    d = diagnose_window(paper_model, replace(sim, first=3000))
    assert d.applied and d.applied[0].cause == "gain_error"
    assert abs(d.applied[0].parameters["gain"] - 1.2) < 0.01


@pytest.mark.parametrize(("gain", "level"), [(1.0, "ok"), (1.2, "error")])
def test_the_plant_monitoring_watches_a_setpoint_loop(paper_model, gain, level):
    """Against the model: no alarm where the plant is the model's, an error where it is
    20 % stronger (|20 log10 1.2| = 1.6 dB is below the 6 dB error size: error_db 1)."""
    from mr_ident.diagnosis.monitoring.drift import Reference
    from mr_ident.diagnosis.monitoring.monitor import PlantWatch
    from mr_ident.io.config import IdentConfig
    from mr_ident.live.estimate import estimate

    true = replace(paper_model, injection="setpoint", noise_std=0.02, plant_gain=gain)
    cfg = IdentConfig(fs_high=240.0, ratio=3, monitor_hold=1, monitor_error_db=1.0)
    watch = PlantWatch(Reference.of_model(paper_model), paper_model, cfg)
    sim = simulate(true, duration=60.0, rng=np.random.default_rng(12))
    state = watch.observe(estimate(sim, cfg))
    assert state.level == level


def test_an_r_held_at_the_plant_input_takes_the_setpoints_estimator(paper_model):
    """r published at the controller's rate and added to the plant input: the lifted
    regressor has rank one per block (every lifted fit NaN); the high-rate fit on r gives
    P_h away from the hold's zeros to the local polynomial's bias, noise-free."""
    F = paper_model.ratio
    r = np.repeat(np.random.default_rng(0).standard_normal((4800, 1)), F, axis=0)
    sim = simulate(paper_model, reference=r)
    res = identify(sim.r, sim.u, sim.y, fs_high=paper_model.fs_high, ratio=F)
    err, _ = _errors(res, paper_model, sim.n_samples)
    assert (
        res.undetermined is not None and np.isnan(err[hold_zero_bins(sim.n_samples, F) - 1]).all()
    )
    assert float(np.nanmedian(err[~res.undetermined])) < 1e-6
    assert res.pfg_data is None
    with pytest.raises(ConfigError, match="r is held over blocks of 3 samples: .* got method"):
        identify(sim.r, sim.u, sim.y, fs_high=paper_model.fs_high, ratio=F, method="time-lifted")


def test_a_periodic_setpoint_gives_the_bla_as_p_h_and_no_pfg_from_data(
    setpoint_model, tmp_path, capsys
):
    """`identify --period` on realizations of a periodic setpoint: the BLA Y/U is P_h at the
    excited lines (the derivation's single-term response), to round-off of the periodic
    steady state; the PFG from data, defined for r at the plant input, is left out."""
    from mr_ident.cli import main
    from mr_ident.numerics.excitation.multisine import design

    ms = design(fs_high=240.0, period=2400, band=(0.5, 100.0), kind="odd", periods=3,
                realizations=2, ratio=3)  # fmt: skip
    runs = [simulate(setpoint_model, reference=ms.r[m]) for m in range(2)]
    r, u, y = (np.stack([getattr(s, k)[2400:, 0] for s in runs]) for k in "ruy")
    np.savez(tmp_path / "p.npz", r=r, u=u, y=y, fs_high=240.0, ratio=3)
    out = tmp_path / "bla.npz"
    assert main(["identify", str(tmp_path / "p.npz"), "--period", "2400", "--out", str(out)]) == 0
    assert "r is the controller's setpoint: no PFG from data" in capsys.readouterr().err
    z = np.load(out)
    P = setpoint_model.plant_discrete().freqresp(z["frequency"])[:, 0, 0]
    # the periodic steady state's round-off relative to P (1e-11 here)
    assert np.max(np.abs(z["P"][:, 0, 0] / P - 1)) < 1e-8 and "pfg_data" not in z
