# SPDX-License-Identifier: Apache-2.0
"""The controller from the data (diagnosis.controller.identified) on loops drawn at random.

The machine's loop is run sample by sample here with a controller of its own, applied by
scipy's ``lfilter`` to the sampled y (not this project's realisation): the model's K_l
with its gain scaled, with its numerator retuned, or followed by a first-order filter the
model lacks. The controller's own equation must then name the difference: the gain to
1e-6 relative (measured 1e-14-1e-12), the retuned numerator's coefficients to 1e-6 of
the largest (measured 1e-13-1e-10), the extra filter as a controller one order higher
whose response equals the machine's to 1e-6; the diagnosis, with the plant's gain
wrong too, names both and no other plant cause.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from mr_bench.scenarios import draw_loop
from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.controller.relation import EXACT, relate
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.simulate import loop_poles


def _machine(model, b, a, r: np.ndarray, v: np.ndarray, plant_gain: float = 1.0):
    """u, y of the loop run sample by sample: the controller (b, a) at the low rate."""
    P = model.plant_discrete()
    F, N = model.ratio, r.shape[0]
    b = np.concatenate([np.zeros(len(a) - len(b)), b])  # descending powers of z: z^-k aligned
    x = np.zeros(P.A.shape[0])
    zi = np.zeros(len(a) - 1)
    held = 0.0
    u, y = np.zeros(N), np.zeros(N)
    for n in range(N):
        y[n] = plant_gain * (P.C @ x)[0] + v[n]
        if n % F == 0:
            out, zi = scipy.signal.lfilter(b, a, [y[n]], zi=zi)
            held = float(out[0])
        u[n] = r[n] - held
        x = P.A @ x + P.B[:, 0] * u[n]
    return u, y


def _with_controller(model, b, a):
    return replace(model, controller=TransferMatrix.siso(b, a, model.ratio / model.fs_high))


def _loop(seed: int, change):
    """A drawn SISO loop with no delay, the machine's controller (b, a) stable in it."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        loop = draw_loop(rng, duration=8.0)
        m = loop.nominal
        if m.n_u != 1 or m.control_delay or m.sample_phase or m.controller_notches:
            continue
        b0, a0 = (np.array(v[0][0], float) for v in (m.controller.num, m.controller.den))
        b, a = change(b0, a0, rng, m)
        if np.max(np.abs(loop_poles(_with_controller(m, b, a)))) < 0.995:
            return m, b, a, rng
    raise AssertionError("no loop drawn")


def _record(m, b, a, rng, plant_gain=1.0, seconds=8.0):
    N = int(seconds * m.fs_high) // m.ratio * m.ratio
    r = rng.standard_normal((N, 1))
    v = m.noise_std * rng.standard_normal(N)
    u, y = _machine(m, b, a, r[:, 0], v, plant_gain)
    return LoopData(r, u[:, None], y[:, None], fs_high=m.fs_high, ratio=m.ratio)


def _gain(b, a, rng, m):
    return b * rng.uniform(1.15, 1.4), a


def _retuned(b, a, rng, m):
    nz = np.flatnonzero(b)
    b2 = b.copy()
    b2[nz] *= 1 + rng.uniform(0.05, 0.2, nz.size) * rng.choice([-1, 1], nz.size)
    return b2, a


def _filtered(b, a, rng, m):
    p = rng.uniform(0.2, 0.6)  # a first-order low-pass with unit DC gain
    return np.convolve(b, [1 - p, 0.0]), np.convolve(a, [1.0, -p])


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_controller_gain_other_than_the_models_is_found_to_rounding(seed):
    m, b, a, rng = _loop(seed, _gain)
    rel = relate(m, _record(m, b, a, rng))
    assert rel is not None and rel.exact and rel.error_before > 0.05
    assert [c.cause for c in rel.choices] == ["controller_gain"]
    g = b[np.flatnonzero(b)[0]] / m.controller.num[0][0][np.flatnonzero(b)[0]]
    assert rel.choices[0].x[0] == pytest.approx(g, rel=1e-6)


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_a_retuned_controller_is_identified_coefficient_by_coefficient(seed):
    m, b, a, rng = _loop(seed, _retuned)
    rel = relate(m, _record(m, b, a, rng))
    assert rel is not None and rel.exact, rel and rel.text()
    (c,) = rel.choices
    assert c.cause == "controller_retuned"
    n = int(c.fixed[0])
    assert n == len(a) - 1
    bb = np.concatenate([np.zeros(n + 1 - len(b)), b])  # b padded to the order's length
    scale = np.max(np.abs(bb))
    np.testing.assert_allclose(c.x[: n + 1], bb, atol=1e-6 * scale)
    np.testing.assert_allclose(c.x[n + 1 :], a[1:], atol=1e-6 * np.max(np.abs(a)))


@pytest.mark.parametrize("seed", [31, 32])
def test_a_filter_the_model_lacks_is_a_controller_one_order_higher(seed):
    m, b, a, rng = _loop(seed, _filtered)
    rel = relate(m, _record(m, b, a, rng))
    assert rel is not None and rel.exact, rel and rel.text()
    (c,) = rel.choices
    assert c.cause == "controller_retuned" and int(c.fixed[0]) == len(m.controller.den[0][0])
    from mr_ident.diagnosis.causes.registry import build

    K = build(m, rel.choices).controller
    z = np.exp(2j * np.pi * np.geomspace(1e-3, 0.45, 50))
    want = np.polyval(b, z) / np.polyval(a, z)
    np.testing.assert_allclose(K(z)[:, 0, 0], want, rtol=1e-6)


def test_controller_and_plant_both_wrong_are_both_named_and_no_other_plant_cause():
    """The controller's gain 1.25 times the model's and the plant's 0.8 times: the
    equation fixes the controller's, the criterion then finds the plant's (2 % as the
    benchmark's tolerance), validated on a second record."""
    m, b, a, rng = _loop(41, lambda b, a, rng, m: (1.25 * b, a))
    data, val = (_record(m, b, a, rng, plant_gain=0.8, seconds=10.0) for _ in range(2))
    d = diagnose(m, data, val)
    names = [c.cause for c in d.applied]
    assert names[0] == "controller_gain" and d.cause == "controller_gain"
    assert d.applied[0].parameters["gain"] == pytest.approx(1.25, rel=1e-6)
    assert "gain_error" in names and set(names) <= {"controller_gain", "gain_error"}
    plant = next(c for c in d.applied if c.cause == "gain_error")
    assert plant.parameters["gain"] == pytest.approx(0.8, rel=0.02)
    assert d.relation is not None and d.relation.error_after <= EXACT
