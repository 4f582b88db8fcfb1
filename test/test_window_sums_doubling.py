# SPDX-License-Identifier: Apache-2.0
"""The moment sums by doubling (and directly) equal the windows' direct sums to round-off.

Reference: a plain einsum over each window in extended precision (``clongdouble``), so the
comparison sees the route's own rounding. The tolerance is relative to the window's scale
``sum_r |Z| * sum_p |coef[q, p]|`` (the kernel's size in monomial form, at least its largest
weight), per window: the signals span 4 decades along the bins, as spectra do, so a scale
of the whole array would hide a lost term in a quiet stretch. The doubling's merges and its
assembly have coefficient rows whose absolute values sum to (about) 1, so each of its
``log2(2n+1) + 1`` steps adds a few ulps of that scale; the Toeplitz and direct routes'
BLAS dot products over 2n+1 terms stay within a few ulps here too. Observed at most
3.3e-16 (doubling), 4.5e-16 (direct), 9.1e-16 (Toeplitz); 1e-14 leaves a margin of 10 to 30
and still catches a lost or wrong binomial term (orders of magnitude above round-off).
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.numerics.identify import identify
from mr_ident.numerics.local import window_sums as ws
from mr_ident.numerics.local.strided import offsets_for
from mr_ident.numerics.systems.simulate import simulate

RTOL = 1e-14
ROUTES = {"toeplitz": ws._toeplitz_sums, "doubling": ws.doubling_sums, "direct": ws._direct_sums}


def direct_reference(Z, w, n, stride, K):
    """``S[q, c, k] = sum_r w[q, r] Z[c, s k + n + r]`` (missing bins zero), and its scale."""
    L = 2 * n + 1
    Zp = np.zeros((Z.shape[0], stride * (K - 1) + L), dtype=np.clongdouble)
    m = min(Z.shape[1], Zp.shape[1])
    Zp[:, :m] = Z[:, :m]
    win = np.lib.stride_tricks.sliding_window_view(Zp, L, axis=1)[:, ::stride][:, :K]
    ref = np.einsum("qr,ckr->qck", w.astype(np.longdouble), win)
    return ref, np.abs(win).sum(axis=2).astype(float)


def signal(rng, C, width, complex_):
    """Z with magnitudes over 4 decades along the bins (spectra are not flat)."""
    Z = rng.standard_normal((C, width))
    if complex_:
        Z = Z + 1j * rng.standard_normal((C, width))
    return (Z * np.exp(rng.uniform(-4.6, 4.6, width))).astype(np.complex128)


def assert_round_off(out, ref, size, kernel):
    coef_size = np.abs(kernel.coef).sum(axis=1)  # (n_q,)
    scale = coef_size[:, None, None] * size[None, :, :]
    err = np.abs(out - ref.astype(np.complex128))
    assert err.shape == scale.shape
    assert np.all(err <= RTOL * scale), float((err / scale).max())


@pytest.mark.parametrize("n", [8, 27, 93, 210])
@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("complex_", [True, False])
def test_every_route_equals_the_direct_sum_of_every_kernel(n, degree, complex_):
    rng = np.random.default_rng(n + 10 * degree)
    h = offsets_for(n)
    for stride in sorted({1, 2 * h + 1, 2 * n + 1}):
        kernels = ws.kernels(n, degree, stride)[1:] + (ws.plain(n, stride),)
        for kernel in kernels:
            # weights and monomial form agree: w[q, r] = sum_p coef[q, p] (r/n)^p
            x = np.arange(-n, n + 1) / n
            V = x[None, :] ** np.arange(kernel.coef.shape[1])[:, None]
            np.testing.assert_allclose(kernel.coef @ V, kernel.w, rtol=0, atol=1e-13)
            K, C = 37, 2
            Z = signal(rng, C, stride * (K - 1) + 2 * n + 1, complex_)
            ref, size = direct_reference(Z, kernel.w, n, stride, K)
            for name, f in ROUTES.items():
                if name == "direct" and stride < 2 * n + 1:
                    continue  # only for windows that do not overlap
                assert_round_off(f(Z, kernel, K), ref, size, kernel)


@pytest.mark.parametrize("n", [8, 93])
def test_windows_past_the_end_count_the_missing_bins_as_zeros(n):
    rng = np.random.default_rng(3)
    for stride in (1, 2 * n + 1):
        kernel = ws.kernels(n, 2, stride)[2]
        K = 40
        Z = signal(rng, 3, stride * (K - 1) + 2 * n + 1 - n - 5, True)  # n + 5 bins short
        ref, size = direct_reference(Z, kernel.w, n, stride, K)
        for name, f in ROUTES.items():
            if name == "direct" and stride < 2 * n + 1:
                continue
            assert_round_off(f(Z, kernel, K), ref, size, kernel)


def test_a_long_record_keeps_round_off_relative_to_its_window_at_high_bins():
    """No drift along the bins: the last windows of 1e5 bins are as exact as the first."""
    rng = np.random.default_rng(4)
    n, K = 210, 100_000
    kernel = ws.kernels(n, 2)[1]
    Z = signal(rng, 1, K + 2 * n, True)
    out = ws.doubling_sums(Z, kernel, K)
    for k0 in (0, K - 50):
        ref, size = direct_reference(Z[:, k0 : k0 + 50 + 2 * n], kernel.w, n, 1, 50)
        assert_round_off(out[:, :, k0 : k0 + 50], ref, size, kernel)


def test_the_cost_rule_takes_toeplitz_narrow_doubling_wide_and_direct_apart():
    assert ws.route(ws.kernels(8, 2)[1], 4096) == "toeplitz"
    assert ws.route(ws.kernels(27, 2)[2], 4096) == "toeplitz"
    for n in (210, 710):
        assert all(ws.route(k, 4096) == "doubling" for k in ws.kernels(n, 2)[1:])
        assert ws.route(ws.kernels(n, 2, 2 * n + 1)[2], 512) == "direct"
        h = offsets_for(n)
        assert ws.route(ws.kernels(n, 2, 2 * h + 1)[2], 4096) == "toeplitz"


@pytest.fixture(scope="module")
def setpoint_record(paper_model):
    model = replace(paper_model, injection="setpoint", noise_std=0.02)
    N = 144_000  # 600 s: the automatic window's candidates reach n = 210
    return simulate(model, n_samples=N, rng=np.random.default_rng(7)), paper_model


#: Routes forced throughout identify(): the Toeplitz route alone (as before the doubling),
#: and the doubling wherever the stride is 1 (even for narrow windows).
RULE = ws.route
FORCED = {
    "toeplitz": lambda kernel, K: "toeplitz",
    "doubling": lambda kernel, K: "doubling" if kernel.stride == 1 else RULE(kernel, K),
}


@pytest.mark.parametrize("forced", sorted(FORCED))
def test_identify_of_a_setpoint_record_equals_the_other_routes_to_round_off(
    setpoint_record, monkeypatch, forced
):
    sim, model = setpoint_record

    def run():
        return identify(sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio,
                        injection="setpoint")  # fmt: skip

    new = run()
    assert new.n_used.max() >= 140  # the doubling route ran (n >= 93)
    monkeypatch.setattr(ws, "route", FORCED[forced])
    old = run()
    np.testing.assert_array_equal(new.n_used, old.n_used)
    P, Po = new.plant.response, old.plant.response
    ok = np.isfinite(Po)
    np.testing.assert_array_equal(np.isfinite(P), ok)
    # round-off of the sums through the solve (cond of the scaled regressor squared),
    # relative to the estimate's own std per bin (observed 1e-11): far below any noise
    assert np.all(np.abs(P - Po)[ok] <= 1e-9 * old.plant.std[ok])
    np.testing.assert_allclose(new.plant.std[ok], old.plant.std[ok], rtol=1e-9)
