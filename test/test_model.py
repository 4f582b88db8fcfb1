"""Model files: the shipped example loads; bad files are rejected with a reason."""

import numpy as np
import pytest
import yaml

from mr_ident.errors import ModelError
from mr_ident.io.modelfile import load_model, model_from_dict, model_to_dict
from mr_ident.numerics.simulate import loop_poles

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

    from mr_ident.numerics.systems import TransferMatrix

    h, up = 0.01, 50
    num, den = [1.0, 2.0], [1.0, 3.0, 100.0]
    Pd = TransferMatrix.siso(num, den).discretize(h, delay=delay_samples * h)
    b, a = np.array(Pd.num[0][0]), np.array(Pd.den[0][0])
    u = np.random.default_rng(0).standard_normal(200)
    y = scipy.signal.lfilter(np.concatenate([np.zeros(a.size - b.size), b]), a, u)
    shift = int(round(delay_samples * up))
    uf = np.concatenate([np.zeros(shift), np.repeat(u, up)])[: u.size * up]
    _, yf, _ = scipy.signal.lsim((num, den), uf, np.arange(u.size * up) * h / up, interp=False)
    np.testing.assert_allclose(y, yf[::up], atol=1e-9 * np.abs(y).max())
