# SPDX-License-Identifier: Apache-2.0
"""Nonlinear distortion under white r (diagnosis.criterion.correlation).

Against constructed truth: an open-loop plant P (a second-order low-pass) driven by white
Gaussian u, with a static nonlinearity before it (``P (u + a u³)``: odd, input side;
``P (u + a u²)``: even, input side) or after it (``f(P u)``, f cubic: odd, output side),
noise of std 0.05 on y; the model is the linear P (its own BLA only up to a gain, a
linear error the test must not read as distortion). The test must find each (p below
1e-6, measured 1e-300-1e-40) and name its kind and side; on the linear plant and on
closed loops drawn at random with their exact model it must not fire (p above the
level 1e-3; measured minimum over these seeds in the docstring of the last test).
"""

from __future__ import annotations

import numpy as np
import pytest

from mr_bench.scenarios import draw_scenario
from mr_ident.diagnosis.criterion.correlation import HOS_ALPHA, correlation
from mr_ident.diagnosis.criterion.prediction import predict
from mr_ident.diagnosis.diagnose import split
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import simulate

N = 20000


def _plant():
    return model_from_dict(
        {
            "fs_high": 200.0,
            "ratio": 1,
            "plant": {"num": [400.0], "den": [1.0, 16.0, 400.0]},
        }
    )


def _record(before=None, after=None, seed=0):
    model = _plant()
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((N, 1))
    w = u if before is None else before(u)
    y = simulate(model, reference=w, noise=np.zeros((N, 1))).y
    y = y if after is None else after(y)
    y = y + 0.05 * rng.standard_normal((N, 1))
    return model, LoopData(u.copy(), u, y, fs_high=model.fs_high, ratio=1)


def _test(model, rec):
    return correlation(model, rec, 0, predict(model, rec), alpha=HOS_ALPHA)


def test_a_linear_plant_shows_no_distortion():
    c = _test(*_record())
    assert c is not None and not c.detected and c.p > HOS_ALPHA


@pytest.mark.parametrize(
    "before,after,kind,side",
    [
        (lambda u: u + 0.15 * u**3, None, "odd", "input"),
        (lambda u: u + 0.2 * u**2, None, "even", "input"),
        (None, lambda y: y + 2.0 * y**3, "odd", "output"),
    ],
    ids=["cubic-input", "square-input", "cubic-output"],
)
def test_a_static_nonlinearity_is_found_with_its_kind_and_side(before, after, kind, side):
    c = _test(*_record(before, after))
    assert c is not None and c.detected and c.p < 1e-6
    assert c.kind == kind and c.side == side, (c.kind, c.side, c.z)
    assert c.level_db > 0.5


@pytest.mark.parametrize("seed", [101, 102, 103, 104, 105, 106])
def test_closed_loops_drawn_at_random_with_their_exact_model_raise_no_alarm(seed):
    """The held-out part, as diagnose tests it (30 s records; a loop whose slowest mode
    outlasts a quarter of it is not tested)."""
    sc = draw_scenario([], np.random.default_rng(seed), duration=30.0)
    m, rec = sc.nominal, sc.data
    c = correlation(m, rec, split(rec), predict(m, rec), alpha=HOS_ALPHA)
    assert c is None or c.p > HOS_ALPHA, c
