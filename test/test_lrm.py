# SPDX-License-Identifier: Apache-2.0
"""The local rational method (numerics/local/lrm.py) against a per-window brute force and exact
models.

Tolerances:
* batched = a per-window complex ``lstsq`` of the joint problem (all outputs, one
  denominator; Levy then one Sanathanan-Koerner step) to 1e-8 relative (normal
  equations, error about eps cond^2);
* an FRF and transient that are exactly rational of order 2 in the bin: every window
  reproduces them to 1e-6 (measured 4e-7 in the windows by the pole half a bin off the
  axis, where the weight 1/D spans decades: normal equations, eps cond^2);
* lightly damped modes drawn at random (damping U(0.001, 0.003), 11 bins across the
  half-power band 2 zeta f_n): noise-free, the worst relative error in f_n (1 +- 2 zeta)
  is < 10 % for rational where polynomial's is > 10 % (measured: open loop 1e-8 to 3e-7
  against 0.10-0.13; the paper's loop with a mode at 35.8 Hz, freq-lifted 3e-5 and
  time-lifted 8e-5 against 0.12 and 0.16, structured 0.008 against 0.18); away from the
  mode rational is no worse than 10x polynomial and < 1e-4 (1e-3 structured). ``lpm`` is
  not held to it in the loop: its aliases act as noise in the denominator's regressors
  (0.43 there, worse than polynomial's 0.18; docs/method.md);
* the reported std: spread over 40 fresh-noise runs / reported std in [0.8, 1.25] near
  the mode and away from it (a 100-run development check: 1.00 and 1.02; without the
  denominator's term 1.17 and 1.13).
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.errors import ConfigError
from mr_ident.io.config import IdentConfig
from mr_ident.io.modelfile import model_from_dict
from mr_ident.numerics.identify import identify
from mr_ident.numerics.lifting import dft
from mr_ident.numerics.local.fit import local_fit
from mr_ident.numerics.local.lrm import SK_ITERATIONS, dof, lrm_bins_last
from mr_ident.numerics.systems.simulate import loop_poles, simulate

BINS_ACROSS = 11  # bins across the half-power band


def brute_force_lrm(U, Y, n, R):
    """G_0 at the centre of one window (2n+1, n_in), (2n+1, n_out), straight from the model."""
    L, ni = U.shape
    no = Y.shape[1]
    x = np.arange(-n, n + 1) / n
    K = np.concatenate(
        [U * (x**s)[:, None] for s in range(R + 1)] + [(x**s)[:, None] + 0j for s in range(R + 1)],
        axis=1,
    )
    p = K.shape[1]
    w = np.ones(L, complex)
    for _ in range(1 + SK_ITERATIONS):
        X = np.zeros((no * L, no * p + R), complex)
        for o in range(no):
            X[o * L : (o + 1) * L, o * p : (o + 1) * p] = K * w[:, None]
            X[o * L : (o + 1) * L, no * p :] = -(Y[:, o] * w)[:, None] * x[:, None] ** np.arange(
                1, R + 1
            )
        th, *_ = np.linalg.lstsq(X, (Y * w[:, None]).T.ravel(), rcond=None)
        w = 1.0 / (1.0 + x[:, None] ** np.arange(1, R + 1) @ th[no * p :])
    return np.stack([th[o * p : o * p + ni] for o in range(no)])


@pytest.mark.parametrize(("ni", "no"), [(1, 1), (1, 2), (2, 3)])
def test_the_batched_lrm_equals_a_per_window_least_squares_loop(ni, no):
    rng = np.random.default_rng(ni + 10 * no)
    n, R, K = 8, 2, 24
    U = rng.standard_normal((K + 2 * n, ni)) + 1j * rng.standard_normal((K + 2 * n, ni))
    k = np.arange(K + 2 * n)[:, None, None]
    G = rng.standard_normal((no, ni)) / (1.0 + 0.3j * (k - 20.0) / (2.0 + 0.5j))  # a pole
    Y = np.einsum("koi,ki->ko", G, U) + 0.05 * rng.standard_normal((K + 2 * n, no))
    Gb, _, _, n_bad, _ = lrm_bins_last(U, Y, n, R, dof(n, R, ni, no))
    assert n_bad == 0
    for j in range(K):
        ref = brute_force_lrm(U[j : j + 2 * n + 1], Y[j : j + 2 * n + 1], n, R)
        np.testing.assert_allclose(Gb[:, :, j], ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())


def test_an_exactly_rational_frf_and_transient_are_recovered():
    """G(k) = N(k)/D(k), T(k) = M(k)/D(k), all of order 2 with random complex coefficients,
    a 2x2 system, D with a root half a bin off the axis: every window is exact."""
    rng = np.random.default_rng(3)
    n, K = 8, 60
    k = np.arange(K + 2 * n) - 30.0
    pole = 0.5j
    D = (k - pole) * (k - 40.0 - 3j)
    Nk = sum(rng.standard_normal((2, 2, 1)) * k**s for s in range(3))
    Mk = sum(rng.standard_normal((2, 1)) * k**s for s in range(3))
    U = rng.standard_normal((K + 2 * n, 2)) + 1j * rng.standard_normal((K + 2 * n, 2))
    G = Nk / D
    Y = np.einsum("oik,ki->ko", G, U) + (Mk / D).T
    fit = local_fit("rational", U, Y, n, 2)
    np.testing.assert_allclose(fit.G, G[:, :, n:-n], rtol=1e-6, atol=0)
    poly = local_fit("polynomial", U, Y, n, 2)
    assert np.abs(poly.G - G[:, :, n:-n]).max() > 1e3 * np.abs(fit.G - G[:, :, n:-n]).max()


def _mode(rng):
    """A damping in U(0.001, 0.003) and the record length giving BINS_ACROSS bins across."""
    zeta = float(rng.uniform(0.001, 0.003))
    return zeta


def _near(freq, fn, zeta):
    return np.abs(freq - fn) <= 2 * zeta * fn


def _open_loop(rng, noise_std=0.0):
    """A first-order plant plus a lightly damped mode at a random frequency, open loop, F = 1."""
    zeta, T = _mode(rng), 60.0
    fn = BINS_ACROSS / (T * 2 * zeta) * rng.uniform(0.97, 1.03)
    fs = 4.0 * fn * rng.uniform(1.0, 1.5)
    model = model_from_dict(
        {
            "fs_high": fs,
            "ratio": 1,
            "plant": {"num": [fs / 5], "den": [1.0, fs / 5]},
            "additive_modes": [
                {"frequency_hz": fn, "damping": zeta, "gain": float(rng.uniform(0.02, 0.1))}
            ],
            "noise_std": noise_std,
        }
    )
    return model, T, fn, zeta


def _errors(res, truth, fn, zeta):
    e = (np.abs(res.plant.response - truth) / np.abs(truth)).max(axis=(1, 2))
    near = _near(res.plant.frequency, fn, zeta)
    return e[near].max(), np.median(e[~near])


def test_random_lightly_damped_modes_open_loop_rational_within_10_percent():
    rng = np.random.default_rng(20)
    for _ in range(3):
        model, T, fn, zeta = _open_loop(rng)
        sim = simulate(model, duration=T, rng=rng)
        truth = model.plant_frf(sim.n_samples)[1:]
        e = {}
        for local in ("polynomial", "rational"):
            res = identify(sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=1, method="lpm",
                           local=local, n=8)  # fmt: skip
            e[local] = _errors(res, truth, fn, zeta)
        assert e["rational"][0] < 0.1 < e["polynomial"][0], (fn, zeta, e)
        assert e["rational"][1] < 1e-6, e


def test_random_lightly_damped_modes_in_the_multirate_loop_rational_within_10_percent(
    paper_model,
):
    """The paper's loop (F = 3) with a mode added to its plant at a random frequency."""
    rng = np.random.default_rng(21)
    zeta, T = _mode(rng), 60.0
    fn = BINS_ACROSS / (T * 2 * zeta)
    truth0 = paper_model.plant_frf(int(T * 240))[int(round(fn * T))]
    gain = 1.5 * abs(truth0[0, 0]) * 2 * zeta  # the peak 1.5 x the plant without it
    model = replace(paper_model, additive_modes=((fn, zeta, gain, 0, 0),))
    assert np.abs(loop_poles(model)).max() < 1.0
    sim = simulate(model, duration=T, rng=rng)
    truth = model.plant_frf(sim.n_samples)[1:]
    for method, far in (("freq-lifted", 1e-4), ("time-lifted", 1e-4), ("structured", 1e-3)):
        e = {}
        for local in ("polynomial", "rational"):
            res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, method=method,
                           local=local, n=8)  # fmt: skip
            e[local] = _errors(res, truth, fn, zeta)
        assert e["rational"][0] < 0.1 < e["polynomial"][0], (method, fn, zeta, e)
        assert e["rational"][1] < max(far, 10 * e["polynomial"][1]), (method, e)


