# SPDX-License-Identifier: Apache-2.0
"""The lifted simulator equals a per-sample simulation of the loop's definition."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import brute_force_loop

from mr_ident.errors import ConfigError, DimensionError
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.systems.simulate import simulate


@pytest.mark.parametrize("phase,delay", [(0, 0), (1, 0), (2, 1), (0, 4)])
def test_lifted_simulation_equals_the_per_sample_loop(paper_model, phase, delay):
    model = replace(paper_model, sample_phase=phase, control_delay=delay)
    rng = np.random.default_rng(1)
    N = 3 * 400
    r = rng.standard_normal((N, 1))
    v = 1e-4 * rng.standard_normal((N, 1))
    sim = simulate(model, reference=r, noise=v)
    u, y = brute_force_loop(model, r, v)
    scale = np.abs(y).max()
    np.testing.assert_allclose(sim.y, y, atol=1e-9 * scale)
    np.testing.assert_allclose(sim.u, u, atol=1e-9 * np.abs(u).max())


def test_mimo_lifted_simulation_equals_the_per_sample_loop():
    model = model_from_dict(
        {
            "fs_high": 100.0,
            "ratio": 2,
            "plant": {"num": [[[1.0], [0.2]], [[0.1], [2.0]]], "den": [1.0, 3.0, 10.0]},
            "controller": {"num": [[[0.5, 0.0], [0.0]], [[0.0], [0.4, 0.0]]], "den": [1.0, -0.5]},
        }
    )
    rng = np.random.default_rng(2)
    r = rng.standard_normal((400, 2))
    sim = simulate(model, reference=r)
    u, y = brute_force_loop(model, r)
    np.testing.assert_allclose(sim.y, y, atol=1e-10 * np.abs(y).max())
    np.testing.assert_allclose(sim.u, u, atol=1e-10 * np.abs(u).max())


def test_simulation_is_reproducible_through_the_generator(paper_model):
    a = simulate(paper_model, duration=1.0, rng=np.random.default_rng(7))
    b = simulate(paper_model, duration=1.0, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.y, b.y)
    assert a.r.shape == (240, 1)


def test_simulation_needs_a_generator_and_a_whole_number_of_periods(paper_model):
    with pytest.raises(ConfigError, match="rng"):
        simulate(paper_model, n_samples=30)
    with pytest.raises(DimensionError, match="multiple of ratio F=3"):
        simulate(paper_model, n_samples=31, rng=np.random.default_rng(0))
