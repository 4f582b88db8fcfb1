# SPDX-License-Identifier: Apache-2.0
"""The segments' time-domain gains on records with missing samples of u and y."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mr_bench.beyond import simulate_actuated
from mr_bench.scenarios import draw_loop
from mr_ident import simulate
from mr_ident.diagnosis.criterion.gain_drift import MAX_MISSING, PARTS, gain_drift, long_run
from mr_ident.diagnosis.criterion.objective import settle_samples
from mr_ident.diagnosis.criterion.timevarying import DRIFT_ALPHA


def holes(rec, share, rng, burst=(5, 51)):
    """``rec`` with ``share`` of u's and y's samples missing: half single samples (u and y
    apart), half in bursts of both (``burst``: their lengths' range)."""
    N = rec.n_samples
    u, y = rec.u.copy(), rec.y.copy()
    for x in (u, y):
        x[rng.random(N) < share / 2] = np.nan
    lost = 0
    while lost < share / 2 * N:
        b = int(rng.integers(*burst))
        a = int(rng.integers(0, N - b))
        u[a : a + b], y[a : a + b] = np.nan, np.nan
        lost += b
    return dataclasses.replace(rec, u=u, y=y)


@pytest.mark.filterwarnings("ignore:simulate. state matrix")
@pytest.mark.parametrize("seed", [4, 6])
def test_missing_samples_of_u_leave_the_gains_exact_where_the_model_is_the_plant(seed):
    """u carries the feedback of output noise v, y is the plant's own output (the record's
    y less v, plus 1e-9 of its rms), 2 % of u and y missing (single samples and bursts of
    2-40, longer than the plant's order 6 or 4): ŷ, from the u filled with the model's
    prediction, differs from the plant's output by the holes' responses, which are
    projected out, so each segment's gain is the plant's, 1, to 1e-6 (measured 5e-10;
    without the holes' responses 8e-4 and 0.07); a gain of 1.3 on y reads 1.3. In open
    loop (a double integrator: the step responses projected out too, what u's mean did)
    the same (measured 2e-9; 0.16 without)."""
    loop = draw_loop(np.random.default_rng(seed), duration=10.0)
    m = loop.nominal
    v = m.noise_std * np.random.default_rng(1).standard_normal(loop.y_clean.shape)
    rec = simulate(m, reference=loop.reference, noise=v)
    tiny = 1e-9 * np.std(rec.y) * np.random.default_rng(1).standard_normal(rec.y.shape)
    lossy = holes(
        dataclasses.replace(rec, y=rec.y - v + tiny), 0.02, np.random.default_rng(2), (2, 41)
    )
    assert np.isnan(lossy.u).any() and np.isnan(lossy.y).any()
    got = gain_drift(lossy, m)
    assert got is not None and len(got.gains) == PARTS
    np.testing.assert_allclose(got.gains, 1.0, atol=1e-6)
    scaled = gain_drift(dataclasses.replace(lossy, y=1.3 * lossy.y), m)
    assert scaled is not None
    np.testing.assert_allclose(scaled.gains, 1.3, atol=1e-6)
    opened = dataclasses.replace(m, controller=None)
    rec = simulate(opened, reference=loop.reference, noise=np.zeros_like(v))
    lossy = holes(
        dataclasses.replace(rec, y=rec.y + tiny), 0.02, np.random.default_rng(2), (2, 41)
    )
    got = gain_drift(lossy, opened)
    assert got is not None
    np.testing.assert_allclose(got.gains, 1.0, atol=1e-6)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_time_invariant_loop_with_missing_samples_keeps_its_gains_within_their_noise(seed):
    """A constant-gain loop with output noise, 2 % of u and y missing: p not small, in
    closed loop, in open loop (z the plant driven by the u with its holes at the mean) and
    periodic (measured over 200 benchmark records: no p below DRIFT_ALPHA, the p uniform)."""
    loop = draw_loop(np.random.default_rng(seed), duration=10.0)
    m = loop.nominal
    noise = m.noise_std * np.random.default_rng(seed + 10).standard_normal(loop.y_clean.shape)
    rng = np.random.default_rng(seed + 20)
    rec = holes(simulate(m, reference=loop.reference, noise=noise), 0.02, rng)
    got = gain_drift(rec, m)
    assert got is not None and got.p > DRIFT_ALPHA and len(got.gains) == PARTS
    opened = dataclasses.replace(m, controller=None)
    rec = holes(simulate(opened, reference=loop.reference, noise=noise), 0.02, rng)
    got = gain_drift(rec, opened)
    assert got is not None and got.p > DRIFT_ALPHA
    P = 256 * m.ratio
    reps = loop.reference.shape[0] // P
    r = np.tile(loop.reference[:P], (reps, 1))
    rec = dataclasses.replace(simulate(m, reference=r, noise=noise[: reps * P]), period=P)
    got = gain_drift(holes(rec, 0.02, rng), m)
    assert got is not None and got.p > DRIFT_ALPHA


def test_a_gain_step_within_a_lossy_record_is_named_and_each_segment_reads_its_gain():
    """The plant's gain steps from 1 to 1.25 at the record's middle, 2 % of u and y
    missing: the segments before the step read 1, those after 1.25 (each within 4 std and
    0.01), and p is far below DRIFT_ALPHA."""
    loop = draw_loop(np.random.default_rng(7), duration=10.0)
    m = loop.nominal
    N = loop.reference.shape[0]
    v = m.noise_std * np.random.default_rng(8).standard_normal((N, 1))

    def step():  # the actuator of mr_bench.beyond: the gain after N/2 samples
        n = [0]

        def gain(u: float, dy: float) -> float:
            n[0] += 1
            return u * (1.0 if n[0] <= N // 2 else 1.25)

        return gain

    rec = holes(simulate_actuated(m, loop.reference, v, step()), 0.02, np.random.default_rng(9))
    got = gain_drift(rec, m)
    assert got is not None and got.p < DRIFT_ALPHA
    start = settle_samples(m, N)
    k = len(got.gains)
    size = (N - start) // k
    for s, (c, sd) in enumerate(zip(got.gains, got.std, strict=True)):
        first, last = start + s * size, start + (s + 1) * size
        if last <= N // 2 or first > N // 2 + 50:  # clear of the step (and its settling)
            want = 1.0 if last <= N // 2 else 1.25
            assert abs(c - want) < 4 * sd + 0.01, (s, c, sd)


def test_too_many_missing_samples_leave_the_test_not_done():
    """More than MAX_MISSING of y's samples missing: None (not done), not a guess."""
    loop = draw_loop(np.random.default_rng(1), duration=10.0)
    m = loop.nominal
    rec = simulate(m, reference=loop.reference, noise=np.zeros_like(loop.y_clean))
    y = rec.y.copy()
    y[np.random.default_rng(3).random(rec.n_samples) < MAX_MISSING + 0.05] = np.nan
    assert gain_drift(dataclasses.replace(rec, y=y), m) is None


def test_the_long_run_variance_over_the_samples_kept_is_that_of_their_sum():
    """z and e as in test_timevarying's Isserlis check (AR(1) 0.8 and 0.6, e holding a part
    of z), 10 % of 4096 samples left out at random and eight holes of 30 (16 % in all): the
    estimate's mean over 300 records against the Monte Carlo variance of ``Σ_kept z e`` over
    3000 within 7 % (measured 5 % high: lag 0 scaled as lag 1, conservative; the Monte
    Carlo's own sd 2.6 %); the masked periodograms unscaled read it 21 % low (about the
    share left out)."""
    import scipy.signal

    rng = np.random.default_rng(5)
    L, burn = 4096, 300
    keep = rng.random(L) > 0.1
    for a in rng.integers(0, L - 40, 8):
        keep[a : a + 30] = False
    est, raw, sums = [], [], []
    for i in range(3000):
        w1, w2 = rng.standard_normal((2, L + burn))
        z = scipy.signal.lfilter([1], [1, -0.8], w1)
        e = scipy.signal.lfilter([1], [1, -0.6], w2) + scipy.signal.lfilter([0, 0.5], [1, -0.5], z)
        z, e = z[burn:] * keep, e[burn:] * keep
        sums.append(float(z @ e))
        if i < 300:
            est.append(float(long_run(z[:, None], e[:, None], mask=keep[:, None]).sum()))
            raw.append(float(long_run(z[:, None], e[:, None]).sum()))
    np.testing.assert_allclose(np.mean(est), np.var(sums), rtol=0.07)
    assert np.mean(raw) < 0.88 * np.var(sums)


def test_a_segment_refused_for_its_holes_leaves_the_time_domain_gains_alone():
    """A time-varying gain (the benchmark's, 10 s at 240 Hz, F = 5) whose first quarter
    misses 12 % of its samples in bursts (3 % of the record): the lifted fit of that
    segment refuses it (DataError; diagnose raised it before), so the segments' comparison
    is the time-domain gains alone: no bands, the level NaN, named, and said without the
    missing level."""
    from mr_bench.beyond import draw_beyond
    from mr_ident.diagnosis.criterion.timevarying import within
    from mr_ident.numerics.identify import default_n

    b = draw_beyond("time_varying_gain", np.random.default_rng(1026014), duration=10.0)
    rec = b.data
    N = rec.n_samples
    u, y = rec.u.copy(), rec.y.copy()
    for a in np.linspace(0.02 * N, 0.2 * N, 6).astype(int):
        u[a : a + N // 200], y[a : a + N // 200] = np.nan, np.nan
    m = b.nominal
    n = default_n("freq-lifted", 2, m.ratio, m.n_u, max(m.n_u, m.n_y))  # diagnose's window
    got = within(dataclasses.replace(rec, u=u, y=y), m, n=n)
    assert got is not None and got.bands == [] and np.isnan(got.level_db) and got.pooled is None
    assert got.drift is not None and got.drift.p < DRIFT_ALPHA and got.varying
    assert got.text().startswith("the plant changes within the record: its gain, one per")


def test_a_lossy_record_leaves_the_pooled_test_out_and_keeps_the_gains():
    """2 % of u and y missing on a time-invariant loop: the pooled test over the lines is not
    done (a hole's error is common to every line of its segment), the time-domain gains
    are, and nothing is named."""
    from mr_ident.diagnosis.criterion.timevarying import within
    from mr_ident.numerics.identify import default_n

    loop = draw_loop(np.random.default_rng(2), duration=10.0)
    m = loop.nominal
    noise = m.noise_std * np.random.default_rng(12).standard_normal(loop.y_clean.shape)
    rec = holes(simulate(m, reference=loop.reference, noise=noise), 0.02, np.random.default_rng(3))
    n = default_n("freq-lifted", 2, m.ratio, m.n_u, max(m.n_u, m.n_y))
    got = within(rec, m, n=n)
    assert got is not None and got.bands and got.pooled is None
    assert got.drift is not None and got.drift.p > DRIFT_ALPHA and not got.varying
    assert got.lossy


def test_on_a_lossy_record_the_level_is_reported_but_names_nothing():
    """The segments' level above its threshold names a complete record, not a lossy one
    (a hole errs in every line of its segment alike): there the time-domain gains decide."""
    from mr_ident.diagnosis.criterion.timevarying import VARYING_DB, Segments

    high = Segments([], 4, VARYING_DB + 5.0)
    assert high.varying
    assert not dataclasses.replace(high, lossy=True).varying


def test_a_low_rate_y_leaves_the_test_not_done():
    """y every F-th sample (``y_phase``) is not on ŷ's samples: the test is not done (it
    compared y with ŷ at the wrong times: a time-invariant loop's gains read -2.2 to 2.3)."""
    from mr_ident.io.modelfile import model_from_dict
    from mr_ident.numerics.signals import LoopData

    model = model_from_dict({"fs_high": 200.0, "ratio": 2,
                             "plant": {"num": [20.0], "den": [1.0, 8.0, 0.0]},
                             "controller": {"num": [2.0, -1.6], "den": [1.0, -0.2]}})  # fmt: skip
    rng = np.random.default_rng(0)
    r = rng.standard_normal((8000, 1))
    rec = simulate(model, reference=r, noise=0.01 * rng.standard_normal((8000, 1)))
    assert gain_drift(rec, model) is not None
    slow = LoopData(rec.r, rec.u, rec.y[1::2], fs_high=200.0, ratio=2, y_phase=1)
    assert gain_drift(slow, model) is None
