# SPDX-License-Identifier: Apache-2.0
"""The best linear approximation with its noise and nonlinear parts
(mr_ident.numerics.excitation.bla).

Open loop: a second-order discrete plant behind a static nonlinearity (none, cubic,
square), odd-random multisines (M realizations, P periods after one dropped), output
noise. Closed multirate loop: the paper's loop (F = 3) played a lifted design, noise-free:
the BLA is P_h. Tolerances at each check.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from mr_ident.errors import ConfigError
from mr_ident.numerics.excitation.bla import best_linear_approximation, distortion_by_band
from mr_ident.numerics.excitation.multisine import design

N, M, P = 1024, 8, 4
B, A = [0.0, 0.02, 0.018], [1.0, -1.7, 0.74]  # a lightly damped second-order plant


def _plant(k):
    z = np.exp(2j * np.pi * k / N)
    return np.polyval(B[::-1], 1 / z) / np.polyval(A[::-1], 1 / z)


def _run(nl, noise=1e-3, seed=0):
    ms = design(fs_high=1.0, period=N, band=(0.01, 0.3), kind="odd-random", periods=P + 1,
                realizations=M, seed=seed)  # fmt: skip
    rng = np.random.default_rng(seed + 100)
    r = ms.r[:, :, 0]
    u = r.copy()  # open loop: u = r
    y = scipy.signal.lfilter(B, A, nl(u), axis=1) + noise * rng.standard_normal(r.shape)
    cut = slice(N, None)  # the first period is the transient
    return ms, best_linear_approximation(r[:, cut], u[:, cut], y[:, cut], N, ms.lines[0])


def test_a_linear_plant_has_no_nonlinear_part_and_its_bla_is_the_plant():
    ms, b = _run(lambda u: u)
    err = np.abs(b.response - _plant(b.lines))
    assert np.median(err / b.std) < 1.5  # the truth within its reported std
    assert np.median(b.nl_std) < 0.6 * np.median(b.noise_std)  # only noise
    assert b.odd_level[0] < 3 * b.noise_level[0] and b.even_level[0] < 3 * b.noise_level[0]
    np.testing.assert_allclose(b.std**2, b.noise_std**2 + b.nl_std**2, rtol=1e-9)


def test_a_cubic_term_shows_as_odd_nonlinear_distortion():
    ms, b = _run(lambda u: u + 0.3 * u**3)
    assert np.median(b.nl_std) > 5 * np.median(b.noise_std)
    assert b.odd_level[0] > 100 * b.noise_level[0]  # at the detection lines
    assert b.even_level[0] < 3 * b.noise_level[0]  # a cubic has no even part


def test_a_square_term_shows_as_even_distortion_only():
    ms, b = _run(lambda u: u + 0.3 * u**2)
    assert b.even_level[0] > 100 * b.noise_level[0]
    assert b.odd_level[0] < 3 * b.noise_level[0]
    # even distortion does not reach the odd excited lines: the BLA's nl part stays small
    assert np.median(b.nl_std) < 0.6 * np.median(b.noise_std)


def test_the_multirate_closed_loop_bla_is_the_plant():
    """The paper's loop (F = 3, noise-free) played a lifted odd design: y = P_h u at every
    excited line, the BLA equals P_h to 1e-8. With a little output noise no line shows
    distortion when the excited lines' lifted aliases are left out of the unexcited ones
    (ratio=3: the even lines within 3 dB of the noise; an odd design leaves no odd one);
    taken as detection lines they carry the loop's folded linear response (ratio=1: odd
    lines > 40 dB above the noise, which must not be read as nonlinear distortion of a
    linear loop)."""
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.excitation.sources import SimSource

    model = load_model("config/paper_example.yaml")
    ms = design(fs_high=240.0, period=2400, band=(0.5, 100.0), kind="odd", periods=3,
                realizations=2, ratio=3, lifted=True)  # fmt: skip
    runs = []
    for m in range(2):
        src = SimSource(model, block=2400, excitation="signal", signal=ms.r[m])
        blocks = [src.next() for _ in range(3)]
        runs.append([np.concatenate([b[i] for b in blocks])[2400:, 0] for i in (1, 2, 3)])
    r, u, y = (np.stack([run[i] for run in runs]) for i in range(3))
    b = best_linear_approximation(r, u, y, 2400, ms.lines[0])
    P = model.plant_discrete().freqresp(b.lines * 240.0 / 2400)[:, 0, 0]
    assert np.max(np.abs(b.response / P - 1)) < 1e-8
    rng = np.random.default_rng(1)
    y_noisy = y + 1e-9 * rng.standard_normal(y.shape)
    right = best_linear_approximation(r, u, y_noisy, 2400, ms.lines[0], ratio=3)
    # an odd design: no odd line is left unexcited (nan), the even ones are noise only
    assert np.isnan(right.odd_db[0]) and abs(right.even_db[0]) < 3, (right.odd_db, right.even_db)
    for band in distortion_by_band(r, y_noisy, 2400, 240.0, ratio=3):
        assert not abs(band.odd_db) >= 6 and abs(band.even_db) < 6, band  # nan or small
    wrong = best_linear_approximation(r, u, y_noisy, 2400, ms.lines[0], ratio=1)
    assert wrong.odd_db[0] > 40


def test_bad_shapes_and_too_little_data_are_refused():
    x = np.zeros((1, 2 * N))
    with pytest.raises(ConfigError, match="at least 2 periods or 2 realizations"):
        best_linear_approximation(x[:, :N], x[:, :N], x[:, :N], N)
    with pytest.raises(ConfigError, match="not a multiple of the period"):
        best_linear_approximation(x[:, :-1], x[:, :-1], x[:, :-1], N)


def test_identify_period_writes_the_bla_with_its_parts(tmp_path, capsys):
    """`mr-ident identify DATA.npz --period N`: r, u, y of shape (M, n) in, the BLA with
    noise_std and nl_std out (read_result reads it as any result); the cubic loop's nonlinear
    std above its noise's; bad periods refused."""
    from mr_ident.cli import main
    from mr_ident.io.datafile import read_result

    ms = design(fs_high=1.0, period=N, band=(0.01, 0.3), kind="odd-random", periods=P + 1,
                realizations=M)  # fmt: skip
    r = ms.r[:, :, 0]
    rng = np.random.default_rng(5)
    y = scipy.signal.lfilter(B, A, r + 0.3 * r**3, axis=1) + 1e-3 * rng.standard_normal(r.shape)
    data = tmp_path / "periodic.npz"
    np.savez(data, r=r, u=r, y=y, fs_high=100.0)
    out = tmp_path / "bla.npz"
    assert main(["identify", str(data), "--period", str(N), "--out", str(out)]) == 0
    assert "BLA on" in capsys.readouterr().out
    frf = read_result(out)
    z = np.load(out)
    assert frf.response.shape[0] == z["nl_std"].shape[0] and str(z["method"]) == "bla"
    assert np.median(z["nl_std"]) > 5 * np.median(z["noise_std"])
    np.testing.assert_allclose(frf.frequency, ms.lines[0] * 100.0 / N)
    assert main(["identify", str(data), "--period", str(N + 1), "--out", str(out)]) == 2
    assert "does not divide" in capsys.readouterr().err


