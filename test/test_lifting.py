# SPDX-License-Identifier: Apache-2.0
"""Lifting: round trips are the identity; the two lifted domains agree (to 1e-12)."""

import numpy as np
import pytest

from mr_ident.errors import ConfigError, DimensionError
from mr_ident.numerics.lifting import (
    dft,
    freq_lift,
    freq_unlift,
    idft,
    lift_frf,
    lifting_transform,
    time_lift,
    time_unlift,
    unlift_frf,
)


@pytest.mark.parametrize("F", [1, 2, 3, 5])
@pytest.mark.parametrize("c", [1, 2])
def test_time_and_frequency_lifting_of_signals_round_trip_exactly(F, c):
    rng = np.random.default_rng(F * 10 + c)
    x = rng.standard_normal((F * 7, c))
    np.testing.assert_array_equal(time_unlift(time_lift(x, F), F), x)
    X = dft(x)
    np.testing.assert_array_equal(freq_unlift(freq_lift(X, F), F), X)
    np.testing.assert_allclose(idft(X).real, x, atol=1e-13)


def test_time_lifting_stacks_consecutive_samples():
    x = np.arange(6.0)
    np.testing.assert_array_equal(time_lift(x, 3), [[0, 1, 2], [3, 4, 5]])


def test_frequency_lifting_stacks_the_aliases():
    X = np.arange(6.0)[:, None]
    np.testing.assert_array_equal(freq_lift(X, 3), [[0, 2, 4], [1, 3, 5]])


def test_a_length_that_is_not_a_multiple_of_F_is_an_error_not_a_cut():
    with pytest.raises(DimensionError, match="not a multiple of ratio F=3"):
        time_lift(np.zeros(10), 3)
    with pytest.raises(ConfigError, match="ratio must be an integer >= 1"):
        time_lift(np.zeros(9), 0)


@pytest.mark.parametrize("F", [2, 3])
def test_the_time_lifted_spectrum_maps_to_the_frequency_lifted_one_by_the_unitary_T(F):
    rng = np.random.default_rng(F)
    c, M = 2, 16
    x = rng.standard_normal((F * M, c))
    Xt = freq_lift(dft(x), F)  # (M, F c)
    Xb = dft(time_lift(x, F))  # (M, F c), M-point DFT
    T = lifting_transform(np.arange(M), F, F * M, c)
    np.testing.assert_allclose(np.einsum("kab,kb->ka", T, Xb), Xt, atol=1e-12)
    np.testing.assert_allclose(
        T @ np.conj(np.swapaxes(T, 1, 2)), np.broadcast_to(np.eye(F * c), T.shape), atol=1e-12
    )


@pytest.mark.parametrize("domain", ["frequency", "time"])
@pytest.mark.parametrize("F", [1, 3, 4])
def test_lifting_an_lti_frf_and_unlifting_it_is_the_identity(domain, F):
    rng = np.random.default_rng(F)
    N, ny, nu = 12 * F, 2, 3
    G = rng.standard_normal((N, ny, nu)) + 1j * rng.standard_normal((N, ny, nu))
    back = unlift_frf(lift_frf(G, F, domain=domain), F, domain=domain)
    np.testing.assert_allclose(back.transpose(1, 0, 2, 3).reshape(N, ny, nu), G, atol=1e-12)


def test_the_time_lifted_frf_is_the_frf_of_the_lifted_system():
    # y = g * u with a short FIR g: the lifted system's M-point FRF must equal
    # lift_frf(..., "time").
    F, M = 3, 32
    N = F * M
    g = np.array([1.0, 0.5, -0.25, 0.125, 0.3])
    G = np.fft.fft(g, N)[:, None, None]
    rng = np.random.default_rng(0)
    u = rng.standard_normal(N)
    y = np.real(np.fft.ifft(np.fft.fft(u) * G[:, 0, 0]))  # circular convolution
    Ub, Yb = dft(time_lift(u, F)), dft(time_lift(y, F))
    Gb = lift_frf(G, F, domain="time")
    np.testing.assert_allclose(np.einsum("kab,kb->ka", Gb, Ub), Yb, atol=1e-12)


def test_half_spectra_of_several_signals_are_each_ones_rfft_whatever_the_threads():
    from mr_ident.numerics.lifting import half_spectra, half_spectrum

    rng = np.random.default_rng(5)
    xs = [rng.standard_normal((24, c)) for c in (1, 2, 1)]
    for workers in (1, 2):
        got = half_spectra(xs, workers=workers)
        assert [len(g) for g in got] == [1, 2, 1]
        for x, g in zip(xs, got, strict=True):
            for i, col in enumerate(g):
                np.testing.assert_array_equal(col, np.fft.rfft(x[:, i], norm="ortho"))
            assert all(np.array_equal(a, b) for a, b in zip(g, half_spectrum(x), strict=True))
