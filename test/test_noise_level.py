# SPDX-License-Identifier: Apache-2.0
"""The criterion's noise level (mr_ident.diagnosis.criterion.objective.Objective) against the noise
the record was made with.

Loops drawn at random with integral action in the controller (``scenarios.draw_scenario``,
nothing hidden, 30 s, white output noise of known std sigma): the level the criterion
whitens by, with the loop's noise gain divided out, is sigma² per bin. Below 1 Hz the LPM
reads the leakage of the integrator's slow closed-loop mode as noise (on these loops
3 000-250 000x sigma² in the lowest ten bins, measured before the fix); the criterion's
level there must be within a factor 3 of sigma² in the median, and within 20 % over the
middle of the band, where the LPM was always right.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mr_bench.scenarios import draw_scenario
from mr_ident.diagnosis.criterion.noise import loop_noise_gain
from mr_ident.diagnosis.criterion.objective import Objective
from mr_ident.diagnosis.diagnose import default_n, identify_record, noise_spectrum, split


@pytest.mark.parametrize("seed", [1, 19, 21])
def test_the_level_near_dc_is_the_noise_not_the_integrators_leakage(seed):
    sc = draw_scenario([], np.random.default_rng(seed), duration=30.0)
    assert sc.loop.controller_kind in ("pi", "pid")
    model, data = sc.nominal, sc.data
    n = default_n("freq-lifted", 2, model.ratio, model.n_u, max(model.n_u, model.n_y))
    est = data.part(0, split(data, 0.7))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_record(est, model, n=n, degree=2)
        noise = noise_spectrum(est, model, n=n, degree=2, ident=ident)
    ob = Objective(est, model, noise)
    g = loop_noise_gain(model, est.n_samples - ob.skip)
    level = (ob.weight**-2 / g)[:, 0] / model.noise_std**2
    low = float(np.median(level[1:11]))
    mid = float(np.median(level[level.size // 4 : level.size // 2]))
    assert 1 / 3 < low < 3, low
    assert abs(mid - 1) < 0.2, mid