def test_the_bla_result_reads_back_and_its_plot_shows_the_noise_and_nonlinear_std(tmp_path):
    """`identify --period --plot`: the figure draws, per excited line, the total std and its
    noise and nonlinear parts (the values of the result, in dB), the odd and even levels
    above the noise over it, and the distortion per band; read_bla gives back what
    was written, and None for a result that is not a BLA."""
    from matplotlib.figure import Figure

    from mr_ident.cli import main
    from mr_ident.io.periodicfile import read_bla
    from mr_ident.plots import bla_figure

    ms = design(fs_high=1.0, period=N, band=(0.01, 0.3), kind="odd-random", periods=P + 1,
                realizations=M)  # fmt: skip
    r = ms.r[:, :, 0]
    rng = np.random.default_rng(6)
    y = scipy.signal.lfilter(B, A, r + 0.3 * r**3, axis=1) + 1e-3 * rng.standard_normal(r.shape)
    data, out, png = tmp_path / "p.npz", tmp_path / "bla.npz", tmp_path / "bla.png"
    np.savez(data, r=r, u=r, y=y, fs_high=100.0)
    argv = ["identify", str(data), "--period", str(N), "--out", str(out), "--plot", str(png)]
    assert main(argv) == 0
    assert png.stat().st_size > 10_000
    got = read_bla(out)
    assert got is not None
    bla, f = got
    want = best_linear_approximation(r[:, N:], r[:, N:], y[:, N:], N)
    np.testing.assert_array_equal(bla.lines, want.lines)
    np.testing.assert_allclose(f, want.lines * 100.0 / N)
    for k in ("response", "std", "noise_std", "nl_std", "odd_level", "even_level"):
        np.testing.assert_allclose(getattr(bla, k), getattr(want, k), rtol=1e-12)
    assert bla.odd_db[0] > 20 and abs(bla.even_db[0]) < 3  # a cubic: odd distortion only
    fig = bla_figure(f, bla, bands=distortion_by_band(r[:, N:], y[:, N:], N, 100.0))
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    lines = {ln.get_label(): ln.get_ydata() for ln in fig.axes[0].get_lines()}
    assert f"odd {bla.odd_db[0]:.1f} dB, even {bla.even_db[0]:.1f} dB" in fig.axes[0].get_title()
    np.testing.assert_allclose(lines["σ noise"], 20 * np.log10(bla.noise_std))
    np.testing.assert_allclose(lines["σ nonlinear"], 20 * np.log10(bla.nl_std))
    other = tmp_path / "frf.npz"
    np.savez(other, frequency=f, P=bla.response[:, None, None], P_std=bla.std[:, None, None])
    assert read_bla(other) is None


def test_distortion_by_band_tells_a_nonlinear_plant_from_a_linear_one():
    """Per band, dB above the noise on the unexcited lines: linear within 3 dB of 0 (noise
    only); cubic: odd lines > 20 dB, even lines within 3 dB of 0."""
    edges = np.array([0.01, 0.1, 0.3])
    for nl, odd_lo, odd_hi in ((lambda u: u, -3.0, 3.0), (lambda u: u + 0.3 * u**3, 20, 99)):
        ms = design(fs_high=1.0, period=N, band=(0.01, 0.3), kind="odd-random", periods=9)
        r = ms.r[0, :, 0]
        rng = np.random.default_rng(3)
        y = scipy.signal.lfilter(B, A, nl(r)) + 1e-3 * rng.standard_normal(r.shape)
        for b in distortion_by_band(r[N:], y[N:], N, 1.0, edges):
            assert odd_lo < b.odd_db < odd_hi, b
            assert abs(b.even_db) < 3.0, b
            assert b.excited_db > 30, b
