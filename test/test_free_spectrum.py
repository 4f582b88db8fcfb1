# SPDX-License-Identifier: Apache-2.0
"""The closed-form DFT of the loop's free responses (LoopStream.free_y_spectrum) against
free responses simulated sample by sample.

Loops drawn at random (``scenarios.draw_loop``, F in {1, 2, 3, 5}) run from rest under a
white r by the per-sample reference loop of conftest; r then stops, and y from there on is
the response to whatever state the loop had reached (plant, controller and held outputs).
Its DFT from any start, a whole number of periods or not, lies in the span of the closed
form's columns to 1e-9 relative (least squares over real coefficients); white noise does
not (residual above 0.9 of it). One column per real mode and two per complex pair.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import brute_force_loop

from mr_bench.scenarios import draw_loop
from mr_ident.numerics.systems.simulate import LoopStream, lifted_loop


def _residual(G: np.ndarray, y: np.ndarray) -> float:
    """Relative residual of rfft(y) after least squares on the real span of G's columns."""
    Y = np.fft.rfft(y, axis=0, norm="ortho")
    A = np.concatenate([G.real, G.imag]).reshape(-1, G.shape[-1])
    b = np.concatenate([Y.real, Y.imag]).ravel()
    beta = np.linalg.lstsq(A, b, rcond=None)[0]
    return float(np.linalg.norm(b - A @ beta) / np.linalg.norm(b))


@pytest.mark.parametrize("seed,ratio", [(7300, 1), (7301, 2), (7302, 3), (7303, 5)])
def test_free_responses_lie_in_the_closed_form_span(seed, ratio):
    model = draw_loop(np.random.default_rng(seed), duration=2.0, ratios=(ratio,)).nominal
    rng = np.random.default_rng(seed)
    F = model.ratio
    n0, n1 = 40 * F, 90 * F
    r = np.zeros((n0 + n1, 1))
    r[:n0] = rng.standard_normal((n0, 1))
    _, y = brute_force_loop(model, r)
    lam = np.linalg.eigvals(lifted_loop(model).A)
    for start in sorted({0, F, 7 * F + F // 2, 13}):
        G = LoopStream(model).free_y_spectrum(n1, start)
        assert G.shape == ((n1 - start) // 2 + 1, 1, G.shape[-1])
        live = lam[np.abs(lam) ** (start // F) > 0]
        assert G.shape[-1] == np.count_nonzero(live.imag >= 0) + np.count_nonzero(live.imag > 0)
        assert _residual(G, y[n0 + start :]) < 1e-9
        assert _residual(G, rng.standard_normal((n1 - start, 1))) > 0.9
