# SPDX-License-Identifier: Apache-2.0
"""The loop's structure read from its data, and what contradicts it refused."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mr_ident.app.identify import identify_recording
from mr_ident.app.requests import IdentifyRequest, Reading
from mr_ident.errors import ConfigError
from mr_ident.io.datafile import read_identification, write_data, write_result
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.structure import hold_of, read_structure, settle_structure
from mr_ident.numerics.systems.simulate import simulate


def _loop(F: int, phase: int, delay: int, injection: str, seed: int = 0):
    """A drawn first-order loop at F with a gentle P controller (stable for every delay)."""
    rng = np.random.default_rng(seed)
    pole = float(rng.uniform(2.0, 20.0))
    model = model_from_dict(
        {
            "fs_high": 100.0 * F,
            "ratio": F,
            "plant": {"num": [pole], "den": [1.0, pole]},
            "controller": {"num": [float(rng.uniform(0.05, 0.3))], "den": [1.0]},
            "sample_phase": phase,
            "control_delay": delay,
            "injection": injection,
            "noise_std": 0.01,
        }
    )
    return model, simulate(model, duration=20.0, rng=rng)


@pytest.mark.parametrize("injection", ["plant_input", "setpoint"])
@pytest.mark.parametrize("F,phase,delay", [(2, 0, 0), (3, 2, 0), (4, 1, 2), (5, 3, 7), (8, 7, 1)])
def test_f_the_hold_and_where_r_enters_are_read_from_the_data(injection, F, phase, delay):
    model, sim = _loop(F, phase, delay, injection, seed=F + phase)
    found = read_structure(sim.r, sim.u)
    assert (found.ratio, found.hold_start, found.injection) == (F, (phase + delay) % F, injection)
    if injection == "setpoint":
        assert found.phase == phase  # white r: the held u follows r at the sampling phase
    assert f"F = {F}" in found.describe()


def test_a_measured_u_shows_no_hold_and_a_held_r_leaves_the_injection_open():
    _, sim = _loop(3, 0, 0, "plant_input")
    noisy = sim.u + 1e-3 * np.random.default_rng(1).standard_normal(sim.u.shape)
    found = read_structure(sim.r, noisy)
    assert (found.held, found.ratio, found.injection) == ("none", None, None)
    held_r = np.repeat(sim.r[::3], 3, axis=0)
    both = read_structure(held_r, held_r - np.repeat(sim.u[::3] - sim.r[::3], 3, axis=0))
    assert (both.held, both.ratio, both.injection) == ("u and u - r", 3, None)
    assert hold_of(np.ones((300, 1))) is None  # constant: nothing to read
    open_loop = read_structure(sim.r, sim.r.copy())
    assert (open_loop.held, open_loop.ratio, open_loop.injection) == ("u = r", None, "plant_input")
    got = settle_structure(open_loop, ratios=[("--ratio", 3)], injections=[], phases=[])
    assert got.notes == ()  # nothing to warn of: r is u


def test_a_hold_is_read_through_round_off_and_missing_samples():
    rng = np.random.default_rng(2)
    held = np.repeat(rng.standard_normal((400, 1)), 4, axis=0)
    r = rng.standard_normal((1600, 1))
    u = (r - held).astype(np.float32).astype(float)  # logged as float32
    u[rng.choice(1600, 16, replace=False)] = np.nan
    assert hold_of(u - r) == (4, 0)


def test_what_contradicts_the_data_is_refused_naming_both():
    _, sim = _loop(3, 1, 0, "setpoint")
    found = read_structure(sim.r, sim.u)
    with pytest.raises(ConfigError, match=r"u changes every 3 samples: F = 3, not 4 \(--ratio\)"):
        settle_structure(found, ratios=[("--ratio", 4)], injections=[], phases=[])
    with pytest.raises(ConfigError, match="the model says injection plant_input"):
        settle_structure(found, ratios=[], injections=[("the model", "plant_input")], phases=[])
    with pytest.raises(ConfigError, match="sampled at sample 1 of each block, not at 0"):
        settle_structure(found, ratios=[], injections=[], phases=[("the model", 0)])
    got = settle_structure(found, ratios=[("the model", 3)], injections=[], phases=[])
    assert (got.ratio, got.injection, got.phase, got.notes) == (3, "setpoint", 1, ())


def test_where_the_data_do_not_tell_the_given_is_taken_and_said():
    _, sim = _loop(3, 0, 0, "plant_input")
    noisy = sim.u + 1e-3 * np.random.default_rng(1).standard_normal(sim.u.shape)
    found = read_structure(sim.r, noisy)
    with pytest.raises(ConfigError, match="ratio F unknown: u shows no hold"):
        settle_structure(found, ratios=[], injections=[], phases=[])
    got = settle_structure(found, ratios=[("--ratio", 3)], injections=[], phases=[])
    assert got.injection == "plant_input" and "{injection} setpoint" in got.notes[0]
    got = settle_structure(
        found, ratios=[("--ratio", 3)], injections=[("--injection", "setpoint")], phases=[]
    )
    assert got.injection == "setpoint" and got.notes == ()


def test_identify_reads_a_setpoint_loop_without_being_told(paper_model, tmp_path):
    """No ratio anywhere, no injection: F, the setpoint and its phase from the data."""
    model = replace(paper_model, injection="setpoint", sample_phase=2)
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(3))
    path = tmp_path / "setpoint.npz"
    np.savez(path, r=sim.r, u=sim.u, y=sim.y, fs_high=240.0)  # no ratio in the file
    heard = []
    got = identify_recording(IdentifyRequest(Reading(path), n=8), heard.append)
    ident = got.identification
    assert (got.ratio, ident.injection) == (3, "setpoint")
    assert "samples r at sample 2" in got.structure
    assert any("not determined" in n.text for n in heard)
    P = paper_model.plant_frf(sim.n_samples)[1:]
    err = np.abs(ident.plant.response - P) / np.abs(P)
    assert np.median(err[~ident.undetermined]) < 1e-6
    out = tmp_path / "result.npz"
    write_result(out, ident, got.structure)
    back = read_identification(out)
    assert back.injection == "setpoint"
    np.testing.assert_array_equal(back.undetermined, ident.undetermined)
    assert str(np.load(out)["structure"]) == got.structure


def test_identify_refuses_a_ratio_or_a_model_the_data_contradict(paper_model, tmp_path):
    sim = simulate(paper_model, duration=20.0, rng=np.random.default_rng(4))
    path = tmp_path / "plant_input.npz"
    write_data(path, sim.r, sim.u, sim.y, fs_high=240.0, ratio=3)
    with pytest.raises(ConfigError, match="u - r changes every 3 samples: F = 3, not 4"):
        identify_recording(IdentifyRequest(Reading(path), ratio=4))
    wrong = replace(paper_model, injection="setpoint")
    with pytest.raises(ConfigError, match="r enters at the plant input; the model says"):
        identify_recording(IdentifyRequest(Reading(path), model=wrong))


def test_the_live_estimate_reads_a_setpoint_window_and_refuses_a_contradicting_parameter(
    paper_model,
):
    from mr_ident.io.config import IdentConfig
    from mr_ident.live.estimate import estimate

    model = replace(paper_model, injection="setpoint", sample_phase=1)
    sim = simulate(model, duration=30.0, rng=np.random.default_rng(5))
    window = replace(sim, first=300)  # an absolute index on the F grid, as the aligner cuts
    est = estimate(window, IdentConfig(fs_high=240.0, ratio=3, n=8))
    ident = est.identification
    assert ident.injection == "setpoint" and est.phase == 1 and "setpoint" in est.structure
    P = paper_model.plant_frf(sim.n_samples)[1:]
    err = np.abs(ident.plant.response - P) / np.abs(P)
    assert np.median(err[~ident.undetermined]) < 1e-4  # the LPM's bias at 30 s: about 4e-6
    with pytest.raises(ConfigError, match="; injection says plant_input"):
        estimate(window, IdentConfig(fs_high=240.0, ratio=3, n=8, injection="plant_input"))
    with pytest.raises(ConfigError, match="F = 3, not 4"):
        estimate(window, IdentConfig(fs_high=240.0, ratio=4, n=12))


@pytest.mark.parametrize("injection", ["plant_input", "setpoint"])
@pytest.mark.parametrize("delay", [0, 1])
def test_a_held_r_leaves_where_it_enters_to_the_controllers_equation(
    paper_model, injection, delay
):
    """r at the controller's rate, held (a PID's logged reference): with no control delay r
    and u are held alike, and the controller's equation with the logged y tells where r
    entered (noise 0.02); with one, the hold does."""
    model = replace(paper_model, injection=injection, noise_std=0.02, control_delay=delay)
    rng = np.random.default_rng(7)
    held = np.repeat(rng.standard_normal(4800), 3)[:, None] * (
        1e3 if injection == "plant_input" else 1
    )
    sim = simulate(model, reference=held, rng=rng)
    found = read_structure(sim.r, sim.u, sim.y)
    assert (found.ratio, found.injection) == (3, injection)
    if delay == 0:  # r and u change on the same samples: the hold alone cannot tell
        assert found.held == "u and u - r"
        assert read_structure(sim.r, sim.u).injection is None  # without y: not told


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_a_u_logged_at_the_controllers_rate_is_held_and_read(tmp_path, suffix):
    """The PID's output at its own rate (N/F values): a CSV gives it on the rows where each
    value was applied, an NPZ from ``u_phase``; held to the high rate, the data show the
    setpoint loop and P_h comes out as from the high-rate u."""
    model, sim = _loop(3, 1, 1, "setpoint", seed=4)
    s = (model.sample_phase + model.control_delay) % 3  # the hold's start
    path = tmp_path / f"slow_u{suffix}"
    if suffix == ".npz":
        np.savez(path, r=sim.r, u=sim.u[s::3], y=sim.y, fs_high=300.0, ratio=3, u_phase=s)
    else:
        u = np.full(sim.u.shape, np.nan)
        u[s::3] = sim.u[s::3]
        write_data(path, sim.r, u, sim.y, fs_high=300.0, ratio=3)
    got = identify_recording(IdentifyRequest(Reading(path), ratio=3, n=8), lambda n: None)
    assert got.identification.injection == "setpoint" and "u changes every 3" in got.structure
    full = identify_recording(
        IdentifyRequest(Reading(_written(tmp_path, sim)), ratio=3, n=8), lambda n: None
    )
    a, b = got.identification.plant.response, full.identification.plant.response
    ok = ~got.identification.undetermined
    # the first s samples of u are missing (before the first value): estimated, not exact
    assert np.median(np.abs(a - b)[ok] / np.abs(b)[ok]) < 1e-2


def _written(tmp_path, sim):
    path = tmp_path / "full.npz"
    write_data(path, sim.r, sim.u, sim.y, fs_high=300.0, ratio=3)
    return path


MOTOR_BENCH = Path(__file__).resolve().parents[2] / "shared" / "data" / "motor_bench"


@pytest.mark.skipif(
    not (MOTOR_BENCH / "MultisineTypeA.mat").exists(),
    reason="the motor bench's measured data (../shared/data/motor_bench) is not beside the clone",
)
def test_measured_data_whose_u_is_the_drives_current_shows_no_hold():
    """Real measurements (a motor bench, FdiTools, MIT): u is the measured current after the
    drive's current loop, with its noise: no hold, so F and where r enters are the user's."""
    from scipy.io import loadmat

    d = loadmat(MOTOR_BENCH / "MultisineTypeA.mat")
    r, u, y = (np.asarray(d[k], float).reshape(-1, 1) for k in ("iq_refx", "iq_adx", "theta_mx"))
    found = read_structure(r, u, y)
    assert (found.held, found.ratio, found.injection) == ("none", None, None)
    assert "u shows no hold" in found.describe()
