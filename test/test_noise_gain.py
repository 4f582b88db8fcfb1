# SPDX-License-Identifier: Apache-2.0
"""The loop's noise gain (mr_ident.diagnosis.criterion.noise.loop_noise_gain) against what a
simulation of the loop does with white output noise.

Loops drawn at random (``scenarios.draw_loop``, F in {1, 2, 3, 5}) run with r = 0 and
white output noise of unit variance: the averaged periodogram of the measured y (64
segments of the record, each a DFT of the gain's length) matches the gain to 15 % in the
median over the bins (the periodogram's own spread over 64 segments is 12 %), and where
the gain has a shape their logarithms correlate above 0.9. F = 1 is also checked against
``|1 / (1 + P K)|²`` directly.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mr_bench.scenarios import draw_loop
from mr_ident.diagnosis.criterion.noise import loop_noise_gain
from mr_ident.numerics.systems.simulate import simulate


@pytest.mark.parametrize("seed,ratio", [(7100, 1), (7101, 2), (7102, 3), (7103, 5)])
def test_the_noise_gain_is_what_the_loop_does_with_white_output_noise(seed, ratio):
    loop = draw_loop(np.random.default_rng(seed), duration=5.0, ratios=(ratio,))
    model = replace(loop.nominal, noise_std=1.0)
    n, segs = 60 * ratio * 4, 64
    skip = 20 * n
    rng = np.random.default_rng(seed)
    N = skip + segs * n
    rec = simulate(model, reference=np.zeros((N, 1)), noise=rng.standard_normal((N, 1)))
    y = rec.y[skip:, 0].reshape(segs, n)
    Y = np.fft.rfft(y, axis=1, norm="ortho")
    S = np.mean(np.abs(Y) ** 2, axis=0)
    g = loop_noise_gain(model, n)[:, 0]
    ratio_ = S[1:-1] / g[1:-1]
    assert abs(np.median(ratio_) - 1) < 0.15, np.median(ratio_)
    lg = np.log(g[1:-1])
    if np.std(lg) > 0.2:  # a shaped gain: the periodogram follows its shape
        assert np.corrcoef(np.log(S[1:-1]), lg)[0, 1] > 0.9
    if ratio == 1:
        f = np.arange(n // 2 + 1) * model.fs_high / n
        P = model.plant_discrete().freqresp(f)[:, 0, 0]
        K = model.controller_frf(n)[: n // 2 + 1, 0, 0]
        with np.errstate(all="ignore"):
            exact = np.abs(1 / (1 + P * K)) ** 2
        ok = np.isfinite(exact) & (exact > 1e-3 * np.median(exact))
        np.testing.assert_allclose(g[ok], exact[ok], rtol=1e-9)


def test_open_loop_gain_is_one():
    loop = draw_loop(np.random.default_rng(7104), duration=5.0, ratios=(2,))
    assert np.all(loop_noise_gain(replace(loop.nominal, controller=None), 240) == 1.0)
