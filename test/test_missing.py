# SPDX-License-Identifier: Apache-2.0
"""Missing samples of u and y as unknowns of the lifted local fit.

Tolerances: the conjugate-gradient solver equals a brute-force least squares (every
window's regression stacked, its local coefficients and the missing samples as columns)
to 1e-10 relative; noise-free, the missing samples come out as the dropped ones up to
the local polynomial's bias (relative 1e-6 in the middle of a 200 s record, worse near
its ends where a hole looks like the transient), and every LPM method's plant is exact to
1e-8 (median relative, 600 s, 1 % missing in bursts of up to 5: 2e-9 to 6e-9 measured;
without holes 5e-11 to 3e-9, test_structured.py; at 200 s the θ̂'s bias floor is about
3e-8); a complete record takes none of the new path.
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.errors import DataError
from mr_ident.numerics import identify as identify_module
from mr_ident.numerics.identify import identify
from mr_ident.numerics.lifted.missing import estimate_missing, longest_burst
from mr_ident.numerics.lifting import dft
from mr_ident.numerics.local.fit import local_fit, missing_factor
from mr_ident.numerics.systems.simulate import simulate


def drop(n_samples, share, rng, burst=5, margin=0):
    """A mask of dropped samples: separate bursts of 1..burst at random up to ``share``."""
    mask = np.zeros(n_samples, bool)
    while mask.mean() < share:
        start = rng.integers(margin + 1, n_samples - margin - burst - 1)
        stop = start + rng.integers(1, burst + 1)
        if not mask[start - 1 : stop + 1].any():
            mask[start:stop] = True
    return mask


def with_holes(sim, mask, signals="uy"):
    u, y = sim.u.copy(), sim.y.copy()
    if "u" in signals:
        u[mask] = np.nan
    if "y" in signals:
        y[mask] = np.nan
    return u, y


def median_rel(P, truth):
    return float(np.median(np.abs(P - truth).max(axis=(1, 2)) / np.abs(truth).max(axis=(1, 2))))


@pytest.mark.parametrize("method", ["freq-lifted", "structured", "time-lifted", "lpm"])
def test_noise_free_with_holes_every_lpm_method_gives_the_exact_plant(paper_model, method):
    model = paper_model if method != "lpm" else replace(paper_model, ratio=1)
    sim = simulate(model, duration=600.0, rng=np.random.default_rng(1))
    mask = drop(sim.n_samples, 0.01, np.random.default_rng(2))
    u, y = with_holes(sim, mask)
    res = identify(sim.r, u, y, fs_high=240.0, ratio=model.ratio, method=method, n=8)
    truth = model.plant_frf(sim.n_samples)[1:]
    assert median_rel(res.plant.response, truth) < 1e-8
    assert res.n_missing.tolist() == [int(mask.sum())] * 2
    assert longest_burst(np.flatnonzero(mask)) <= 5


@pytest.mark.parametrize("signals", ["y", "u", "uy"])
def test_noise_free_the_estimates_are_the_dropped_samples(paper_model, signals):
    sim = simulate(paper_model, duration=200.0, rng=np.random.default_rng(3))
    N = sim.n_samples
    mask = drop(N, 0.01, np.random.default_rng(4), margin=N // 50)
    u, y = with_holes(sim, mask, signals)
    fill = estimate_missing(sim.r, u, y, 3, 8, 2)
    for name, got, true in (("y", fill.y, sim.y), ("u", fill.u, sim.u)):
        if name in signals:
            err = np.abs(got[mask, 0] - true[mask, 0]) / np.std(true)
            assert np.median(err) < 1e-6 and err.max() < 1e-4, name
        else:
            np.testing.assert_array_equal(got, true)


def brute_force_theta(r, u, y, F, n, R):
    """min over θ and every window's local coefficients, one dense least squares.

    Every centre bin k = 0..M//2 of the lifted fit r -> [y; u] (the criterion with stride
    1): per alias l and column c of [y; u] the window's 2n+1 bins are
    ``Y0 + D θ = K β_{k,l,c} + e`` with K the lifted R times (x^s) and the transient x^s;
    the real and imaginary parts of all of them stacked, β (complex) and θ (real) as
    columns.
    """
    N = r.shape[0]
    M = N // F
    yu = np.concatenate([y, u], axis=1)
    mask = np.isnan(yu)
    Rf, X0 = dft(r)[:, 0], dft(np.where(mask, 0.0, yu))
    holes = [(m, c) for m, c in zip(*np.nonzero(mask), strict=True)]
    x = np.arange(-n, n + 1) / n
    rows, rhs, blocks = [], [], []
    for k in range(M // 2 + 1):
        kappa = ((k + np.arange(-n, n + 1))[:, None] + M * np.arange(F)[None, :]) % N
        Rl = Rf[kappa]  # (2n+1, F)
        K = np.concatenate([Rl * (x**s)[:, None] for s in range(R + 1)], axis=1)
        K = np.concatenate([K] + [(x**s)[:, None] + 0j for s in range(R + 1)], axis=1)
        for c in range(yu.shape[1]):
            for a in range(F):
                kap = kappa[:, a]
                D = np.zeros((2 * n + 1, len(holes)), complex)
                for j, (m, ch) in enumerate(holes):
                    if ch == c:
                        D[:, j] = np.exp(-2j * np.pi * kap * m / N) / np.sqrt(N)
                rows.append(D)
                rhs.append(-X0[kap, c])
                blocks.append(K)
    nb, q = len(blocks), blocks[0].shape[1]
    L = 2 * n + 1
    A = np.zeros((2 * nb * L, 2 * nb * q + len(holes)))
    b = np.zeros(2 * nb * L)
    for i, (D, K, y0) in enumerate(zip(rows, blocks, rhs, strict=True)):
        re, im = slice(2 * i * L, (2 * i + 1) * L), slice((2 * i + 1) * L, (2 * i + 2) * L)
        cr, ci = slice(2 * i * q, (2 * i + 1) * q), slice((2 * i + 1) * q, (2 * i + 2) * q)
        # D θ - K β = -Y0, β = βr + j βi
        A[re, cr], A[re, ci], A[im, cr], A[im, ci] = -K.real, K.imag, -K.imag, -K.real
        A[re, 2 * nb * q :], A[im, 2 * nb * q :] = D.real, D.imag
        b[re], b[im] = y0.real, y0.imag
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    return holes, sol[2 * nb * q :]


def test_the_fast_solver_equals_the_stacked_least_squares(paper_model):
    model = replace(paper_model, noise_std=1e-5)
    sim = simulate(model, n_samples=3 * 27, rng=np.random.default_rng(5))  # N odd
    mask_y = np.zeros(sim.n_samples, bool)
    mask_y[[17, 18, 19, 50, 70]] = True
    mask_u = np.zeros(sim.n_samples, bool)
    mask_u[[40, 41, 65]] = True
    u, y = sim.u.copy(), sim.y.copy()
    y[mask_y], u[mask_u] = np.nan, np.nan
    holes, theta = brute_force_theta(sim.r, u, y, 3, 6, 1)  # q = 13 - 2 * 4 = 5 > 3
    fill = estimate_missing(sim.r, u, y, 3, 6, 1, rtol=1e-14, stride=1, reweight=False, ftol=0)
    yu = np.concatenate([fill.y, fill.u], axis=1)
    got = np.array([yu[m, c] for m, c in holes])
    np.testing.assert_allclose(got, theta, rtol=1e-10, atol=1e-10 * np.abs(theta).max())


def test_a_complete_record_takes_none_of_the_new_path(paper_model, monkeypatch):
    model = replace(paper_model, noise_std=1e-4)
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(6))
    before = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, method="structured")

    def refuse(*args, **kwargs):
        raise AssertionError("estimate_missing called on a complete record")

    monkeypatch.setattr(identify_module, "estimate_missing", refuse)
    for method in ("freq-lifted", "structured", "time-lifted", "lpm"):
        res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, method=method)
        assert res.n_missing.tolist() == [0, 0]
    after = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, method="structured")
    np.testing.assert_array_equal(after.plant.response, before.plant.response)
    np.testing.assert_array_equal(after.plant.std, before.plant.std)
    # a zero share scales the noise covariance by exactly 1
    rng = np.random.default_rng(7)
    U = rng.standard_normal((64, 1)) + 1j * rng.standard_normal((64, 1))
    Y = 2 * U + 0.1 * (rng.standard_normal((64, 2)) + 1j * rng.standard_normal((64, 2)))
    plain = local_fit("polynomial", U, Y, 8, 2)
    zero = local_fit("polynomial", U, Y, 8, 2, missing=np.zeros(2))
    np.testing.assert_array_equal(plain.noise_cov, zero.noise_cov)
    assert missing_factor(np.zeros(1), 8, 11)[0] == 1.0


def test_nan_in_r_is_recovered_inf_and_too_many_missing_samples_are_clear_errors(paper_model):
    sim = simulate(paper_model, duration=60.0, rng=np.random.default_rng(8))
    r = sim.r.copy()
    r[10] = np.nan  # u - r is held: r is recovered (test_lost_r.py)
    assert identify(r, sim.u, sim.y, fs_high=240.0, ratio=3).r_recovered == 1
    y = sim.y.copy()
    y[10] = np.inf
    with pytest.raises(DataError, match="inf"):
        identify(sim.r, sim.u, y, fs_high=240.0, ratio=3)
    u, y = with_holes(sim, drop(sim.n_samples, 0.15, np.random.default_rng(9)))
    with pytest.raises(DataError, match="y channel 0 misses .* % of its|y channel 0 misses"):
        identify(sim.r, u, y, fs_high=240.0, ratio=3, n=8)


def test_the_rational_local_model_fits_the_filled_record(paper_model):
    sim = simulate(paper_model, duration=600.0, rng=np.random.default_rng(10))
    u, y = with_holes(sim, drop(sim.n_samples, 0.01, np.random.default_rng(11)))
    res = identify(sim.r, u, y, fs_high=240.0, ratio=3, n=None, local="rational")
    full = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, n=None, local="rational")
    truth = paper_model.plant_frf(sim.n_samples)[1:]
    assert median_rel(full.plant.response, truth) < 1e-8
    assert median_rel(res.plant.response, truth) < 1e-8


@pytest.mark.parametrize("suffix", ["npz", "csv"])
def test_a_data_file_with_holes_is_identified_whole(tmp_path, capsys, paper_model, suffix):
    from mr_ident.cli import main
    from mr_ident.io.datafile import read_data, read_identification, write_data

    sim = simulate(paper_model, duration=30.0, rng=np.random.default_rng(12))
    mask = drop(sim.n_samples, 0.01, np.random.default_rng(13))
    mask[1:3] = False
    u, y = with_holes(sim, mask)
    y[1] = np.nan  # y[1] alone: rows 0, 2 given, yet a high-rate y (rows 2, 3 are adjacent)
    path = tmp_path / f"d.{suffix}"
    write_data(path, sim.r, u, y, fs_high=240.0, ratio=3)
    data = read_data(path)
    assert data.y.shape == y.shape and np.isnan(data.y).sum() == np.isnan(y).sum()
    res = tmp_path / "res.npz"
    code = main(["identify", str(path), "--ratio", "3", "--out", str(res)])
    out, err = capsys.readouterr()
    assert code == 0, err
    n_y, n_u = int(np.isnan(y).sum()), int(mask.sum())
    assert f"note: {n_y} samples of y and {n_u} of u missing (NaN) of 7200" in out
    assert read_identification(res).n_missing.tolist() == [n_y, n_u]
    if suffix == "csv":  # an empty cell of u is a missing sample too; inf is refused
        lines = path.read_text().splitlines()
        cells = lines[5].split(",")
        lines[5] = ",".join(cells[:2] + [""] + cells[3:])
        path.write_text("\n".join(lines) + "\n")
        assert np.isnan(read_data(path).u[4, 0])
        cells[2] = "inf"
        lines[5] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(DataError, match="line 6, column 'u': inf"):
            read_data(path)


def test_diagnose_takes_a_record_with_holes_within_the_limits(paper_model):
    from mr_ident.diagnosis.diagnose import check_record
    from mr_ident.numerics.signals import LoopData

    sim = simulate(paper_model, duration=30.0, rng=np.random.default_rng(14))
    u, y = with_holes(sim, drop(sim.n_samples, 0.01, np.random.default_rng(15)))
    check_record(paper_model, LoopData(sim.r, u, y, 240.0, 3), what="d.npz")
    u, y = with_holes(sim, drop(sim.n_samples, 0.2, np.random.default_rng(15)))
    with pytest.raises(DataError, match=r"d.npz: too many missing samples for diagnose \(20 %"):
        check_record(paper_model, LoopData(sim.r, u, y, 240.0, 3), what="d.npz")
