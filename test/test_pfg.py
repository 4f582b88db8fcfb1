# SPDX-License-Identifier: Apache-2.0
"""PFG against a brute-force single-sine simulation of the loop (within 1 %)."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import brute_force_loop

from mr_ident.numerics.identify import identify
from mr_ident.numerics.lifted.pfg import pfg_from_lifted, pfg_from_plant
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.simulate import loop_poles, simulate


@pytest.mark.parametrize("phase,delay,gain", [(0, 0, 6000.0), (1, 1, 2000.0), (2, 2, 2000.0)])
def test_pfg_from_the_true_plant_equals_a_single_sine_simulation(paper_model, phase, delay, gain):
    # A computation delay costs phase margin: the delayed cases use a gentler controller.
    K = TransferMatrix.siso([gain, -0.9 * gain], [1.0, -0.3], 3 / 240.0)
    model = replace(paper_model, controller=K, sample_phase=phase, control_delay=delay)
    assert np.max(np.abs(loop_poles(model))) < 0.9  # steady state within 11 periods
    F, N = 3, 240
    M = N // F
    g = pfg_from_plant(
        model.plant_frf(N), model.controller_frf(M), F, N, phase=phase, delay=delay
    ).gain
    periods = 12  # the first 11 let the transient die out
    for kappa in (7, 23, 50, 101):
        assert (2 * kappa) % M  # the +w and -w aliases stay apart
        n = np.arange(periods * N)
        r = np.cos(2 * np.pi * kappa * n / N)[:, None]
        _, y = brute_force_loop(model, r)
        Y = np.fft.fft(y[-N:, 0]) / np.sqrt(N)
        R = np.sqrt(N) / 2  # DFT of the e^{+jwn} half of the cosine
        aliases = (kappa + M * np.arange(F)) % N
        brute = np.linalg.norm(Y[aliases]) / R
        assert abs(g[kappa] - brute) < 0.01 * brute, (kappa, g[kappa], brute)


def test_pfg_from_the_identified_lifted_map_equals_the_true_pfg(paper_model):
    sim = simulate(paper_model, duration=200.0, rng=np.random.default_rng(4))
    N = sim.r.shape[0]
    res = identify(
        sim.r,
        sim.u,
        sim.y,
        fs_high=240.0,
        ratio=3,
        controller_low=paper_model.controller_frf(N // 3),
    )
    g = pfg_from_plant(paper_model.plant_frf(N), paper_model.controller_frf(N // 3), 3, N).gain
    assert res.lifted_J is not None and res.pfg is not None
    direct = pfg_from_lifted(
        res.lifted_J.response,
        res.lifted_J.bins,
        3,
        N,
        row_cov=res.lifted_J.row_cov,
        col_cov=res.lifted_J.col_cov,
    )
    kappa, gain, std = np.rint(direct.frequency * N).astype(int), direct.gain, direct.std
    # Noise-free, 200 s: the LPM error is ~2e-6 of the largest gain at worst; small gains far
    # below the peak are therefore checked against the peak.
    for est, ref in ((gain, g[kappa]), (res.pfg.gain, g[1:])):
        assert np.median(np.abs(est - ref) / ref) < 1e-6
        assert np.max(np.abs(est - ref)) < 1e-5 * ref.max()
    assert np.all(np.isfinite(std)) and np.all(np.isfinite(res.pfg.std))


def test_pfg_std_follows_the_noise(paper_model):
    model = replace(paper_model, noise_std=2e-5)
    rng = np.random.default_rng(8)
    r = rng.standard_normal((6000, 1))
    K = model.controller_frf(2000)
    runs, stds = [], []
    for _ in range(40):
        sim = simulate(model, reference=r, rng=rng)
        res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, controller_low=K)
        runs.append(res.pfg.gain)
        stds.append(res.pfg.std)
    emp = np.std(runs, axis=0, ddof=1)
    rep = np.sqrt(np.mean(np.square(stds), axis=0))
    assert 0.75 < np.median(emp / rep) < 1.25


def test_the_dense_closed_loop_maps_agree_with_the_structured_pfg(paper_model):
    from mr_ident.numerics.lifted.loop import closed_loop_maps
    from mr_ident.numerics.lifting import half_to_full

    F, N = 3, 300
    M = N // F
    P_half = paper_model.plant_frf(N)
    K = paper_model.controller_frf(M)
    g = pfg_from_plant(P_half, K, F, N, phase=1, delay=1).gain
    ks = np.arange(M)
    J, S = closed_loop_maps(half_to_full(P_half, N), K, ks, F, phase=1, delay=1)
    kappa = np.arange(N // 2 + 1)
    dense = np.linalg.norm(J[kappa % M][np.arange(kappa.size), :, kappa // M], axis=1)
    np.testing.assert_allclose(g, dense, rtol=1e-10)


@pytest.mark.parametrize("F,N", [(2, 18), (3, 21), (4, 24), (5, 35)])
def test_the_aliases_read_from_the_half_spectrum_are_the_whole_spectrum_ones_in_c_order(F, N):
    from mr_ident.numerics.lifted.pfg import _aliases
    from mr_ident.numerics.lifting import half_to_full

    rng = np.random.default_rng(F)
    P = rng.standard_normal((N // 2 + 1, 2, 3)) + 1j * rng.standard_normal((N // 2 + 1, 2, 3))
    kappa = np.arange(2, N // 2 + 1)
    for X in (P, np.abs(P)):  # a std is real: mirrored, not conjugated
        whole = half_to_full(X, N)
        want = np.stack([whole[(kappa + j * (N // F)) % N] for j in range(F)], axis=1)
        got = _aliases(X, kappa, F, N)  # (K, F, n_y, n_u)
        np.testing.assert_array_equal(got, want)
        # C order, as the sums over the aliases expect (a moved-axis view sums differently)
        assert got.flags.c_contiguous
        np.testing.assert_array_equal(
            _aliases(X[:, 0, 0], kappa, F, N, axis=0), want[:, :, 0, 0].T
        )
