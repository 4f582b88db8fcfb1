# SPDX-License-Identifier: Apache-2.0
"""P_h from a low-rate output on a rotated lifted multisine
(mr_ident.numerics.lifted.slow_periodic).

Loops drawn at random (``scenarios.draw_loop``: plants of order 2-6, lead/PI/PID, F in
{2, 3, 5}) played a rotated lifted design (``design(rotate=True)``, F realizations), in
steady state, y kept at samples q, q + F, ... only. Noise-free, P_h is exact at every line
of every excited alias family (to 1e-8 relative), beyond the design's band up to fs/2,
where a white r and a local model reach 1e-4 only where the alias range allows
(test_slow_output.py); so is the PFG from data, J = diag(P_h) S from the measured u,
without the controller. One realization (or an unrotated design) cannot give it: refused
bins, no line. With output noise the std covers the error.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import periodic_runs

from mr_bench.scenarios import draw_loop
from mr_ident.errors import ConfigError, DimensionError
from mr_ident.numerics.excitation.multisine import alias_family, design
from mr_ident.numerics.lifted.pfg import pfg_of_model
from mr_ident.numerics.lifted.slow_periodic import slow_output_plant
from mr_ident.numerics.systems.simulate import loop_poles


def _record(seed, noise=0.0, kept=3, rotate=True):
    """A drawn loop's rotated-design record in steady state: the first periods dropped
    until its slowest closed-loop pole has decayed to 1e-12."""
    loop = draw_loop(np.random.default_rng(seed), duration=5.0, ratios=(2, 3, 5))
    model = replace(loop.nominal, noise_std=noise)
    F, fs = model.ratio, model.fs_high
    period = 120 * F
    rho = float(np.max(np.abs(loop_poles(model))))
    skip = int(np.ceil(np.log(1e-12) / np.log(rho) * F / period)) + 1
    assert skip * period < 30_000, "a loop that settles within the test's budget"
    ms = design(fs_high=fs, period=period, band=(fs / period, 0.2 * fs), kind="full",
                periods=skip + kept, realizations=F, ratio=F, lifted=True, rotate=rotate,
                seed=seed)  # fmt: skip
    r, u, y = periodic_runs(model, ms.r, period, skip + kept, skip)
    return model, ms, period, (r, u), y


@pytest.mark.parametrize("seed", [4601, 4603, 4604, 4608])  # F = 2, 2 (PID), 3, 5
def test_noise_free_a_rotated_design_gives_p_h_exactly_from_a_slow_y(seed):
    model, ms, period, ru, y = _record(seed)
    F, q = model.ratio, seed % model.ratio
    sp = slow_output_plant(*ru, y[:, q::F], period, F, phase=q)
    lines = sp.lines
    truth = model.plant_frf(period)[lines, 0, 0]
    assert np.max(np.abs(sp.response / truth - 1)) < 1e-8
    # the PFG from data, J = diag(P_h) S, without the controller: the model's to 1e-8
    pfg = pfg_of_model(model, period).gain[lines - 1]
    assert np.max(np.abs(sp.pfg / pfg - 1)) < 1e-8
    # every line of every excited family, beyond the band (0.2 fs) up to fs/2
    fams = np.unique(np.concatenate([alias_family(k, period, F) for k in ms.lines[0]]))
    assert np.array_equal(np.sort(lines), fams)
    assert lines.max() * model.fs_high / period > 0.4 * model.fs_high


def test_without_rotation_the_lifted_bins_are_not_identifiable():
    model, _, period, ru, y = _record(4604, rotate=False)
    assert slow_output_plant(*ru, y[:, ::3], period, 3).lines.size == 0


def test_with_noise_the_std_covers_the_error():
    model, _, period, ru, y = _record(4601, kept=12)
    rng = np.random.default_rng(7)
    y = y + 1e-3 * float(np.std(y)) * rng.standard_normal(y.shape)
    sp = slow_output_plant(*ru, y[:, ::2], period, 2)
    z = np.abs(sp.response - model.plant_frf(period)[sp.lines, 0, 0]) / sp.std
    assert np.all(np.isfinite(z)) and np.mean(z < 3) > 0.95, np.sort(z)[-5:]
    zg = np.abs(sp.pfg - pfg_of_model(model, period).gain[sp.lines - 1]) / sp.pfg_std
    assert np.all(np.isfinite(zg)) and np.mean(zg < 3) > 0.95, np.sort(zg)[-5:]


def test_bad_arguments_are_refused():
    u = np.zeros((2, 240))
    with pytest.raises(ConfigError, match="multiple of ratio"):
        slow_output_plant(u, u, np.zeros((2, 120)), 25, 2)
    with pytest.raises(DimensionError, match="y_low"):
        slow_output_plant(u, u, np.zeros((2, 100)), 24, 2)
    with pytest.raises(ConfigError, match="rotate needs"):
        design(fs_high=100.0, period=24, band=(1, 40), kind="odd", ratio=2, lifted=True,
               rotate=True, realizations=2)  # fmt: skip


def test_excite_rotate_then_identify_period_on_a_slow_y(tmp_path, capsys):
    """`mr-ident excite --lifted --rotate` designs it; the loop played it, y kept at the low
    rate (NPZ y of n/F samples per realization, y_phase 1): `identify --period N` writes
    P_h on every line of the excited families, equal to the plant's to 1e-8; an unrotated
    design is refused with the remedy named."""
    from mr_ident.cli import main
    from mr_ident.io.datafile import read_identification, read_result

    loop = draw_loop(np.random.default_rng(4601), duration=5.0, ratios=(2, 3, 5))
    model = replace(loop.nominal, noise_std=0.0)
    F, fs, period = model.ratio, model.fs_high, 120 * model.ratio
    rho = float(np.max(np.abs(loop_poles(model))))
    skip = int(np.ceil(np.log(1e-12) / np.log(rho) * F / period)) + 1
    design_file = tmp_path / "design.npz"
    args = ["excite", "--fs-high", str(fs), "--band", f"1,{0.2 * fs}", "--period", str(period),
            "--periods", str(skip + 3), "--realizations", str(F), "--kind", "full",
            "--ratio", str(F), "--lifted", "--out", str(design_file)]  # fmt: skip
    assert main([*args, "--rotate"]) == 0
    d = np.load(design_file)
    assert d["realization_lines"].shape[0] == F
    r, u, y = periodic_runs(model, d["r"], period, skip + 3, 0)
    data, out = tmp_path / "slow.npz", tmp_path / "P.npz"
    np.savez(data, r=r, u=u, y=y[:, 1::F], y_phase=1, fs_high=fs, ratio=F)
    argv = ["identify", str(data), "--period", str(period), "--transient-periods", str(skip),
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    assert "P_h from y at the low rate" in capsys.readouterr().out
    frf = read_result(out)
    lines = np.rint(frf.frequency * period / fs).astype(int)
    truth = model.plant_frf(period)[lines, 0, 0]
    assert np.max(np.abs(frf.response[:, 0, 0] / truth - 1)) < 1e-8
    got = read_identification(out).pfg_data
    assert got is not None
    assert np.max(np.abs(got.gain / pfg_of_model(model, period).gain[lines - 1] - 1)) < 1e-8
    assert main([*args]) == 0  # the same without --rotate
    d = np.load(design_file)
    r, u, y = periodic_runs(model, d["r"], period, skip + 3, 0)
    np.savez(data, r=r, u=u, y=y[:, ::F], fs_high=fs, ratio=F)
    assert main(argv) == 2
    assert "--rotate" in capsys.readouterr().err
