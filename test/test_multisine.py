# SPDX-License-Identifier: Apache-2.0
"""Multisine designs checked line by line (mr_ident.numerics.excitation.multisine, mr-ident
excite).

Every property is checked on the signal itself (its DFT), not on the design's own
bookkeeping: periodic to 1e-12, energy only on the stated lines (outside: < 1e-20 of the
peak power), equal amplitudes within 1e-9 (flat), the crest factor, the lifted aliases.
"""

from __future__ import annotations

import numpy as np
import pytest

from mr_ident.cli import main
from mr_ident.errors import ConfigError, MrIdentError
from mr_ident.numerics.excitation.multisine import design

FS, N = 240.0, 2400


def _spectrum(x):
    """|X(k)|, k = 0..N/2, of one period."""
    return np.abs(np.fft.rfft(x[:N]))


@pytest.mark.parametrize("kind", ["full", "odd", "odd-random"])
def test_lines_periodicity_amplitudes_and_crest_factor(kind):
    ms = design(fs_high=FS, period=N, band=(1.0, 100.0), kind=kind, periods=3, realizations=2)
    assert ms.r.shape == (2, 3 * N, 1)
    for m in range(2):
        x = ms.r[m, :, 0]
        np.testing.assert_allclose(x[N : 2 * N], x[:N], atol=1e-12)  # periodic
        np.testing.assert_allclose(np.sqrt(np.mean(x**2)), 1.0, rtol=1e-12)  # rms 1
        X = _spectrum(x)
        lines = ms.lines[0]
        on = np.zeros(X.size, bool)
        on[lines] = True
        assert np.max(X[~on] ** 2) < 1e-20 * np.max(X**2)  # nothing off the lines
        np.testing.assert_allclose(X[lines], X[lines][0], rtol=1e-9)  # flat
        cf = np.max(np.abs(x)) / np.sqrt(np.mean(x**2))
        assert cf <= 2.0 and abs(cf - ms.crest_factor[m, 0]) < 1e-9
    f = lines * FS / N
    assert f.min() >= 1.0 and f.max() <= 100.0
    if kind != "full":
        assert np.all(lines % 2 == 1)
    if kind == "odd-random":  # one of every 3 consecutive odd lines left out
        odd = np.arange(lines.min(), lines.max() + 1, 2)
        assert set(lines) | set(ms.detection) >= set(odd)
        assert not set(lines) & set(ms.detection)
        groups = np.sort(np.concatenate([lines, ms.detection])).reshape(-1, 3)[: len(ms.detection)]
        assert all(np.isin(g, ms.detection).sum() == 1 for g in groups)
    assert not np.allclose(ms.r[0], ms.r[1])  # realizations: other phases


def test_lifted_lines_give_each_lifted_bin_one_alias():
    """With F = 3, every lifted bin κ (mod M = N/F), conjugates included, holds at most one
    excited line of the signal's full DFT."""
    F = 3
    ms = design(fs_high=FS, period=N, band=(0.1, 119.0), kind="full", ratio=F, lifted=True)
    X = np.fft.fft(ms.r[0, :N, 0])
    excited = np.flatnonzero(np.abs(X) > 1e-9 * np.abs(X).max())  # both signs of frequency
    kappa = excited % (N // F)
    assert np.unique(kappa).size == kappa.size
    assert ms.frequencies.size > 0.3 * (N // F) / 2  # most bins used, not a sparse handful


def test_several_inputs_never_share_a_line():
    ms = design(fs_high=FS, period=N, band=(1.0, 50.0), kind="odd", inputs=3)
    spectra = [_spectrum(ms.r[0, :, i]) > 1e-9 for i in range(3)]
    assert not (spectra[0] & spectra[1]).any() and not (spectra[1] & spectra[2]).any()
    # orthogonal over a period
    G = ms.r[0, :N].T @ ms.r[0, :N] / N
    np.testing.assert_allclose(G, np.eye(3), atol=1e-12)


def test_a_slope_shapes_the_amplitude_spectrum():
    ms = design(fs_high=FS, period=N, band=(1.0, 100.0), kind="full", slope_db_per_decade=-20)
    X = _spectrum(ms.r[0, :, 0])
    k = ms.lines[0]
    ratio = X[k[-1]] / X[k[0]]
    np.testing.assert_allclose(ratio, k[0] / k[-1], rtol=1e-9)  # 1/f: -20 dB per decade


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"band": (1.0, 130.0)}, "at or below fs_high/2 = 120 Hz"),
        ({"band": (1.01, 1.05)}, "no line of a 2400-sample period"),
        ({"band": (1.0, 1.01)}, "no odd-random line in 1-1.01 Hz"),
        ({"ratio": 7, "lifted": True}, "period must be a multiple of ratio F = 7"),
        ({"rms": 0.0}, "rms must be > 0"),
        ({"kind": "even"}, "kind must be one of"),
    ],
)
def test_bad_designs_say_what_is_wrong(kwargs, match):
    args = {"fs_high": FS, "period": N, "band": (1.0, 100.0)} | kwargs
    with pytest.raises(ConfigError, match=match):
        design(**args)


