# SPDX-License-Identifier: Apache-2.0
"""The higher-order correlation test on MIMO loops and on records with missing samples.

Against constructed truth, as ``test_correlation.py``: a coupled 2x2 open-loop plant
driven by white Gaussian u with a cubic before its second input (odd, input side) must
be found (p below 1e-6) and named; the linear plant must not fire (p above the level
1e-3), nor closed 2x2 loops with their exact model. With 2 % of the samples of u and y
missing (NaN: single samples, and bursts of 5-50 of both, as a bag that dropped
messages) the SISO cases of ``test_correlation.py`` hold the same way, and so do closed
loops drawn at random with their exact model.
"""

from __future__ import annotations

from dataclasses import replace

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


def _plant(n: int):
    num = [[[400.0]]] if n == 1 else [[[400.0], [80.0]], [[40.0], [400.0]]]
    return model_from_dict(
        {"fs_high": 200.0, "ratio": 1, "plant": {"num": num, "den": [1.0, 16.0, 400.0]}}
    )


def _holes(shape: tuple[int, ...], rng: np.random.Generator, share: float = 0.02):
    """A mask of missing samples: half single samples, half bursts of 5-50."""
    n = shape[0]
    mask = np.zeros(shape, bool)
    single = rng.choice(n, int(share * n / 2) * shape[1]).reshape(-1, shape[1])
    for ch in range(shape[1]):
        mask[single[:, ch], ch] = True
    lost = 0
    while lost < share * n / 2:
        k = int(rng.integers(5, 51))
        s = int(rng.integers(n // 10, n - k))
        mask[s : s + k] = True
        lost += k
    return mask


def _with_holes(rec: LoopData, seed: int) -> LoopData:
    rng = np.random.default_rng(seed)
    u, y = rec.u.copy(), rec.y.copy()
    u[_holes(u.shape, rng)] = np.nan
    y[_holes(y.shape, rng)] = np.nan
    return replace(rec, u=u, y=y)


def _record(n: int, before=None, after=None, seed=0) -> tuple:
    model = _plant(n)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((N, n))
    w = u if before is None else before(u)
    y = simulate(model, reference=w, noise=np.zeros((N, n))).y
    y = y if after is None else after(y)
    y = y + 0.05 * rng.standard_normal((N, n))
    return model, LoopData(u.copy(), u, y, fs_high=model.fs_high, ratio=1)


def _cubic_second(u):
    return u + np.array([0.0, 0.15]) * u**3


def _test(model, rec):
    return correlation(model, rec, 0, predict(model, rec), alpha=HOS_ALPHA)


def test_a_linear_mimo_plant_shows_no_distortion():
    c = _test(*_record(2))
    assert c is not None and not c.detected and c.p > HOS_ALPHA
    assert len(c.z) == 6 and c.names[0].startswith("input0_even")


def test_a_cubic_at_one_input_of_a_mimo_plant_is_found_with_its_kind_and_side():
    c = _test(*_record(2, before=_cubic_second))
    assert c is not None and c.detected and c.p < 1e-6
    assert c.kind == "odd" and c.side == "input", (c.kind, c.side, c.names, c.z)


def _cubic_output_second(y):
    return y + np.array([0.0, 0.3]) * y**3 / y.std(axis=0) ** 2


def test_a_distortion_at_one_output_leaves_the_other_outputs_noise_bound_at_its_noise():
    """A cubic at output 1 only: output 0's rest is its noise (0.05²; a variance of N
    samples, relative std sqrt(2/N) = 1 %, 5 % allowed for the AR whitening's fit), output
    1's fitted part is ten times that noise and more, and the level is output 1's."""
    c = _test(*_record(2, after=_cubic_output_second))
    assert c is not None and c.detected and c.side == "output"
    assert c.rest_vars[0] == pytest.approx(0.05**2, rel=0.05)
    assert c.fitted_vars[0] < 0.01 * c.rest_vars[0]
    assert c.fitted_vars[1] > 10 * c.rest_vars[0]
    assert c.level_db == pytest.approx(10 * np.log10(1 + c.fitted_vars[1] / c.rest_vars[1]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closed_mimo_loops_with_their_exact_model_raise_no_alarm(mimo_model, seed):
    m = replace(mimo_model, noise_std=0.05)
    rec = simulate(m, duration=120.0, rng=np.random.default_rng(seed))
    c = correlation(m, rec, split(rec), predict(m, rec), alpha=HOS_ALPHA)
    assert c is not None and c.p > HOS_ALPHA, c


@pytest.mark.parametrize(
    "before,after,kind,side",
    [
        (None, None, "", ""),
        (lambda u: u + 0.15 * u**3, None, "odd", "input"),
        (None, lambda y: y + 2.0 * y**3, "odd", "output"),
    ],
    ids=["linear", "cubic-input", "cubic-output"],
)
def test_missing_samples_leave_the_test_as_it_was(before, after, kind, side):
    model, rec = _record(1, before, after)
    c = _test(model, _with_holes(rec, 5))
    assert c is not None
    if not kind:
        assert not c.detected and c.p > HOS_ALPHA
        return
    assert c.detected and c.p < 1e-6 and c.kind == kind and c.side == side, c
    assert c.samples < N  # the holes' samples are not counted


@pytest.mark.parametrize("seed", [101, 102, 103, 104])
def test_closed_loops_with_missing_samples_and_their_exact_model_raise_no_alarm(seed):
    sc = draw_scenario([], np.random.default_rng(seed), duration=30.0)
    m, rec = sc.nominal, _with_holes(sc.data, seed)
    c = correlation(m, rec, split(rec), predict(m, rec), alpha=HOS_ALPHA)
    assert c is None or c.p > HOS_ALPHA, c
