# SPDX-License-Identifier: Apache-2.0
"""The model's output error through the estimator (criterion/matched.py) against analytic truth.

Noise-free, an exact model's output error ``y - P u`` is zero (to rounding), from rest or
from a state the record did not start at. With noise, the loop of the benchmark whose
first bins the local fit biases far beyond its std (seed 107, as in test_validate): the
plain σ-error there is many thresholds, the matched one within noise at every bin.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.diagnosis.criterion.evidence import frf_evidence
from mr_ident.diagnosis.criterion.matched import (
    free_response,
    matched,
    matched_evidence,
    output_error,
)
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.identify import default_n
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import simulate


def _integrator_loop() -> tuple:
    """An integrating plant 20 / (s (s + 8)) under a lead at half its rate, 20 s of white r."""
    model = model_from_dict({"fs_high": 200.0, "ratio": 2,
                             "plant": {"num": [20.0], "den": [1.0, 8.0, 0.0]},
                             "controller": {"num": [2.0, -1.6], "den": [1.0, -0.2]}})  # fmt: skip
    r = np.random.default_rng(3).standard_normal((4000, 1))
    return model, r


def _benchmark_loop() -> tuple:
    """The loop of test_validate (seed 107: 240 Hz, F = 3, two integrators), 10 s, noisy."""
    from mr_bench.scenarios import draw_loop

    rng = np.random.default_rng(107)
    loop = draw_loop(rng, duration=10.0)
    m = loop.nominal
    v = m.noise_std * rng.standard_normal(loop.y_clean.shape)
    n = default_n("freq-lifted", 2, m.ratio, m.n_u, max(m.n_u, m.n_y))
    return m, loop.reference, v, n


def test_an_exact_models_output_error_on_noise_free_data_is_zero():
    model, r = _integrator_loop()
    rec = simulate(model, reference=r, noise=np.zeros((r.shape[0], 1)))
    e = output_error(model, rec)
    assert e is not None
    assert np.max(np.abs(e.y)) < 1e-10 * np.std(rec.y)
    assert e.r is rec.r and e.u is rec.u  # closed loop: r and u as identified


def test_a_record_not_started_at_rest_loses_the_plants_free_response():
    """From the middle of a run the integrator holds a state: y - P u from rest is a
    constant plus a decaying mode, which the least-squares initial state removes."""
    model, r = _integrator_loop()
    run = simulate(model, reference=np.concatenate([r, r]), noise=np.zeros((8000, 1)))
    rec = run.part(3000, 8000)
    err = output_error(model, rec)
    assert err is not None
    assert np.max(np.abs(err.y)) < 1e-9 * np.std(rec.y)
    Ob = free_response(model.plant_discrete(), 50)
    assert Ob.shape == (50, 1, 2)  # two states: one column each, unit norm
    assert np.allclose(np.sum(Ob**2, axis=(0, 1)), 1.0)


def test_a_low_rate_y_gives_the_output_error_at_its_phase():
    model, r = _integrator_loop()
    rec = simulate(model, reference=r, noise=np.zeros((r.shape[0], 1)))
    slow = LoopData(rec.r, rec.u, rec.y[1::2], fs_high=200.0, ratio=2, y_phase=1)
    err = output_error(model, slow)
    assert err is not None and err.y.shape == (2000, 1)
    assert np.max(np.abs(err.y)) < 1e-10 * np.std(rec.y)


def test_the_matched_difference_is_within_noise_where_the_plain_one_is_biased():
    """Exact model, noise as drawn: the first bin's plain σ-error is over 3 thresholds
    (the local fit's bias: 56 σ), the matched one below the threshold at every bin, those
    whose window reaches DC included; the matched std there is the noise's, a hundredth
    of the plain one (which holds the fit's misfit)."""
    m, r, v, n = _benchmark_loop()
    rec = simulate(m, reference=r, noise=v)
    ev = frf_evidence(m, rec, n=n, degree=2, alpha=0.01)
    me = matched_evidence(ev, m, rec, n=n, degree=2, alpha=0.01)
    assert ev.sigma_error[0] > 3 * ev.threshold
    assert me.tested.all() and not me.significant.any()
    assert np.nanmax(me.sigma_error[:n]) < 0.5 * me.threshold
    assert np.all(me.P_std[:n] < 0.01 * ev.P_std[:n])
    # the threshold is the per-bin test's over every bin (one more family member per bin)
    assert me.threshold == pytest.approx(ev.threshold, rel=0.01)
    assert me.threshold >= ev.threshold


@pytest.mark.filterwarnings("ignore:All-NaN slice")  # noise-free: the plain std is 0 on bins
def test_noise_free_the_bias_cancels_exactly_and_an_error_is_seen():
    """Noise-free data of the exact model: the plain estimate's bias at the first bin is
    over a percent of P, the matched difference zero to rounding at every bin. With noise,
    a plant 5 % stronger than the model is significant."""
    m, r, v, n = _benchmark_loop()
    clean = simulate(m, reference=r, noise=np.zeros_like(v))
    got = matched(m, clean, n=n, degree=2)
    assert got is not None
    P = m.plant_frf(clean.n_samples)[1:]
    plain = frf_evidence(m, clean, n=n, degree=2, alpha=0.01)
    assert np.abs(plain.P_hat[0] - P[0]) > 1e-2 * np.abs(P[0])
    assert np.all(np.abs(got.difference) <= 1e-9 * np.abs(P))
    true = replace(m, plant_gain=1.05 * m.plant_gain)
    rec = simulate(true, reference=r, noise=v)
    ev = frf_evidence(m, rec, n=n, degree=2, alpha=0.01)
    assert matched_evidence(ev, m, rec, n=n, degree=2, alpha=0.01).significant.any()


def test_periodic_records_and_foreign_bins_are_handled():
    model, r = _integrator_loop()
    rec = simulate(model, reference=r, noise=np.zeros((r.shape[0], 1)))
    periodic = replace(rec, period=400)
    assert matched(model, periodic, n=8, degree=2) is None
    m, r2, v, n = _benchmark_loop()
    rec2 = simulate(m, reference=r2, noise=v)
    ev = frf_evidence(m, rec2, n=n, degree=2, alpha=0.01)
    with pytest.raises(ValueError, match="ev must be on the bins"):
        matched_evidence(ev, model, rec, n=8, degree=2, alpha=0.01)


def test_the_output_errors_noise_level_is_the_noises_at_the_lowest_bins():
    """Exact model, white output noise of variance σ²: from y the LPM noise at the first
    bins is the local fit's misfit (over 10⁶ σ² here); from the output error, unshaped by
    the loop, it is σ² within the running median's scatter (measured 0.5-2.3 σ²)."""
    from mr_ident.diagnosis.criterion.evidence import identify_record
    from mr_ident.diagnosis.criterion.noise import noise_spectrum

    m, r, v, n = _benchmark_loop()
    rec = simulate(m, reference=r, noise=v)
    plain = noise_spectrum(rec, m, n=n, degree=2)[:, 0] / m.noise_std**2
    err = output_error(m, rec)
    assert err is not None
    ident = identify_record(err, m, n=n, degree=2)
    level = noise_spectrum(rec, m, n=n, degree=2, ident=ident, shaped=False)[:, 0]
    level = level / m.noise_std**2
    assert np.all(plain[:10] > 1e6)
    assert np.all((level > 0.4) & (level < 3.0))


def test_in_open_loop_what_us_mean_did_is_taken_out_too():
    """Open loop, an integrating plant: u's mean, taken out, drove a ramp in y that is no
    free response; the step responses remove it, so the output error is the noise and its
    level at the first bins is σ² (without them 1e5-4e9 σ²)."""
    from mr_ident.diagnosis.criterion.evidence import identify_record
    from mr_ident.diagnosis.criterion.noise import noise_spectrum

    model = model_from_dict({"fs_high": 200.0, "ratio": 2,
                             "plant": {"num": [20.0], "den": [1.0, 8.0, 0.0]}})  # fmt: skip
    rng = np.random.default_rng(0)
    r = rng.standard_normal((4000, 1)) + 0.3
    rec = simulate(model, reference=r, noise=0.01 * rng.standard_normal((4000, 1)))
    err = output_error(model, rec)
    assert err is not None
    assert np.std(err.y) < 1.1e-2
    ident = identify_record(err, model, n=8, degree=2)
    level = noise_spectrum(rec, model, n=8, degree=2, ident=ident, shaped=False)[:, 0] / 1e-4
    assert np.all((level[:10] > 0.3) & (level[:10] < 3.0))
