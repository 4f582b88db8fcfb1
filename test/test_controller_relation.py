# SPDX-License-Identifier: Apache-2.0
"""The controller's own equation (diagnosis.controller.relation) on loops drawn at random.

The machine's loop is run sample by sample here, its controller the nominal K_l followed
by a notch discretised with scipy's bilinear transform (prewarped by hand, not
``realize.notch``) and a delay and sampling phase of its own; the equation must hold
exactly where the controller is the model's and find the notch, delay and offset to
1e-6 where it is not; on a 2x2 loop too (a notch on both channels with a sampling
offset). Tolerances: the values to 1e-6 relative (measured 1e-13-1e-10);
the relation error of the model's own controller below ``EXACT`` (measured 1e-15-1e-12).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from mr_bench.scenarios import draw_loop, draw_scenario
from mr_ident.diagnosis.causes.registry import CAUSES
from mr_ident.diagnosis.controller.relation import EXACT, Equation, relate
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import loop_poles


def _machine_notch(f: float, zeta: float, depth: float, fs_low: float) -> tuple:
    """(b, a) of the notch at fs_low by scipy's bilinear transform, prewarped at f."""
    w = 2 * np.pi * f
    wp = 2 * fs_low * np.tan(w / (2 * fs_low))  # the analogue frequency that maps onto f
    return scipy.signal.bilinear(
        [1.0, 2 * depth * zeta * wp, wp * wp], [1.0, 2 * zeta * wp, wp * wp], fs=fs_low
    )


def _machine_loop(model, notch, phase: int, delay: int, r: np.ndarray, v: np.ndarray):
    """u, y of the loop run sample by sample: K_l then the notch (b, a) at the low rate."""
    P = model.plant_discrete()
    K = model.controller_ss()
    F, N = model.ratio, r.shape[0]
    b, a = notch
    x, xk = np.zeros(P.A.shape[0]), np.zeros(K.A.shape[0])
    zi = np.zeros(2)  # the notch's direct form II transposed state
    pending: dict[int, float] = {}
    held = 0.0
    u, y = np.zeros(N), np.zeros(N)
    for n in range(N):
        y[n] = (P.C @ x)[0] + v[n]
        if n % F == phase:
            k_out = (K.C @ xk + K.D @ y[n : n + 1])[0]
            xk = K.A @ xk + K.B @ y[n : n + 1]
            out, zi = scipy.signal.lfilter(b, a, [k_out], zi=zi)
            pending[n + delay] = float(out[0])
        if n in pending:
            held = pending.pop(n)
        u[n] = r[n] - held
        x = P.A @ x + P.B[:, 0] * u[n]
    return u, y


@pytest.mark.parametrize("seed", [4, 8, 9, 12])
def test_the_equation_finds_a_notch_delay_and_offset_of_a_loop_run_sample_by_sample(seed):
    rng = np.random.default_rng(seed)
    loop = draw_loop(rng, duration=4.0, ratios=(2, 3))
    m = loop.nominal
    F, fl = m.ratio, m.fs_low
    f, zeta, depth = fl * rng.uniform(0.05, 0.4), rng.uniform(0.1, 0.5), rng.uniform(0.0, 0.3)
    phase, delay = int(rng.integers(1, F)), int(rng.integers(1, F + 1))
    true = replace(
        m, sample_phase=phase, control_delay=delay, controller_notches=((f, zeta, depth),)
    )
    assert np.all(np.abs(loop_poles(true)) < 0.999)  # these seeds' machine loops are stable
    N = 1500 * F
    r = rng.standard_normal(N)
    v = 0.05 * rng.standard_normal(N)
    u, y = _machine_loop(m, _machine_notch(f, zeta, depth, fl), phase, delay, r, v)
    rec = LoopData(r, u, y, fs_high=m.fs_high, ratio=F)
    assert Equation(rec, m).error(true) < EXACT
    rel = relate(m, rec)
    assert rel is not None and rel.exact and rel.error_before > 1e-3
    found = {c.cause: CAUSES[c.cause].named(c, m) for c in rel.choices}
    assert found.keys() == {"controller_notch", "control_delay", "sampling_offset"}
    assert found["control_delay"]["delay_samples"] == delay
    assert found["sampling_offset"]["offset_samples"] == phase
    got = found["controller_notch"]
    np.testing.assert_allclose(
        [got["frequency_hz"], got["damping"], got["depth"] + 1], [f, zeta, depth + 1], rtol=1e-6
    )
    assert all(s < 1e-6 for sd in rel.std for s in sd.values())


