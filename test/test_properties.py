# SPDX-License-Identifier: Apache-2.0
"""Property tests (hypothesis) on the core: lifting round trips, LPM scaling, block alignment.

Derandomized (the same examples every run, so CI is reproducible); set
MR_IDENT_HYPOTHESIS_EXAMPLES=400 to search afresh with more examples.
"""

from __future__ import annotations

import os

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mr_ident.io.blocks import Block
from mr_ident.live.align import Aligner
from mr_ident.numerics.lifting import (
    freq_lift,
    freq_unlift,
    lift_frf,
    time_lift,
    time_unlift,
    unlift_frf,
)
from mr_ident.numerics.local.lpm import lpm

SETTINGS = settings(
    max_examples=int(os.environ.get("MR_IDENT_HYPOTHESIS_EXAMPLES", 40)),
    deadline=None,
    derandomize=os.environ.get("MR_IDENT_HYPOTHESIS_EXAMPLES") is None,
)


@SETTINGS
@given(F=st.integers(1, 7), M=st.integers(1, 40), c=st.integers(1, 3), seed=st.integers(0, 2**31))
def test_signal_lifting_round_trips(F, M, c, seed):
    x = np.random.default_rng(seed).standard_normal((F * M, c))
    np.testing.assert_array_equal(time_unlift(time_lift(x, F), F), x)
    X = x + 1j * np.random.default_rng(seed + 1).standard_normal(x.shape)
    np.testing.assert_array_equal(freq_unlift(freq_lift(X, F), F), X)


@SETTINGS
@given(
    F=st.integers(1, 5),
    M=st.integers(1, 12),
    ny=st.integers(1, 2),
    nu=st.integers(1, 2),
    seed=st.integers(0, 2**31),
)
def test_frf_lifting_round_trips(F, M, ny, nu, seed):
    rng = np.random.default_rng(seed)
    N = F * M
    G = rng.standard_normal((N, ny, nu)) + 1j * rng.standard_normal((N, ny, nu))

    def high_rate(out):  # (M, F, ny, nu), entry [k, l] at bin k + l M -> (N, ny, nu)
        return out.transpose(1, 0, 2, 3).reshape(N, ny, nu)

    Gf = high_rate(unlift_frf(lift_frf(G, F, domain="frequency"), F, domain="frequency"))
    np.testing.assert_allclose(Gf, G, rtol=0, atol=1e-12)
    Gt = high_rate(unlift_frf(lift_frf(G, F, domain="time"), F, domain="time"))
    np.testing.assert_allclose(Gt, G, rtol=0, atol=1e-12 * F)


@SETTINGS
@given(scale=st.floats(1e-6, 1e6), n_in=st.integers(1, 2), seed=st.integers(0, 2**31))
def test_lpm_estimate_scales_inversely_with_the_input(scale, n_in, seed):
    """U -> a U gives G -> G / a (to 1e-9 relative), and the same noise covariance."""
    rng = np.random.default_rng(seed)
    K, n = 60, 6
    U = rng.standard_normal((K, n_in)) + 1j * rng.standard_normal((K, n_in))
    Y = rng.standard_normal((K, 2)) + 1j * rng.standard_normal((K, 2))
    a = lpm(U, Y, n=n, degree=1)
    b = lpm(scale * U, Y, n=n, degree=1)
    np.testing.assert_allclose(b.G * scale, a.G, rtol=1e-9, atol=1e-9 * np.abs(a.G).max())
    np.testing.assert_allclose(
        b.noise_cov, a.noise_cov, rtol=1e-8, atol=1e-9 * np.abs(a.noise_cov).max()
    )


@SETTINGS
@given(data=st.data(), N=st.integers(30, 400), F=st.integers(1, 4), seed=st.integers(0, 2**31))
def test_split_and_reordered_blocks_align_to_the_original_stream(data, N, F, seed):
    rng = np.random.default_rng(seed)
    x = [rng.standard_normal((N, 1)) for _ in range(3)]
    al = Aligner(capacity=F * (N // F), ratio=F, reorder_blocks=10_000)
    for s in range(3):
        cuts = sorted(
            set(data.draw(st.lists(st.integers(1, N - 1), max_size=12), label=f"cuts{s}"))
        )
        edges = [0, *cuts, N]
        blocks = [Block(a, x[s][a:b]) for a, b in zip(edges[:-1], edges[1:], strict=False)]
        for i in data.draw(st.permutations(range(len(blocks))), label=f"order{s}"):
            al.push(s, blocks[i])
    w = al.window()
    assert w is not None and w.first == 0 and w.n_samples == F * (N // F)
    for s, got in enumerate((w.r, w.u, w.y)):
        np.testing.assert_array_equal(got, x[s][: w.n_samples])
