# SPDX-License-Identifier: Apache-2.0
"""State-space realisations (numerics/systems/realize.py) against closed forms and direct
evaluation.

Tolerances: the simulated step response of a sixth-order modal plant within 1e-9 of its
peak against the closed-form continuous step response (a held step is exact under ZOH);
frequency responses within 1e-9 relative of the polynomial evaluated directly (away from
poles); splitting a mode off and adding it back reproduces the system to 1e-10.
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.realize import (
    lowpass,
    mode_block,
    notch,
    parallel,
    sections,
    series,
    split_mode,
    zoh,
)
from mr_ident.numerics.systems.simulate import simulate

FS = 1000.0
MODES = [(40.0, 0.02, 1.0), (150.0, 0.01, -0.3), (380.0, 0.05, 0.2)]  # f, damping, gain


def _modal_polynomials(modes):
    num, den = np.zeros(1), np.ones(1)
    for f, z, g in modes:
        w = 2 * np.pi * f
        d = np.array([1.0, 2 * z * w, w * w])
        num = np.polyadd(np.polymul(num, d), np.polymul([g * w * w], den))
        den = np.polymul(den, d)
    return num, den


def _step(t, modes):
    y = np.zeros_like(t)
    for f, z, g in modes:
        w = 2 * np.pi * f
        wd = w * np.sqrt(1 - z * z)
        y += g * (
            1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z) * np.sin(wd * t))
        )
    return y


def test_a_sixth_order_modal_plant_simulates_to_its_closed_form_step_response():
    num, den = _modal_polynomials(MODES)
    model = Model(FS, 1, TransferMatrix.siso(num, den))
    n = 2000
    sim = simulate(model, reference=np.ones((n, 1)))
    t = np.arange(n) / FS
    truth = _step(t, MODES)
    np.testing.assert_allclose(sim.y[:, 0], truth, rtol=0, atol=1e-9 * np.abs(truth).max())


def test_sections_evaluate_as_the_polynomial_they_come_from():
    rng = np.random.default_rng(3)
    for _ in range(200):
        n_p = int(rng.integers(1, 7))
        n_z = int(rng.integers(0, n_p + 1))

        def roots(k):
            out = []
            while len(out) < k:
                if k - len(out) >= 2 and rng.random() < 0.6:
                    w, z = rng.uniform(5, 2000), rng.uniform(0.01, 0.9)
                    p = -z * w + 1j * w * np.sqrt(1 - z * z)
                    out += [p, np.conj(p)]
                else:
                    out.append(-rng.uniform(0, 1500) * (rng.random() < 0.9))
            return out

        num = np.atleast_1d(np.real(np.poly(roots(n_z)))) * rng.uniform(0.1, 100)
        den = np.real(np.poly(roots(n_p)))
        f = np.geomspace(0.3, 3000, 97)
        s = 2j * np.pi * f
        truth = np.polyval(num, s) / np.polyval(den, s)
        got = sections(num, den).freqresp(f)[:, 0, 0]
        # the polynomial's own conditioning bounds the agreement near lightly damped poles
        np.testing.assert_allclose(got, truth, rtol=1e-5)


def test_a_mode_split_off_and_added_back_is_the_system():
    num, den = _modal_polynomials(MODES)
    S = sections(num, den)
    w = 2 * np.pi * 150.0
    pole = complex(-0.01 * w, w * np.sqrt(1 - 1e-4))
    c1, c0, rest = split_mode(S, pole)
    again = parallel(rest, mode_block(150.0, 0.01, c1, c0))
    f = np.linspace(1, 499, 300)
    np.testing.assert_allclose(again.freqresp(f), S.freqresp(f), rtol=1e-10)
    # the modal numerator of g w^2/(s^2+...) is c1 = 0, c0 = g w^2
    np.testing.assert_allclose([c1[0, 0], c0[0, 0]], [0.0, -0.3 * w * w], atol=1e-8 * w * w)
    assert rest.n_states == 4


def test_a_mode_change_keeps_the_numerator_or_scales_it_with_the_mass():
    num, den = _modal_polynomials(MODES)
    base = Model(FS, 1, TransferMatrix.siso(num, den))
    stiff = replace(base, mode_changes=((150.0, 165.0, 0.02, 1.0),))
    mass = replace(base, mode_changes=((150.0, 165.0, 0.02, (165 / 150) ** 2),))
    f = np.linspace(1, 499, 300)
    for m, g in ((stiff, -0.3 * 150**2 / 165**2), (mass, -0.3)):
        truth_modes = [MODES[0], (165.0, 0.02, g), MODES[2]]
        P = Model(FS, 1, TransferMatrix.siso(*_modal_polynomials(truth_modes)))
        np.testing.assert_allclose(
            m.plant_ss().freqresp(f), P.plant_ss().freqresp(f), rtol=1e-8, atol=1e-12
        )


def test_the_notch_has_its_depth_at_its_frequency_and_unit_gain_far_away():
    N = notch(20.0, 0.3, 0.1, 1 / 80.0)
    g = N.freqresp([20.0, 0.01, 39.99])[:, 0, 0]
    np.testing.assert_allclose(np.abs(g), [0.1, 1.0, 1.0], rtol=1e-6, atol=1e-3)


def test_lowpasses_and_series_connections_are_the_products_they_stand_for():
    f = np.geomspace(1, 400, 50)
    s = 2j * np.pi * f
    w1, w2 = 2 * np.pi * 30, 2 * np.pi * 90
    truth = w1 / (s + w1) * w2**2 / (s**2 + 2 * 0.2 * w2 * s + w2**2)
    got = series(lowpass(30.0), lowpass(90.0, 0.2)).freqresp(f)[:, 0, 0]
    np.testing.assert_allclose(got, truth, rtol=1e-12)


@pytest.mark.parametrize("delay", [0.0, 0.35e-3, 2.6e-3])
def test_the_zoh_with_delay_matches_a_fine_simulation(delay):
    import scipy.signal

    num, den = _modal_polynomials(MODES[:2])
    h, up = 1 / FS, 40
    Pd = zoh(sections(num, den), h, delay=delay)
    u = np.random.default_rng(1).standard_normal(300)
    _, y, _ = scipy.signal.dlsim((Pd.A, Pd.B, Pd.C, Pd.D, h), u)
    shift = int(round(delay / h * up))
    uf = np.concatenate([np.zeros(shift), np.repeat(u, up)])[: u.size * up]
    S = sections(num, den)
    t = np.arange(u.size * up) * h / up
    _, yf, _ = scipy.signal.lsim((S.A, S.B, S.C, S.D), uf, t, interp=False)
    np.testing.assert_allclose(y[:, 0], yf[::up], atol=1e-6 * np.abs(yf).max())


def test_freqresp_on_a_pole_is_infinite_there_and_exact_elsewhere():
    """A double integrator's response at DC (z = 1): inf, not a LinAlgError; others exact."""
    from mr_ident.numerics.systems.lti import StateSpace

    dt = 1e-3
    A = np.array([[1.0, dt], [0.0, 1.0]])  # defective: the eigenvector path is refused
    ss = StateSpace(A, np.array([[dt**2 / 2], [dt]]), np.array([[1.0, 0.0]]), np.zeros((1, 1)), dt)
    f = np.array([0.0, 1.0, 10.0])
    G = ss.freqresp(f)[:, 0, 0]
    z = np.exp(2j * np.pi * f[1:] * dt)
    exact = dt**2 / 2 * (z + 1) / (z - 1) ** 2
    assert np.isinf(G[0])
    np.testing.assert_allclose(G[1:], exact, rtol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_a_defective_system_responds_as_one_solve_per_frequency(seed):
    """Random series of sections, shift registers and a shared repeated pole (defective: the
    eigenvector path is refused), states shuffled: the block substitution of freqresp equals
    ``C (xI - A)^-1 B + D`` solved point by point, within 1e-10 relative; and the blocks it
    uses leave A block lower triangular."""
    from mr_ident.numerics.systems.lti import StateSpace, triangular_blocks
    from mr_ident.numerics.systems.realize import shift

    rng = np.random.default_rng(seed)
    dt = 1e-3
    parts = [zoh(sections(*_modal_polynomials(MODES[: 1 + seed % 2])), dt)]
    parts += [shift(1, int(rng.integers(1, 4)), dt)]
    jordan = np.array([[0.9, 1.0], [0.0, 0.9]])  # a repeated pole, one eigenvector
    parts += [StateSpace(jordan, rng.standard_normal((2, 1)), rng.standard_normal((1, 2)),
                         rng.standard_normal((1, 1)), dt)]  # fmt: skip
    ss = parts[0]
    for p in rng.permutation(parts[1:]):
        ss = series(ss, p)
    perm = rng.permutation(ss.A.shape[0])
    ss = StateSpace(ss.A[np.ix_(perm, perm)], ss.B[perm], ss.C[:, perm], ss.D, dt)
    assert np.linalg.cond(np.linalg.eig(ss.A)[1]) >= 1e8
    f = rng.uniform(0.1, 499.0, 300)
    z = np.exp(2j * np.pi * f * dt)
    n = ss.A.shape[0]
    exact = np.array([ss.C @ np.linalg.solve(zk * np.eye(n) - ss.A, ss.B) + ss.D for zk in z])
    np.testing.assert_allclose(ss.freqresp(f), exact, rtol=1e-10)
    order, blocks = triangular_blocks(ss.A)
    Ap = ss.A[np.ix_(order, order)]
    for a, b in blocks:
        assert not Ap[a:b, b:].any()  # nothing after a block drives it
