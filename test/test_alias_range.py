# SPDX-License-Identifier: Apache-2.0
"""The alias range rho: a brute-force per-bin loop, and the lifted state space of the loop."""

from dataclasses import replace

import numpy as np
import pytest

from mr_bench.scenarios import draw_loop
from mr_ident.errors import DimensionError
from mr_ident.numerics.lifted.alias_range import alias_range, pfg_alias_range, row_alias_range
from mr_ident.numerics.lifting import half_to_full, lifting_transform
from mr_ident.numerics.systems.simulate import lifted_loop


def _per_bin(G, F, n):
    """rho straight from the definition, one centre bin and one column at a time."""
    K, n_out, fin = G.shape
    n_in = fin // F
    out = np.empty((K - 2 * n, F))
    for j in range(n, K - n):
        big = np.array([max(abs(G[k, i, c]) for k in range(j - n, j + n + 1) for c in range(fin))
                        for i in range(n_out)])  # fmt: skip
        for a in range(F):
            col = G[j][:, a * n_in : (a + 1) * n_in]
            out[j - n, a] = np.sqrt(np.sum(big**2)) / np.linalg.svd(col, compute_uv=False)[0]
    return out


@pytest.mark.parametrize("n_out,n_in,F,n", [(3, 1, 3, 0), (4, 2, 2, 2), (1, 2, 3, 1)])
def test_the_alias_range_equals_a_per_bin_loop(n_out, n_in, F, n):
    rng = np.random.default_rng(n_out + 10 * n)
    G = rng.standard_normal((9, n_out, F * n_in)) + 1j * rng.standard_normal((9, n_out, F * n_in))
    G *= np.logspace(0, -6, F * n_in)[None, None, :]  # entries of very different size
    np.testing.assert_allclose(alias_range(G, F, n), _per_bin(G, F, n), rtol=1e-12)


def _lifted_J_of_the_simulation(model, N, bins):
    """J from the state space the simulation runs (time-lifted), moved to frequency lifting."""
    ss = lifted_loop(model)
    F = model.ratio
    A, B, C, D = ss.A, ss.B[:, :F], ss.C[:F], ss.D[:F, :F]
    z = np.exp(2j * np.pi * bins / (N // F))
    X = np.linalg.solve(
        z[:, None, None] * np.eye(A.shape[0]) - A, np.broadcast_to(B, (z.size, *B.shape))
    )
    T = lifting_transform(bins, F, N)
    return T @ (C @ X + D) @ np.conj(np.swapaxes(T, 1, 2))


@pytest.mark.parametrize("seed", [1, 7])
def test_the_models_alias_range_equals_that_of_the_simulated_loop(seed):
    """pfg_alias_range (the Woodbury lifted maps) against the simulation's lifted state space,
    with a window across the lifted bin 0 (the bins below it continue the window).

    Within n bins of a multiple of fs_low the window holds the lifted bin 0, where a loop
    with an integrator has its pole: there the maps are infinite or, with the pole missed by
    round-off, finite and arbitrary (seed 1's controller: 4.6e13 with numpy 2.3, inf with
    numpy 1.26). Every other bin is finite and equal."""
    loop = draw_loop(np.random.default_rng(seed), duration=20.0, fs_choices=(240.0, 500.0))
    model, N, n = replace(loop.nominal, noise_std=0.0), loop.reference.shape[0], 8
    F, M = model.ratio, loop.reference.shape[0] // model.ratio
    got = pfg_alias_range(model, N, n)
    bins = np.arange(-n, M // 2 + 1 + n)
    ref = alias_range(_lifted_J_of_the_simulation(model, N, bins), F, n)
    kappa = np.arange(M // 2 + 1)[:, None] + M * np.arange(F)[None, :]
    idx = np.where(kappa > N // 2, N - kappa, kappa).ravel()
    want = np.full(N // 2 + 1, np.nan)
    want[idx] = ref.ravel()
    kappa = np.arange(1, N // 2 + 1)
    pole = np.minimum(kappa % M, M - kappa % M) <= n  # the window holds a multiple of M
    assert 0 < pole.sum() <= (2 * n + 1) * (F // 2 + 1)
    assert np.isfinite(got[~pole]).all()
    np.testing.assert_allclose(got[~pole], want[1:][~pole], rtol=1e-6)


def test_the_row_alias_range_of_a_siso_plant_is_the_largest_alias_over_the_own():
    rng = np.random.default_rng(0)
    F, N = 3, 24
    P = rng.standard_normal((N // 2 + 1, 1, 1)) + 0j
    P[0] = P[N // 2] = P[N // 2].real
    full = half_to_full(P, N)[:, 0, 0]
    kappa = np.arange(1, N // 2 + 1)
    alias = (kappa[:, None] + (N // F) * np.arange(F)[None, :]) % N
    want = np.abs(full[alias]).max(axis=1) / np.abs(full[kappa])
    np.testing.assert_allclose(row_alias_range(P, F, N), want, rtol=1e-12)


def test_bad_shapes_are_named():
    with pytest.raises(DimensionError, match=r"G must have shape \(K \+ 2\*halfwidth"):
        alias_range(np.ones((5, 2, 4)), 3)
    with pytest.raises(DimensionError, match="halfwidth=3, K >= 1; got"):
        alias_range(np.ones((6, 2, 3)), 3, 3)
    with pytest.raises(DimensionError, match=r"P_half must have shape \(N//2\+1=13"):
        row_alias_range(np.ones((12, 1, 1)), 3, 24)