@pytest.mark.parametrize("cause", ["gain_error", "input_delay", "periodic_disturbance"])
def test_causes_outside_the_controller_leave_the_equation_exact(cause):
    sc = draw_scenario([cause], np.random.default_rng(40), duration=8.0)
    rel = relate(sc.nominal, sc.data)
    assert rel is not None and rel.exact and rel.choices == []
    assert rel.error_before < 1e-9


def test_a_measured_u_with_its_own_noise_is_not_taken_for_the_controllers_output():
    sc = draw_scenario(["controller_notch"], np.random.default_rng(41), duration=8.0)
    d = sc.data
    noisy = replace(
        d, u=d.u + 1e-3 * np.std(d.u) * np.random.default_rng(0).standard_normal(d.u.shape)
    )
    rel = relate(sc.nominal, noisy)
    assert rel is not None and not rel.exact and rel.choices == []
    assert "not the model controller's output" in rel.text()


def test_open_loop_and_a_slow_y_have_no_equation():
    sc = draw_scenario(["gain_error"], np.random.default_rng(42), duration=4.0)
    assert relate(replace(sc.nominal, controller=None), sc.data) is None
    d, F = sc.data, sc.nominal.ratio
    if F > 1:
        slow = LoopData(d.r, d.u, d.y[::F], fs_high=d.fs_high, ratio=F)
        assert relate(sc.nominal, slow) is None


def test_diagnose_applies_what_the_equation_settled_and_rules_out_the_rest():
    from mr_ident.diagnosis import diagnose

    sc = draw_scenario(["controller_notch"], np.random.default_rng(43), duration=20.0)
    d = diagnose(sc.nominal, sc.data)
    assert d.relation is not None and d.relation.exact
    assert [c.cause for c in d.applied] == ["controller_notch"]
    h = sc.hidden[0].parameters
    np.testing.assert_allclose(
        [d.parameters[k] for k in ("frequency_hz", "damping")],
        [h["frequency_hz"], h["damping"]],
        rtol=1e-6,
    )
    assert abs(d.parameters["depth"] - h["depth"]) < 1e-6
    ruled = {c.cause for c in d.ranking if not c.applicable and "equation" in c.description}
    assert ruled == {
        "controller_gain",
        "controller_notch",
        "controller_retuned",
        "control_delay",
        "sampling_offset",
    }


def test_a_two_by_two_loop_with_a_notch_on_both_channels_and_an_offset(mimo_model):
    from mr_ident import simulate

    m = replace(mimo_model, noise_std=0.01)
    f = 0.15 * m.fs_low
    true = replace(m, sample_phase=1, controller_notches=((f, 0.2, 0.0),))
    rel = relate(m, simulate(true, duration=20.0, rng=np.random.default_rng(0)))
    assert rel is not None and rel.exact
    assert [c.cause for c in rel.choices] == ["sampling_offset", "controller_notch"]
    np.testing.assert_allclose(rel.choices[1].x, (f, 0.2, 0.0), atol=1e-8)


def test_y_logged_a_sample_late_is_not_taken_for_a_control_delay():
    """``max_causes=0``: the skew is judged before any cause is sought (contradicted, and
    so not applied, with or without them); the search for causes of the skewed record
    (three additive modes) took 26 of the test's 29 s."""
    from mr_ident.diagnosis import diagnose

    sc = draw_scenario(["gain_error"], np.random.default_rng(102), duration=8.0)
    d, F = sc.data, sc.nominal.ratio
    n = (d.n_samples - 1) // F * F
    skewed = LoopData(d.r[:n], d.u[:n], d.y[1 : n + 1], fs_high=d.fs_high, ratio=F)
    rel = relate(sc.nominal, skewed)
    assert rel is not None and rel.exact and rel.choices  # the shift closes the equation...
    dg = diagnose(sc.nominal, skewed, max_causes=0)
    assert dg.relation is not None and dg.relation.contradicted  # ...but not y: not applied
    assert not dg.relation.settles
    assert "skewed in time" in dg.relation.text()


def test_a_control_delay_shorter_than_modelled():
    from mr_ident import simulate

    sc = draw_scenario(["gain_error"], np.random.default_rng(44), duration=8.0)
    model = replace(sc.nominal, control_delay=3)
    true = replace(model, control_delay=1)
    assert np.all(np.abs(loop_poles(true)) < 1)  # (the model's own loop need not be stable)
    rel = relate(model, simulate(true, duration=8.0, rng=np.random.default_rng(1)))
    assert rel is not None and rel.exact
    assert [(c.cause, c.x) for c in rel.choices] == [("control_delay", (-2.0,))]
    text = CAUSES["control_delay"].describe({"delay_samples": -2.0})
    assert text == "the control output is applied 2 high-rate samples earlier than modelled"
