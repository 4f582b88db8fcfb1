# SPDX-License-Identifier: Apache-2.0
"""The criterion keeps the loops it has seen (Objective's modal forms, free responses and
their projection) and its last residuals: a model's residual is the same whatever the
criterion evaluated before it (the same operations on the same numbers: equal to 1e-12 of
the residual's largest component, which allows for a BLAS kernel that rounds by where the
arrays lie in memory; a wrong loop reused would differ at the size of the residual).

A loop drawn at random (``scenarios.draw_scenario``, nothing hidden, 30 s, white r): the
residuals of a sequence of models that share loops (the nominal, a gain change, each with
output disturbances of other values; more loops than are kept, so some are dropped and
built again) against each model's residual from a criterion that saw no other model.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from mr_bench.scenarios import draw_scenario
from mr_ident.diagnosis.criterion.objective import LOOPS_KEPT, Objective
from mr_ident.diagnosis.diagnose import default_n, identify_record, noise_spectrum, split


def test_a_models_residual_does_not_depend_on_the_models_before_it():
    sc = draw_scenario([], np.random.default_rng(5), duration=30.0)
    model, data = sc.nominal, sc.data
    n = default_n("freq-lifted", 2, model.ratio, model.n_u, max(model.n_u, model.n_y))
    est = data.part(0, split(data, 0.7))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify_record(est, model, n=n, degree=2)
        noise = noise_spectrum(est, model, n=n, degree=2, ident=ident)
    f = 0.11 * model.fs_high
    gains = [1.0, 1.05, 0.9, 1.2, 1.1, 0.8][: LOOPS_KEPT + 2]
    models = [
        replace(model, plant_gain=g, disturbances=d)
        for g in gains
        for d in ((), ((f, 0.01, 0.3, 0),), ((f, 0.02, -0.5, 0),))
    ]
    ob = Objective(est, model, noise)
    seen = [ob.residuals(m) for m in models + models[::-1]]
    for m, got, back in zip(models, seen, seen[::-1], strict=False):
        alone = Objective(est, model, noise).residuals(m)
        tol = 1e-12 * np.max(np.abs(alone))
        np.testing.assert_allclose(got, alone, rtol=0, atol=tol)
        np.testing.assert_allclose(back, alone, rtol=0, atol=tol)
