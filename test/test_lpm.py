# SPDX-License-Identifier: Apache-2.0
"""LPM: the batched engine equals a per-bin least-squares loop; exact on polynomial data."""

import numpy as np
import pytest
from conftest import lpm_regressor

from mr_ident.errors import ConfigError, DataError
from mr_ident.numerics.local.lpm import lpm


def per_bin_reference(U, Y, n, R):
    """Straight per-bin LPM with numpy.linalg.lstsq (QR/SVD based)."""
    K = U.shape[0] - 2 * n
    ni, no = U.shape[1], Y.shape[1]
    G = np.empty((K, no, ni), complex)
    Cv = np.empty((K, no, no), complex)
    Ai = np.empty((K, ni, ni), complex)
    for k in range(K):
        Uw, Yw = U[k : k + 2 * n + 1], Y[k : k + 2 * n + 1]
        Km = lpm_regressor(Uw, n, R)
        th, *_ = np.linalg.lstsq(Km, Yw, rcond=None)
        G[k] = th[:ni].T
        V = Yw - Km @ th
        Cv[k] = V.T @ V.conj() / (2 * n + 1 - Km.shape[1])
        Ai[k] = np.linalg.inv(Km.conj().T @ Km)[:ni, :ni]
    return G, Cv, Ai


@pytest.mark.parametrize("ni,no,n,R", [(1, 2, 8, 2), (3, 6, 8, 2), (2, 2, 6, 1), (1, 1, 3, 0)])
def test_the_batched_lpm_equals_a_per_bin_least_squares_loop(ni, no, n, R):
    rng = np.random.default_rng(ni * 100 + no)
    K = 40
    U = rng.standard_normal((K + 2 * n, ni)) + 1j * rng.standard_normal((K + 2 * n, ni))
    Y = rng.standard_normal((K + 2 * n, no)) + 1j * rng.standard_normal((K + 2 * n, no))
    fit = lpm(U, Y, n=n, degree=R, map_outputs=1)
    G, Cv, Ai = per_bin_reference(U, Y, n, R)
    np.testing.assert_allclose(fit.G, G, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fit.noise_cov, Cv, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fit.inv_gram, Ai, rtol=1e-10, atol=1e-12)


def test_lpm_recovers_a_polynomial_frf_and_transient_exactly():
    rng = np.random.default_rng(3)
    n, R, K = 8, 2, 200
    k = np.arange(K + 2 * n) / 50.0
    U = rng.standard_normal((K + 2 * n, 2)) + 1j * rng.standard_normal((K + 2 * n, 2))
    G = np.stack([1 + 0.5j * k + 0.1 * k**2, -2 + k, 0.3j * k**2, 1 - 1j * k], 1).reshape(-1, 2, 2)
    T = (0.2 - 0.3j * k + 0.05 * k**2)[:, None] * np.array([1.0, -2.0])
    Y = np.einsum("kab,kb->ka", G, U) + T
    fit = lpm(U, Y, n=n, degree=R)
    np.testing.assert_allclose(fit.G, G[n:-n], atol=1e-10)
    # The residual covariance comes from Y^H Y - B^H A^-1 B: zero up to ~1e-14 of |Y|^2.
    assert np.abs(fit.noise_cov).max() < 1e-12 * np.mean(np.abs(Y) ** 2)


def test_scaling_the_input_scales_the_estimate_inversely():
    rng = np.random.default_rng(5)
    n, K = 8, 60
    U = rng.standard_normal((K + 2 * n, 1)) + 1j * rng.standard_normal((K + 2 * n, 1))
    Y = rng.standard_normal((K + 2 * n, 2)) + 1j * rng.standard_normal((K + 2 * n, 2))
    a = lpm(U, Y, n=n)
    b = lpm(1e3 * U, Y, n=n)
    np.testing.assert_allclose(b.G * 1e3, a.G, rtol=1e-9)
    np.testing.assert_allclose(b.inv_gram * 1e6, a.inv_gram, rtol=1e-9)


def test_too_few_degrees_of_freedom_is_a_clear_error():
    with pytest.raises(
        ConfigError, match=r"must exceed n_out = 6 .* use n >= 9 or a lower degree"
    ):
        lpm(np.ones((40, 3)), np.ones((40, 6)), n=8, degree=2)


def test_too_few_bins_is_a_data_error():
    with pytest.raises(DataError, match="at least 2n\\+1 = 17 bins"):
        lpm(np.ones((10, 1)), np.ones((10, 1)), n=8)


def test_a_window_without_excitation_gives_nan_and_a_warning():
    rng = np.random.default_rng(0)
    U = rng.standard_normal((60, 1)) + 0j
    U[20:45] = 0.0
    Y = rng.standard_normal((60, 1)) + 0j
    with pytest.warns(RuntimeWarning, match="rank-deficient"):
        fit = lpm(U, Y, n=8)
    assert np.isnan(fit.G[20]).all() and np.isfinite(fit.G[0]).all()


def test_the_engine_at_selected_centres_equals_every_centre_taken_there():
    """Runs and single bins over three chunks of the engine (4096 bins each), a chunk with
    none selected among them: G, C_v and the inverse Gram matrix at the selected centres
    equal those of the fit at every centre within 1e-10 relative and 1e-13 of the largest
    entry (rounding: the windowed sums are formed over a shorter stretch, so the BLAS blocks
    group the bins differently)."""
    from mr_ident.numerics.local.lpm import dof, lpm_bins_last

    rng = np.random.default_rng(3)
    n, K = 8, 11_000
    U = rng.standard_normal((K + 2 * n, 2)) + 1j * rng.standard_normal((K + 2 * n, 2))
    Y = U @ rng.standard_normal((2, 3)) + 0.1 * rng.standard_normal((K + 2 * n, 3))
    q = dof(n, 2, 2)
    every = lpm_bins_last(U, Y, n, 2, q)
    centres = np.r_[3:40, 100, 4090:4110, 8300:8302, 10_990:11_000]
    some = lpm_bins_last(U, Y, n, 2, q, centres=centres)
    assert some[3] == 0
    for a, b in zip(every[:3], some[:3], strict=True):
        np.testing.assert_allclose(b, a[..., centres], rtol=1e-10, atol=1e-13 * np.abs(a).max())


@pytest.mark.parametrize("n", [8, "auto"])
def test_the_benchmarks_straightforward_reference_gives_our_estimate(paper_model, n):
    """`make bench`'s reference (every window's regressor built, one QR per window, J and S
    fitted apart) put in the engine's place: the same P_h as our engine within 1e-9
    relative, at the fixed window and with the automatic one (runs of centres)."""
    import functools
    import sys
    from unittest import mock

    from bench_identify import straightforward_lpm_core

    from mr_ident.numerics.identify import identify
    from mr_ident.numerics.systems.simulate import simulate

    sim = simulate(paper_model, duration=40.0, rng=np.random.default_rng(2))
    args = dict(fs_high=240.0, ratio=3, n=n, keep_lifted=False, workers=1)
    ours = identify(sim.r, sim.u, sim.y, **args).plant.response
    engine = functools.partial(straightforward_lpm_core, split=3)
    with mock.patch.object(sys.modules["mr_ident.numerics.local.lpm"], "lpm_bins_last", engine):
        ref = identify(sim.r, sim.u, sim.y, **args).plant.response
    np.testing.assert_allclose(ref, ours, rtol=1e-9)