def test_the_reported_std_matches_the_spread_near_the_mode_and_away():
    """40 runs, one excitation, fresh noise (about 40 dB SNR), rational LRM on the spectra."""
    rng = np.random.default_rng(22)
    model, T, fn, zeta = _open_loop(rng, noise_std=0.0)
    N = int(round(T * model.fs_high))
    r = rng.standard_normal((N, 1))
    y0 = simulate(model, reference=r, rng=rng).y
    model = replace(model, noise_std=0.01 * float(np.std(y0)))
    n, R = 8, 2
    k0 = int(round(fn * T))
    idx = np.arange(k0 - 150 - n, k0 + 150 + n + 1)  # 301 bins around the mode
    est, var = [], []
    for _ in range(40):
        sim = simulate(model, reference=r, rng=rng)
        fit = local_fit("rational", dft(sim.u)[idx], dft(sim.y)[idx], n, R)
        est.append(fit.G[0, 0])
        g = fit.den.gain[0, 0]
        var.append(
            fit.noise_cov[0, 0].real * fit.inv_gram[0, 0].real
            + np.einsum("tk,tsk,sk->k", g, fit.den.cov, np.conj(g)).real
        )
    emp = np.var(np.array(est), axis=0, ddof=1)
    rep = np.mean(var, axis=0)
    near = _near(idx[n:-n] / T, fn, zeta)
    for sel in (near, ~near):
        ratio = np.sqrt(np.median(emp[sel] / rep[sel]))
        assert 0.8 < ratio < 1.25, ratio


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n": 3}, r"local rational degrees of freedom.*n=3.*denominator order R_d=2.*n >= 8"),
        ({"degree": 0}, "local rational needs degree R >= 1"),
        ({"method": "etfe"}, "applies to the LPM methods"),
        ({"local": "spline"}, "local must be one of polynomial, rational; got 'spline'"),
    ],
)
def test_orders_the_window_cannot_support_are_named(paper_model, kwargs, match):
    sim = simulate(paper_model, duration=20.0, rng=np.random.default_rng(0))
    opts = {"local": "rational", **kwargs}
    with pytest.raises(ConfigError, match=match):
        identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, **opts)


