# SPDX-License-Identifier: Apache-2.0
"""The verdict (diagnosis.selection.headline) and what a model leaves beyond the noise.

``unexplained`` against analytic truth: an open-loop plant driven by white u with white
output noise of known σ; the exact model's residual power over nσ² is 1 within 4 std
of its sample spread (``sqrt(2/n)``), a sinusoid of amplitude A left in y raises it by
``A²/(2σ²)`` (to 4 std) and its share of y's rms is ``√(A²/2)/std(y)`` (to 2 % of
itself). The headline's rules on constructed findings: nonlinear distortion named where
no linear extension closes the gap, the BLA named as such, the unexplained part said,
never "none" with a significant gap; on a MIMO loop each output's noise bounded by its own
correlation rest.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mr_ident.diagnosis.causes.cause import CauseFit
from mr_ident.diagnosis.criterion.nonlinearity import Nonlinearity, summarize
from mr_ident.diagnosis.criterion.prediction import predict
from mr_ident.diagnosis.criterion.realizations import SpreadLevels
from mr_ident.diagnosis.criterion.unexplained import (
    Unexplained,
    loop_shaped,
    period_noise,
    unexplained,
    with_distortion,
)
from mr_ident.diagnosis.selection.headline import headline
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.excitation.bla import BandLevels
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import simulate

N, SIGMA = 24000, 0.05


def _open_loop(extra: float = 0.0):
    model = model_from_dict(
        {"fs_high": 200.0, "ratio": 1, "plant": {"num": [30.0], "den": [1.0, 30.0]}}
    )
    rng = np.random.default_rng(5)
    u = rng.standard_normal((N, 1))
    clean = simulate(model, reference=u, noise=np.zeros((N, 1))).y
    t = np.arange(N) / model.fs_high
    y = clean + SIGMA * rng.standard_normal((N, 1)) + extra * np.sin(2 * np.pi * 7.3 * t)[:, None]
    rec = LoopData(u.copy(), u, y, fs_high=model.fs_high, ratio=1)
    return model, rec


def test_the_exact_model_leaves_nothing_beyond_the_noise():
    model, rec = _open_loop()
    got = unexplained(model, rec, 0, predict(model, rec), np.array([SIGMA**2]))
    assert abs(got.ratio - 1.0) < 4 * math.sqrt(2 / N)
    assert not got.significant and got.share < 2.0
    assert got.fit == pytest.approx(got.allowed, abs=0.2)


def test_a_sinusoid_left_in_y_is_unexplained_by_its_share_of_y():
    A = 0.2
    model, rec = _open_loop(A)
    got = unexplained(model, rec, 0, predict(model, rec), np.array([SIGMA**2]))
    assert got.ratio == pytest.approx(1 + A**2 / (2 * SIGMA**2), abs=4 * math.sqrt(2 / N) * 9)
    y = rec.y[:, 0] - rec.y[:, 0].mean()
    assert got.share == pytest.approx(100 * math.sqrt(A**2 / 2) / y.std(), rel=0.02)
    assert got.significant and got.fit < got.allowed


def test_the_spread_over_periods_is_the_noise_variance():
    rng = np.random.default_rng(3)
    periodic = np.tile(rng.standard_normal(500), 40)[:, None]  # no part of the spread
    e = periodic + SIGMA * rng.standard_normal((20000, 1))
    assert period_noise(e, 500)[0] == pytest.approx(SIGMA**2, rel=0.03)  # 19500 dof: 1 %


def _fit(cause: str, text: str) -> CauseFit:
    model = model_from_dict({"fs_high": 100.0, "ratio": 1, "plant": {"num": [1.0], "den": [1.0]}})
    return CauseFit(cause, {"gain": 0.7}, 0.0, {}, model, True, text)


NL = Nonlinearity(29.0, [(1.0, 4.0)], "odd", ("across the records",))
GAP = Unexplained(90.6, 96.3, 8.7, 6.6, 0.01)
NO_GAP = dataclasses.replace(GAP, fit=96.2, share=0.3, ratio=1.02)


def test_distortion_with_a_gap_is_the_verdict_and_the_linear_cause_its_bla():
    h = headline([_fit("gain_error", "plant gain 0.7 x nominal")], False, NL, GAP)
    assert h.cause == "nonlinear_distortion"
    assert "best linear approximation" in h.text and "plant gain 0.7" in h.text
    assert "8.7 % of y (rms) unexplained beyond the noise" in h.text
    assert h.parameters == {"level_db": 29.0, "unexplained_percent": 8.7}


def test_distortion_with_nothing_validated_is_named_not_none():
    h = headline([], False, NL, NO_GAP)
    assert h.cause == "nonlinear_distortion" and "the nominal model" in h.text


def test_a_linear_cause_that_closes_the_gap_is_the_verdict():
    h = headline([_fit("gain_error", "plant gain 0.7 x nominal")], False, NL, NO_GAP)
    assert h.cause == "gain_error" and h.parameters == {"gain": 0.7}


def test_a_gap_no_cause_explains_is_said_with_how_much():
    assert headline([], False, None, GAP).cause == "unexplained"
    assert headline([], True, None, NO_GAP).cause == "plant_correction"
    assert headline([], False, None, NO_GAP).cause == "none"
    h = headline([_fit("gain_error", "plant gain")], False, None, GAP)
    assert h.cause == "gain_error" and "unexplained beyond the noise" in h.text


def test_the_summary_takes_kind_from_the_lines_and_level_from_every_test():
    lines = [BandLevels((1.0, 3.0), 40.0, 25.0, 2.0, 5.0, 5.0)]
    spread = [SpreadLevels((1.0, 3.0), 31.0, 4.0, 0.1, 0.01, 20)]
    got = summarize(lines, spread)
    assert got is not None and got.kind == "odd" and got.level_db == 31.0
    assert got.bands == [(1.0, 3.0)] and len(got.by) == 2
    assert summarize([BandLevels((1.0, 3.0), 40.0, 2.0, 2.0, 5.0, 5.0)], []) is None


def test_a_distortion_the_noise_level_holds_counts_as_unexplained():
    """Fitted distortion 3 against a rest of 1: the ratio at least 4, the share the
    distortion's rms fraction of the residual's, sqrt(3/4) of 100 - fit."""
    left = Unexplained(70.0, 65.0, 0.0, 0.7, 0.1, 1.0)
    got = with_distortion(left, 3.0, 1.0)
    assert got.ratio == pytest.approx(4.0) and got.significant and got.distorted
    assert got.share == pytest.approx(30.0 * math.sqrt(0.75))
    assert "holds the distortion" in got.text()


def test_a_mimo_distortion_at_one_output_bounds_each_outputs_noise_by_its_own_rest():
    """A 2x2 open loop (white u, noise 0.02 on each output) with a cubic at output 1 only:
    the verdict names the distortion, and the noise level it states is bounded per output
    by that output's correlation rest (output 0's is its noise, output 1's holds the part
    of the distortion the regressors do not span), under three times the true noise where
    the LPM's level, which holds the distortion, reads five times it."""
    from dataclasses import replace

    from mr_ident.diagnosis.diagnose import diagnose

    sigma, n = 0.02, 20000
    model = model_from_dict(
        {
            "fs_high": 200.0,
            "ratio": 1,
            "noise_std": sigma,
            "plant": {"num": [[[400.0], [80.0]], [[40.0], [400.0]]], "den": [1.0, 16.0, 400.0]},
        }
    )

    def record(seed: int) -> LoopData:
        rng = np.random.default_rng(seed)
        u = rng.standard_normal((n, 2))
        s = simulate(model, reference=u, noise=sigma * rng.standard_normal((n, 2)))
        y = s.y.copy()
        y[:, 1] += 0.3 * y[:, 1] ** 3 / y[:, 1].std() ** 2
        return replace(s, y=y)

    d = diagnose(model, record(1), record(2))
    assert d.headline is not None and d.headline.cause == "nonlinear_distortion"
    assert d.unexplained is not None and d.unexplained.distorted
    assert d.unexplained.noise_std < 3 * sigma, d.unexplained
    assert d.unexplained.allowed > d.unexplained.fit + 5, d.unexplained


