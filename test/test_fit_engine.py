# SPDX-License-Identifier: Apache-2.0
"""The fit's engine: conditioning of its linear steps, the one-pass normal equations, the
coarse stage's bins, the restarts from a local minimum and which of them are kept."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.numerics.fit import restart
from mr_ident.numerics.fit.basis import columns, initial_poles, pole_derivatives
from mr_ident.numerics.fit.frf_fit import fit_frf, hold_response
from mr_ident.numerics.fit.refine import Problem, _Projected, refine, solution, to_params
from mr_ident.numerics.fit.restart import moved
from mr_ident.numerics.fit.strategy import COARSE_BINS, coarse_rows
from mr_ident.numerics.results import FRF
from mr_ident.numerics.systems.modal import ModalPlant

FS = 1000.0


def _modes(f, zeta):
    w = 2 * np.pi * np.asarray(f)
    z = np.asarray(zeta)
    return -z * w + 1j * w * np.sqrt(1 - z * z)


def _plant(rng, f, zeta, n=1):
    p = _modes(f, zeta)
    mag = np.exp(rng.uniform(0, np.log(10), (p.size, n, n)))
    R = (-p.real / 1e3)[:, None, None] * mag * np.exp(2j * np.pi * rng.uniform(size=mag.shape))
    return ModalPlant(p, R, np.zeros((n, n)))


def _problem(truth, K, rng, rel=0.05):
    f = np.arange(1, K + 1) * FS / (2 * K + 2)
    P = hold_response(truth, 0.0, "continuous", FS, f)
    sd = rel * np.median(np.abs(P), axis=0)[None] * np.ones(P.shape)
    noise = sd * (rng.standard_normal(P.shape) + 1j * rng.standard_normal(P.shape)) / np.sqrt(2)
    E = P[0].size
    prob = Problem(
        np.exp(2j * np.pi * f / FS),
        (P + noise).reshape(K, E),
        (1 / sd).reshape(K, E),
        "continuous",
        1 / FS,
        2 * np.pi * f[-1],
        False,
    )
    return f, prob, FRF(f, P + noise, sd, "test")


def test_every_linear_step_at_order_40_over_three_decades_has_a_condition_below_1e4():
    """20 modes log-spaced over 0.45-450 Hz, 2000 bins; the issue's bound 1e4 with a margin
    of 10 (measured 28-184 over four seeds; 1.1e4-3.0e4 before the starting pairs were
    kept two bins apart: the first relocation's columns were nearly collinear)."""
    for seed in range(2):
        rng = np.random.default_rng(seed)
        truth = _plant(rng, np.geomspace(0.45, 450, 20), np.full(20, 0.03))
        _, _, data = _problem(truth, 2000, rng)
        fit = fit_frf(data, fs=FS, order=40, delay=0.0)
        assert 1.0 <= fit.max_condition <= 1e3, fit.max_condition
        assert fit.in_band


def test_the_one_pass_normal_equations_equal_the_explicit_jacobians():
    rng = np.random.default_rng(3)
    truth = _plant(rng, [20.0, 90.0], [0.05, 0.02], n=2)
    _, prob, _ = _problem(truth, 300, rng)
    prob = replace(prob, direct=True)
    poles = np.append(truth.poles * 1.01, -40.0 + 0j)
    pair = [bool(p.imag > 0) for p in poles]
    f = _Projected(prob, pair, None)  # the delay free too
    x = np.append(to_params(poles, "continuous", prob.h, prob.w_ref), 0.3)
    pt = f.point(x)
    H, g = f.normal(pt)
    # the explicit way: every entry's D = ∂(Φ(x) c)/∂x by central differences (c fixed),
    # projected, stacked; independent of the mixing by residues under test
    Phi, W = pt.Phi, prob.W

    def Phi_at(xx):
        poles_x, tau_x = f.unpack(xx)
        return columns(poles_x, prob.z, "continuous", prob.h, tau_x, direct=True)

    dPhi = []
    for j in range(x.size):
        step = 1e-6 * max(abs(x[j]), 1.0)
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        dPhi.append((Phi_at(xp) - Phi_at(xm)) / (2 * step))
    J, r = [], []
    for e in range(prob.P.shape[1]):
        A = W[:, e, None] * Phi
        D = W[:, e, None] * np.column_stack([d @ pt.coef[:, e] for d in dPhi])
        Ar, Dr = np.vstack([A.real, A.imag]), np.vstack([D.real, D.imag])
        Q, _ = np.linalg.qr(Ar)
        J.append(-np.sqrt(2) * (Dr - Q @ (Q.T @ Dr)))
        r.append(np.sqrt(2) * np.concatenate([pt.res[:, e].real, pt.res[:, e].imag]))
    Jm, rv = np.vstack(J), np.concatenate(r)
    np.testing.assert_allclose(H, Jm.T @ Jm, rtol=1e-6, atol=1e-7 * np.abs(H).max())
    np.testing.assert_allclose(g, Jm.T @ rv, rtol=1e-6, atol=1e-7 * np.abs(g).max())
    assert pole_derivatives(poles, prob.z, "continuous", prob.h, 0.3 / FS).shape == (300, 5)


def test_the_coarse_stage_keeps_every_bin_of_a_narrow_resonance():
    rng = np.random.default_rng(4)
    truth = _plant(rng, [3.0, 60.0, 200.0], [0.002, 0.05, 0.1])
    f, prob, _ = _problem(truth, 40_000, rng)
    rows = coarse_rows(prob)
    assert rows is not None and rows.size == COARSE_BINS
    band = np.flatnonzero(np.abs(f - 3.0) <= 3.0 * 0.002)  # the half-power band
    assert np.isin(band, rows).all()
    assert coarse_rows(replace(prob, P=prob.P[:COARSE_BINS])) is None


def test_a_restart_moves_the_weakest_pair_to_the_missed_mode():
    rng = np.random.default_rng(5)
    truth = _plant(rng, [20.0, 80.0, 150.0], [0.03, 0.02, 0.03])
    f, prob, _ = _problem(truth, 1000, rng, rel=0.02)
    # a local minimum's shape: the 80 Hz mode missed, two pairs on the 150 Hz one
    p = truth.poles
    sol = solution(prob, np.array([p[0], p[2], p[2] * 1.002]), 0.0)
    new = moved(prob, f, sol)
    assert new is not None and new.size == 3
    assert np.min(np.abs(np.abs(new) / (2 * np.pi) - 80.0)) < 2.0
    assert np.min(np.abs(new - p[0])) < 1e-9  # the needed 20 Hz pair kept
    assert columns(new, prob.z, "continuous", prob.h).shape == (1000, 6)


def test_a_restart_moves_two_real_poles_as_one_pair_and_leaves_that_minimum():
    """The minimum of drawn 3x3 plants that the restarts missed: a mode unfitted, its order
    spent on two real poles (only complex pairs were moved before)."""
    rng = np.random.default_rng(5)
    truth = _plant(rng, [20.0, 80.0, 150.0], [0.03, 0.02, 0.03])
    f, prob, _ = _problem(truth, 1000, rng, rel=0.02)
    p = truth.poles
    start = np.array([p[0], p[2], -30.0 + 0j, -5000.0 + 0j])
    new = moved(prob, f, solution(prob, start, 0.0))
    assert new is not None and new.size == 3 and np.all(new.imag > 0)  # the same order
    assert np.min(np.abs(np.abs(new) / (2 * np.pi) - 80.0)) < 2.0
    local = refine(prob, start, 0.0, free_delay=False, max_delay=0.0)
    assert np.sum(local.poles.imag == 0) == 2 and local.cost > 1e6  # still the two real poles
    out = restart.escape(prob, f, local, 1100.0, free_delay=False, max_delay=0.0)
    best = refine(prob, p, 0.0, free_delay=False, max_delay=0.0)  # the minimum at the truth
    assert out.cost == pytest.approx(best.cost, abs=1e-3)


def test_a_restart_inside_the_band_is_kept_only_past_its_gain(monkeypatch):
    rng = np.random.default_rng(6)
    truth = _plant(rng, [20.0, 80.0], [0.03, 0.02])
    f, prob, _ = _problem(truth, 200, rng)
    sol = replace(solution(prob, truth.poles, 0.0), cost=100.0)
    costs: list[float] = []
    monkeypatch.setattr(restart, "moved", lambda prob, f, s: s.poles)
    monkeypatch.setattr(restart, "refine", lambda *a, **k: replace(sol, cost=costs.pop(0)))

    def run(bound, gain, *new):
        costs[:] = new
        out = restart.escape(prob, f, sol, bound, free_delay=False, max_delay=0.0, gain=gain)
        return out.cost, len(new) - len(costs)  # the cost kept, the restarts made

    assert run(200.0, np.inf, 10.0) == (100.0, 0)  # inside the band, no gain: no restart
    assert run(200.0, 1.0, 99.5) == (100.0, 1)  # lowers V by less than the gain: rejected
    assert run(200.0, 1.0, 98.5, 98.0) == (98.5, 2)  # kept, then one that gains too little
    assert run(50.0, np.inf, 99.0, 98.0, 97.0, 1.0) == (97.0, 3)  # above: any decrease, 3 times
    assert run(50.0, np.inf, 100.5) == (100.0, 1)  # above, but higher: rejected


def test_starting_pairs_that_linear_spacing_cannot_keep_two_bins_apart_are_spaced_linearly():
    s = initial_poles(10, 1.0, 100.0, "continuous", 1e-3, spacing=50.0)
    f = s.imag / (2 * np.pi)  # the pairs' frequencies (Hz)
    np.testing.assert_allclose(np.diff(f), 19.8, rtol=1e-6)  # mid-points of [1, 100]