def test_config_and_result_carry_the_local_model(tmp_path, paper_model):
    from mr_ident.io.datafile import write_result

    assert IdentConfig().local == "polynomial"
    assert IdentConfig(local="rational").lpm_n(1, 1) == 9  # the denominator's dof
    with pytest.raises(ConfigError, match="local must be one of"):
        IdentConfig(local="spline")
    with pytest.raises(ConfigError, match="n >= 8"):
        IdentConfig(local="rational", n=4)
    sim = simulate(paper_model, duration=20.0, rng=np.random.default_rng(0))
    res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, local="rational", n=9)
    assert res.local == "rational"
    write_result(tmp_path / "r.npz", res)
    assert str(np.load(tmp_path / "r.npz")["local"]) == "rational"


def test_the_command_line_names_an_unsupported_order(tmp_path, paper_model):
    import subprocess
    import sys

    from mr_ident.io.datafile import write_data

    sim = simulate(paper_model, duration=20.0, rng=np.random.default_rng(0))
    data = tmp_path / "d.npz"
    write_data(data, sim.r, sim.u, sim.y, fs_high=240.0, ratio=3)
    cmd = [sys.executable, "-m", "mr_ident.cli", "identify", str(data), "--out",
           str(tmp_path / "o.npz")]  # fmt: skip
    bad = subprocess.run(cmd + ["--local", "rational", "--n", "5"], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.startswith("error: local rational degrees")
    assert "Traceback" not in bad.stderr and not (tmp_path / "o.npz").exists()
    ok = subprocess.run(cmd + ["--local", "rational"], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
