# SPDX-License-Identifier: Apache-2.0
"""The broadband test of a model's residual (criterion/broadband.py) against analytic truth.

Synthetic LPM estimates of pure noise: complex Gaussian bins, a local polynomial of degree
2 over windows of 2n+1 bins (n = 8), its centre value the estimate and its residual the
variance (q = 2n+1 - 3 dof), exactly the correlation between neighbouring estimates the
test assumes. Under "model right" T's false-alarm rate must be alpha; a thin error, each
bin far below the per-bin (Bonferroni) threshold, must be seen.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from mr_ident.diagnosis.criterion.broadband import broadband, null_band
from mr_ident.diagnosis.criterion.evidence import Evidence, threshold
from mr_ident.numerics.fit.frf_fit import correlation_length, lpm_kernel

N_HALF, DEGREE, BINS = 8, 2, 1200
Q = 2 * N_HALF + 1 - (DEGREE + 1)


def _estimates(rng: np.random.Generator, trials: int) -> tuple[np.ndarray, np.ndarray]:
    """(estimate, std) of ``trials`` x BINS local-polynomial fits of unit complex noise."""
    w = 2 * N_HALF + 1
    shape = (trials, BINS + w - 1)
    x = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)
    win = np.lib.stride_tricks.sliding_window_view(x, w, axis=1)  # (trials, BINS, w)
    V = np.vander(np.arange(-N_HALF, N_HALF + 1) / N_HALF, DEGREE + 1, increasing=True)
    pinv = np.linalg.pinv(V)
    coef = win @ pinv.T  # (trials, BINS, R+1)
    resid = win - coef @ V.T
    var = np.sum(np.abs(resid) ** 2, axis=-1) / Q
    a = pinv[0]
    return coef[..., 0], np.sqrt(var * np.dot(a, a))


def _evidence(P_hat: np.ndarray, std: np.ndarray) -> Evidence:
    k = P_hat.size
    f = np.arange(1, k + 1, dtype=float)
    e, b = np.zeros(0), np.zeros(0, bool)
    z = np.abs(P_hat) / std
    thr = threshold(0.01, k, Q)
    shape = (k, 1, 1)
    return Evidence(f, P_hat.reshape(shape), std.reshape(shape), np.zeros(shape, complex), z,
                    thr, z > thr, e, e, np.inf, b, Q, np.ones(k, bool))  # fmt: skip


def test_the_null_band_is_the_fits_cost_band_with_no_parameters():
    mean, sd, L, thr = null_band(1000, 11.0, N_HALF, DEGREE, 0.01)
    assert L == pytest.approx(correlation_length(lpm_kernel(N_HALF, DEGREE)))
    assert mean == pytest.approx(1000 * 11 / 10)
    assert sd == pytest.approx(11 / 10 * np.sqrt(1000 * L))
    assert thr == pytest.approx(mean + scipy.stats.norm.isf(0.01) * sd)
    assert null_band(1000, 11.0, 0, DEGREE, 0.01)[2] == 1.0  # periodic lines: independent


@pytest.mark.parametrize("alpha", [0.05, 0.01])
def test_a_right_model_raises_the_broadband_alarm_at_rate_alpha(alpha):
    trials = 600
    P, S = _estimates(np.random.default_rng(41), trials)
    hits = [broadband(_evidence(P[j], S[j]), n=N_HALF, degree=DEGREE, alpha=alpha).significant
            for j in range(trials)]  # fmt: skip
    # within 3 binomial std of alpha (600 trials: 0.05 +- 0.027, 0.01 +- 0.012)
    tol = 3.0 * np.sqrt(alpha * (1 - alpha) / trials)
    assert abs(np.mean(hits) - alpha) <= tol
    z = [broadband(_evidence(P[j], S[j]), n=N_HALF, degree=DEGREE, alpha=alpha).z
         for j in range(trials)]  # fmt: skip
    assert abs(np.mean(z)) < 0.15 and abs(np.std(z) - 1.0) < 0.1  # standardized


def test_a_thin_error_below_every_bins_threshold_is_seen():
    trials = 100
    P, S = _estimates(np.random.default_rng(7), trials)
    c = 0.6  # the error per bin, in σ: a sixth of the per-bin threshold's
    thr = threshold(0.01, BINS, Q)
    assert c < 0.2 * thr
    phase = np.exp(2j * np.pi * np.linspace(0.0, 3.0, BINS))  # a slowly turning error
    found = []
    for j in range(trials):
        ev = _evidence(P[j] + c * S[j] * phase, S[j])
        found.append(broadband(ev, n=N_HALF, degree=DEGREE, alpha=0.01).significant)
    # the shift q/(q-1) c² N (465) over sd{T} (q/(q-1) sqrt(N L), 90): 5.2 sd, 2.8 beyond
    # the 2.33 of alpha = 1 % (the sd widened by the error's cross term), seen in ~ 99 %
    assert np.mean(found) >= 0.9
