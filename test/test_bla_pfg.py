# SPDX-License-Identifier: Apache-2.0
"""The PFG from data at the lines of a lifted design
(mr_ident.numerics.excitation.bla.lifted_line_pfg).

Loops drawn at random (``scenarios.draw_loop``: plants of order 2-6, lead/PI/PID
controllers, F in {2, 3, 5}) played a lifted odd multisine (``design(lifted=True)``: one
excited line per lifted bin), noise-free and in steady state: at every excited line the
PFG from data equals the model's (``pfg_of_model``) to 1e-8 relative, where a white r and
a local model reach 1e-4 only where the alias range is small (test_pfg_data.py). Where
two excited lines share a lifted bin the column is not measured: nan.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import periodic_runs

from mr_bench.scenarios import draw_loop
from mr_ident.numerics.excitation.bla import best_linear_approximation, lifted_line_pfg
from mr_ident.numerics.excitation.multisine import design
from mr_ident.numerics.lifted.pfg import pfg_of_model


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_noise_free_the_pfg_from_data_is_the_models_at_every_line_of_a_lifted_design(seed):
    loop = draw_loop(np.random.default_rng(4400 + seed), duration=5.0, ratios=(2, 3, 5))
    model = replace(loop.nominal, noise_std=0.0)
    F, fs = model.ratio, model.fs_high
    period = 60 * F * 10
    ms = design(fs_high=fs, period=period, band=(fs / period, 0.45 * fs), kind="odd",
                periods=12, realizations=2, ratio=F, lifted=True, seed=seed)  # fmt: skip
    r, u, y = periodic_runs(model, ms.r, period, 12)
    b = best_linear_approximation(r[:, 10 * period :], u[:, 10 * period :],
                                  y[:, 10 * period :], period, ms.lines[0], ratio=F)  # fmt: skip
    assert b.pfg is not None and b.pfg_std is not None
    assert np.all(np.isfinite(b.pfg)), "every line of a lifted design is alone in its bin"
    truth = pfg_of_model(model, period).gain[b.lines - 1]
    err = np.abs(b.pfg / truth - 1)
    assert np.max(err) < 1e-8, (F, np.max(err))


def test_a_line_sharing_its_lifted_bin_gives_nan_and_noise_gives_a_calibrated_std():
    period, F = 24, 3  # M = 8: lines 1 and 9 share lifted bin 1, line 4 meets its conjugate
    lines = np.array([1, 2, 4, 9])
    R = np.zeros((1, period // 2 + 1), complex)
    R[0, lines] = 1.0
    Y = np.ones((1, period // 2 + 1), complex)
    g, s = lifted_line_pfg(R, Y, np.full(Y.shape, 1e-4), lines, period, F)
    assert np.isnan(g[[0, 2, 3]]).all() and np.isnan(s[[0, 2, 3]]).all()
    assert g[1] == pytest.approx(np.sqrt(F)), "three aliases of magnitude 1 over |R| = 1"
    # the std: first order in the entries' variance, 1e-4 each: var |c| = 3 * 1e-4 / (2 * 3)
    assert s[1] == pytest.approx(np.sqrt(0.5e-4))


def test_identify_period_on_a_lifted_design_writes_the_pfg_from_data(tmp_path, capsys):
    """`mr-ident identify DATA.npz --period N` on a drawn loop played a lifted design with a
    little output noise: the result holds pfg_data at every line (read_identification reads
    it back as the data PFG), within 5 of its std of the model's at 99 % of the lines, and
    the CLI says so."""
    from mr_ident.cli import main
    from mr_ident.io.datafile import read_identification

    loop = draw_loop(np.random.default_rng(4500), duration=5.0, ratios=(3,))
    model = replace(loop.nominal, noise_std=0.0)
    F, fs, period = model.ratio, model.fs_high, 1800
    ms = design(fs_high=fs, period=period, band=(fs / period, 0.45 * fs), kind="odd",
                periods=6, realizations=2, ratio=F, lifted=True, seed=1)  # fmt: skip
    r, u, y = periodic_runs(model, ms.r, period, 6)
    noise = 1e-3 * float(np.std(y)) * np.random.default_rng(2).standard_normal(y.shape)
    data, out = tmp_path / "lifted.npz", tmp_path / "bla.npz"
    np.savez(data, r=r, u=u, y=y + noise, fs_high=fs, ratio=F)
    assert main(["identify", str(data), "--period", str(period), "--out", str(out)]) == 0
    assert "PFG from data at" in capsys.readouterr().out
    ident = read_identification(out)
    assert ident.pfg_data is not None
    lines = np.rint(ident.pfg_data.frequency * period / fs).astype(int)
    truth = pfg_of_model(model, period).gain[lines - 1]
    z = np.abs(ident.pfg_data.gain - truth) / ident.pfg_data.std
    assert np.all(np.isfinite(z)) and np.mean(z < 5) > 0.99, np.sort(z)[-5:]
