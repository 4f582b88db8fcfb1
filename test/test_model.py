# SPDX-License-Identifier: Apache-2.0
"""Model files: the shipped example loads; bad files are rejected with a reason."""

import numpy as np
import pytest
import yaml

from mr_ident.errors import ModelError
from mr_ident.io.modelfile import load_model, model_from_dict, model_to_dict
from mr_ident.numerics.systems.simulate import loop_poles

BASE = {
    "fs_high": 240.0,
    "ratio": 3,
    "plant": {"num": [1.0], "den": [1.0, 2.0, 100.0]},
    "controller": {"num": [0.1, 0.0], "den": [1.0, -0.9]},
    "noise_std": 0.0,
}


def test_the_paper_example_loads_and_its_loop_is_stable(paper_model):
    assert paper_model.ratio == 3 and paper_model.fs_high == 240.0
    assert np.max(np.abs(loop_poles(paper_model))) < 0.9
    # resonance above the low-rate Nyquist frequency (40 Hz), below the high one (120 Hz)
    wn = np.abs(np.roots(paper_model.plant.den[0][0])) / (2 * np.pi)
    assert np.any((wn > 40) & (wn < 120))


def test_a_model_round_trips_through_its_dict(paper_model):
    again = model_from_dict(yaml.safe_load(yaml.safe_dump(model_to_dict(paper_model))))
    assert again == paper_model


@pytest.mark.parametrize(
    "change,match",
    [
        ({"gain": 2.0}, r"unknown key\(s\) \['gain'\]"),
        ({"ratio": 0}, "ratio must be an integer >= 1, got 0"),
        ({"ratio": 2.5}, "ratio must be an integer >= 1"),
        ({"fs_high": "fast"}, "fs_high must be a positive number"),
        (
            {"plant": {"num": [1.0, "x"], "den": [1.0, 2.0, 100.0]}},
            r"plant.num\[1\] must be a finite number, got 'x'",
        ),
        ({"plant": {"num": [1.0, 0.0, 0.0, 0.0], "den": [1.0, 2.0, 100.0]}}, "improper"),
        ({"plant": {"num": [1.0], "den": [1.0, 2.0, 100.0], "gain": 1}}, r"plant: unknown key"),
        ({"controller": {"num": [500.0, 0.0], "den": [1.0, -0.9]}}, "closed loop is not stable"),
        ({"sample_phase": 3}, "sample_phase must be in 0..2"),
        (
            {"plant": {"num": [[[1.0], [0.5]], [[0.2], [1.0]]], "den": [1.0, 2.0, 100.0]}},
            r"controller is 1x1, expected n_u x n_y = 2x2",
        ),
        (
            {"controller": {"num": [0.1], "den": [1.0, -0.9], "domain": "continuous"}},
            "controller must be discrete",
        ),
    ],
)
def test_bad_model_files_are_rejected_with_a_reason(change, match):
    with pytest.raises(ModelError, match=match):
        model_from_dict(BASE | change)


def test_a_missing_file_and_bad_yaml_are_model_errors(tmp_path):
    with pytest.raises(ModelError, match="cannot read model file"):
        load_model(tmp_path / "nope.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("fs_high: [1,\n")
    with pytest.raises(ModelError, match="not valid YAML"):
        load_model(p)


@pytest.mark.parametrize("delay_samples", [0.0, 0.4, 1.0, 2.3])
def test_a_fractional_input_delay_is_discretised_exactly_for_held_inputs(delay_samples):
    """Against a fine continuous-time simulation of the delayed plant, held input (lsim, ZOH)."""
    import scipy.signal

    from mr_ident.numerics.systems.realize import sections, zoh

    h, up = 0.01, 50
    num, den = [1.0, 2.0], [1.0, 3.0, 100.0]
    Pd = zoh(sections(num, den), h, delay=delay_samples * h)
    u = np.random.default_rng(0).standard_normal(200)
    _, y, _ = scipy.signal.dlsim((Pd.A, Pd.B, Pd.C, Pd.D, h), u)
    y = y[:, 0]
    shift = int(round(delay_samples * up))
    uf = np.concatenate([np.zeros(shift), np.repeat(u, up)])[: u.size * up]
    _, yf, _ = scipy.signal.lsim((num, den), uf, np.arange(u.size * up) * h / up, interp=False)
    np.testing.assert_allclose(y, yf[::up], atol=1e-9 * np.abs(y).max())


def test_the_small_lti_kernels_agree_with_scipy_and_with_analytic_truth():
    """expm and tf2ss (numpy, for start-up time) against scipy's and against closed forms,
    and the ZOH of sections against the ZOH of scipy's realisation, on random low-order
    systems; 1e-12 relative (the ZOH: 1e-9 of the peak)."""
    import scipy.linalg
    import scipy.signal

    from mr_ident.numerics.systems.lti import expm, tf2ss
    from mr_ident.numerics.systems.realize import sections, zoh

    w = 3.0  # a rotation generator: expm is exact in closed form
    R = expm(np.array([[0.0, -w], [w, 0.0]]))
    np.testing.assert_allclose(R, [[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]], atol=1e-14)
    # a companion matrix whose coefficients span 13 decades (modes at 1, 60 and 100 Hz at
    # 240 Hz): balanced first, else the squaring loses six digits
    den = np.real(np.poly(2 * np.pi * np.array([-1.0, -3 + 60j, -3 - 60j, -5 + 100j, -5 - 100j])))
    A = tf2ss([1.0], den)[0] / 240.0
    ref = scipy.linalg.expm(A)
    np.testing.assert_allclose(expm(A), ref, rtol=0, atol=1e-9 * np.abs(ref).max())
    rng = np.random.default_rng(7)
    for n in range(1, 7):
        A = rng.standard_normal((n, n)) * rng.choice([0.01, 1.0, 20.0])
        ref = scipy.linalg.expm(A)
        np.testing.assert_allclose(expm(A), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        den = np.poly(-rng.uniform(0.5, 5.0, n))
        num = rng.standard_normal(rng.integers(1, n + 2))
        for mine, theirs in zip(tf2ss(num, den), scipy.signal.tf2ss(num, den), strict=True):
            np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-12)
        A, B, C, D = tf2ss(num, den)
        dt = 1e-3  # truth: the ZOH in state space, C (zI - e^(A dt))^-1 Bd + D
        E = scipy.linalg.expm(np.block([[A, B], [np.zeros((1, n + 1))]]) * dt)
        f = np.linspace(1.0, 400.0, 50)
        truth = [
            (C @ np.linalg.solve(z * np.eye(n) - E[:n, :n], E[:n, n:]) + D)[0, 0]
            for z in np.exp(2j * np.pi * f * dt)
        ]
        Gd = zoh(sections(num, den), dt)
        peak = np.abs(truth).max()
        np.testing.assert_allclose(Gd.freqresp(f)[:, 0, 0], truth, rtol=1e-9, atol=1e-9 * peak)