def test_the_command_writes_npz_and_csv(tmp_path, capsys):
    out = tmp_path / "ms.npz"
    argv = ["excite", "--fs-high", "240", "--band", "1,100", "--period", "2400"]
    assert main([*argv, "--periods", "2", "--realizations", "3", "--out", str(out)]) == 0
    z = np.load(out)
    assert z["r"].shape == (3, 4800) and int(z["period"]) == 2400 and float(z["fs_high"]) == 240
    assert "odd-random multisine" in capsys.readouterr().out
    csv = tmp_path / "ms.csv"
    assert main([*argv, "--inputs", "2", "--out", str(csv)]) == 0
    head = csv.read_text().splitlines()[:2]
    assert head[0].startswith("# multisine") and head[1] == "t,r_m0_u0,r_m0_u1"
    assert main([*argv, "--lifted", "--out", str(out)]) == 2  # --lifted needs --ratio
    assert "--lifted needs --ratio" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:  # the parser's own refusal: usage, exit 2
        main(["excite", "--fs-high", "240", "--band", "5,1", "--period", "2400", "--out", "x.npz"])
    assert stop.value.code == 2 and "expected 0 <= LO < HI" in capsys.readouterr().err


def test_the_command_says_what_a_publish_or_design_lacks(tmp_path, capsys):
    """Nothing to do, a design file with design options beside it, no design at all: each an
    error naming the options (exit 2), before any ROS code runs."""
    argv = ["excite", "--fs-high", "240", "--band", "1,100", "--period", "2400"]
    assert main(argv) == 2
    assert "needs --out FILE.npz|FILE.csv or --publish TOPIC" in capsys.readouterr().err
    design_file = tmp_path / "d.npz"
    assert main([*argv, "--out", str(design_file)]) == 0
    assert main(["excite", "--design", str(design_file), "--band", "1,10", "--out", "x.npz"]) == 2
    assert "--design FILE gives the design; --band not with it" in capsys.readouterr().err
    assert main(["excite", "--period", "48", "--out", str(tmp_path / "x.npz")]) == 2
    assert "excite needs --fs-high, --band to design" in capsys.readouterr().err


def test_the_simulated_loop_plays_an_excitation_file(tmp_path):
    """`mr-ident-sim --excitation FILE.npz`: the file's realizations in turn, looped, are the
    r of the blocks, exactly; the loop's P_h from one period of the steady state equals the
    exact plant on the excited lines (noise-free: 1e-6 relative)."""
    from mr_ident.io.excitefile import read_excitation, write_excitation
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.excitation.sources import SimSource
    from mr_ident.ros.sim import excitation_signal

    model = load_model("config/paper_example.yaml")
    ms = design(fs_high=240.0, period=2400, band=(0.5, 100.0), kind="odd", realizations=2)
    path = tmp_path / "ex.npz"
    write_excitation(path, ms, ratio=3)
    r, fs, period = read_excitation(path)
    assert r.shape == (2, 2400, 1) and fs == 240.0 and period == 2400
    sig = excitation_signal(str(path), model)
    src = SimSource(model, block=1200, excitation="signal", signal=sig)
    blocks = [src.next() for _ in range(6)]  # 7200 samples: both realizations, then again
    got = np.concatenate([b[1] for b in blocks])[:, 0]
    np.testing.assert_array_equal(got[:4800], sig[:, 0])
    np.testing.assert_array_equal(got[4800:], sig[:2400, 0])
    # one realization, four periods: in the last one the loop is periodic, and y = P_h u
    one = design(fs_high=240.0, period=2400, band=(0.5, 100.0), kind="odd", periods=4)
    src = SimSource(model, block=2400, excitation="signal", signal=one.r[0])
    blocks = [src.next() for _ in range(4)]
    u, y = (np.concatenate([b[i] for b in blocks])[7200:, 0] for i in (2, 3))
    k = one.lines[0]
    U, Y = np.fft.rfft(u)[k], np.fft.rfft(y)[k]
    P = model.plant_discrete().freqresp(k * 240.0 / 2400)[:, 0, 0]
    assert np.median(np.abs(Y / U / P - 1)) < 1e-6
    from dataclasses import replace

    with pytest.raises(MrIdentError, match="is at fs_high = 240 Hz, the model at 500 Hz"):
        excitation_signal(str(path), replace(model, fs_high=500.0))