def test_a_distortion_counts_per_output_whatever_the_units():
    """Two outputs in units 1000 apart: output 0 left within the noise, output 1 with a
    fitted distortion 3 against a rest 1 (in its own units). Each output's share is bounded
    by its own ratio, so the share is the mean of 0 and sqrt(3/4) (100 - fit₁), whatever
    the units; a NaN noise level leaves the bound 1 + 3/1 and the finding significant."""
    left = Unexplained(80.0, 80.0, 0.0, 1.0, 0.1, fits=(90.0, 70.0), shares=(0.0, 0.0))
    got = with_distortion(left, np.array([0.0, 3.0]), np.array([1000.0**2, 1.0]))
    assert got.shares == pytest.approx((0.0, 30.0 * math.sqrt(0.75)))
    assert got.share == pytest.approx(15.0 * math.sqrt(0.75))
    nan_level = with_distortion(dataclasses.replace(left, ratio=math.nan), [0.0, 3.0], [1.0, 1.0])
    assert nan_level.ratio == pytest.approx(4.0) and nan_level.significant


def test_a_coupled_loop_carries_each_outputs_noise_into_the_others(mimo_model):
    """The 2x2 closed loop of the fixture: the shaped variance is linear in the outputs'
    variances (Σ_j |T̃_ij|² σ_j², round-off relative to its size), equal variances give
    σ² times the sum of both, and each output's noise reaches the other (coupled plant)."""
    n = 4000
    e0, e1 = loop_shaped([1.0, 0.0], mimo_model, n), loop_shaped([0.0, 1.0], mimo_model, n)
    both = loop_shaped([0.3, 2.0], mimo_model, n)
    assert both == pytest.approx(0.3 * e0 + 2.0 * e1, rel=1e-12)
    assert loop_shaped([0.5, 0.5], mimo_model, n) == pytest.approx(0.5 * (e0 + e1), rel=1e-12)
    assert e1[0] > 0.0 and e0[1] > 0.0  # weakly: 7e-6 of output 0's own
