"""The best linear approximation with its noise and nonlinear parts (mr_ident.numerics.bla).

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
from mr_ident.numerics.bla import best_linear_approximation
from mr_ident.numerics.multisine import design

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
    excited line, the BLA equals P_h to 1e-8 and no line shows distortion."""
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.excitation import SimSource

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


def test_distortion_by_band_tells_a_nonlinear_plant_from_a_linear_one():
    """Per band, dB above the noise on the unexcited lines: linear within 3 dB of 0 (noise
    only); cubic: odd lines > 20 dB, even lines within 3 dB of 0."""
    from mr_ident.numerics.bla import distortion_by_band

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
