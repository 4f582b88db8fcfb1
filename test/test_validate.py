# SPDX-License-Identifier: Apache-2.0
"""Model validation: hide an effect in the data, require diagnose to find it.

Set-up: the paper's plant under a softer lead controller (half the gain of
config/paper_example.yaml, so that up to 3 samples of control delay keep the loop
stable), F = 3, 240 Hz, 15 s of white-noise reference (3600 samples; the last 30 %
held out for validation). Noise: white output noise with a std of 2 % of the
nominal output's std (34 dB SNR), a realistic encoder-plus-vibration level.

The effect's parameters are drawn inside each test from a seeded generator
(redrawn until the true loop is stable). Tolerances on the recovered parameters:
gain 1 %, delay 0.05 samples, mode frequency 1 %, damping 15 %, residue scale 5 %,
disturbance frequency 0.2 %, amplitude 10 %; integer offsets and delays exactly. The validation
fit of y must rise by at least MARGIN percentage points (stated per cause: what the
effect at its smallest drawn size costs the nominal model, with room for the noise).

The records were 30 s; 15 s keeps every check's margin (measured on these seeds, 30 s ->
15 s, as a fraction of the tolerance): gain 0.04 -> 0.09, delay 0.002 -> 0.03, frequency
0.06 -> 0.12, damping 0.03 -> 0.06, residue scale 0.03 -> 0.02, amplitude 0.15 -> 0.01,
disturbance frequency 2e-4 -> 5e-3 (two effects: gain 0.05 -> 0.08); the smallest rise
of the fit over its MARGIN 6.2 / 3 -> 5.2 / 3 (sampling offset) and 4.1 / 0.5 ->
4.2 / 0.5 (disturbance); no significant bin after; noise alone: the controller check's
fraction 7e-5 -> 2e-3 (it flags above 0.03). The diagnoses' time halves (38 -> 22 s for
the seven causes, alone on the 2-core machine).
"""

from dataclasses import replace

import numpy as np
import pytest

from mr_ident.cli import main
from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.causes.plant_causes import plant_modes
from mr_ident.errors import ModelError
from mr_ident.io.modelfile import load_model, model_from_dict, model_to_dict
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.simulate import simulate

FS, F, DURATION = 240.0, 3, 15.0
NOISE_FRACTION = 0.02
MARGIN = {
    "gain_error": 3.0,
    "input_delay": 3.0,
    "series_resonance": 3.0,
    "mode_shift": 3.0,
    "sampling_offset": 3.0,
    "control_delay": 3.0,
    "periodic_disturbance": 0.5,
}


@pytest.fixture(scope="module")
def nominal(paper_model) -> Model:
    return replace(
        paper_model, controller=TransferMatrix.siso([3000.0, -2700.0], [1.0, -0.3], F / FS)
    )


def _stable(m: Model) -> Model | None:
    try:
        return model_from_dict(model_to_dict(m))
    except ModelError:
        return None


def _draw(
    cause: str, nominal: Model, rng: np.random.Generator, y_std: float
) -> tuple[Model, dict]:
    """A true loop differing from ``nominal`` by ``cause``, parameters drawn from ``rng``."""
    for _ in range(50):
        if cause == "gain_error":
            p = {"gain": 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.3)}
            m = replace(nominal, plant_gain=p["gain"])
        elif cause == "input_delay":
            p = {"delay_s": rng.uniform(0.3, 1.5) / FS}
            m = replace(nominal, input_delay=p["delay_s"])
        elif cause == "series_resonance":
            p = {"frequency_hz": rng.uniform(70.0, 110.0), "damping": rng.uniform(0.03, 0.1)}
            m = replace(nominal, series_dynamics=((p["frequency_hz"], p["damping"], "input", 0),))
        elif cause == "mode_shift":
            f0, z0 = plant_modes(nominal)[-1]
            f = f0 * rng.choice([rng.uniform(0.85, 0.95), rng.uniform(1.05, 1.2)])
            p = {
                "frequency_hz": f,
                "damping": rng.uniform(0.03, 0.08),
                "residue_scale": float(rng.choice([1.0, (f / f0) ** 2])),
            }
            m = replace(nominal, mode_changes=((f0, f, p["damping"], p["residue_scale"]),))
        elif cause == "sampling_offset":
            p = {"offset_samples": float(rng.integers(1, F))}
            m = replace(nominal, sample_phase=int(p["offset_samples"]))
        elif cause == "control_delay":
            p = {"delay_samples": float(rng.integers(1, 4))}
            m = replace(nominal, control_delay=int(p["delay_samples"]))
        elif cause == "periodic_disturbance":
            p = {
                "frequency_hz": rng.uniform(5.0, 100.0),
                "amplitude": rng.uniform(0.05, 0.2) * y_std,
            }
            m = replace(
                nominal,
                disturbances=((p["frequency_hz"], p["amplitude"], rng.uniform(0, 6.28), 0),),
            )
        else:
            raise AssertionError(cause)
        true = _stable(m)
        if true is not None:
            return true, p
    raise AssertionError(f"no stable draw for {cause}")


def _data(true: Model, nominal: Model, seed: int) -> LoopData:
    y_std = simulate(nominal, duration=DURATION, rng=np.random.default_rng(seed)).y.std()
    sim = simulate(
        replace(true, noise_std=NOISE_FRACTION * y_std),
        duration=DURATION,
        rng=np.random.default_rng(seed),
    )
    return LoopData(sim.r, sim.u, sim.y, FS, F)


def _y_std(nominal: Model) -> float:
    return float(simulate(nominal, duration=DURATION, rng=np.random.default_rng(0)).y.std())


_CASES: dict[tuple[str, int], tuple] = {}


def _case(nominal: Model, cause: str, seed: int) -> tuple:
    """(true model, drawn parameters, record, diagnosis) of a hidden ``cause``; computed once
    per process (the extended model's second diagnosis takes one of these)."""
    if (cause, seed) not in _CASES:
        true, p = _draw(cause, nominal, np.random.default_rng(seed), _y_std(nominal))
        rec = _data(true, nominal, seed)
        _CASES[cause, seed] = true, p, rec, diagnose(nominal, rec)
    return _CASES[cause, seed]


@pytest.fixture(scope="module")
def cli_gain_case(nominal, tmp_path_factory):
    """The gain case (seed 11) diagnosed by the command line, ``diagnose nominal data --json
    --report --out-model``: (drawn parameters, output directory); the diagnosis it computes
    (kept by a wrapper around diagnose) is the case's for the test above."""
    import mr_ident.diagnosis

    true, p = _draw("gain_error", nominal, np.random.default_rng(11), _y_std(nominal))
    rec = _data(true, nominal, 11)
    out = tmp_path_factory.mktemp("cli_gain")
    np.savez(out / "data.npz", r=rec.r, u=rec.u, y=rec.y, fs_high=FS, ratio=F)
    import yaml

    (out / "nominal.yaml").write_text(yaml.safe_dump(model_to_dict(nominal)))
    made = []

    def kept(*args, **kwargs):
        made.append(diagnose(*args, **kwargs))
        return made[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mr_ident.diagnosis, "diagnose", kept)
        code = main(
            ["diagnose", str(out / "nominal.yaml"), str(out / "data.npz"),
             "--json", str(out / "r.json"), "--report", str(out / "r.html"),
             "--out-model", str(out / "ext.yaml")]
        )  # fmt: skip
    assert code == 0
    (d,) = made
    _CASES["gain_error", 11] = true, p, rec, d
    return p, out


TOL = {
    "gain": 0.01,
    "frequency_hz": 0.01,
    "damping": 0.15,
    "amplitude": 0.10,
    "residue_scale": 0.05,
}


@pytest.mark.parametrize(
    "cause,seed",
    [
        ("gain_error", 11),
        ("input_delay", 12),
        ("series_resonance", 13),
        ("mode_shift", 14),
        ("sampling_offset", 15),
        ("control_delay", 16),
        ("periodic_disturbance", 17),
    ],
)
def test_diagnose_names_the_hidden_cause_recovers_it_and_raises_the_fit(
    nominal, cause, seed, request
):
    """The gain case's diagnosis is the command line's (its run below)."""
    if cause == "gain_error":
        request.getfixturevalue("cli_gain_case")
    _, p, _, d = _case(nominal, cause, seed)
    assert d.cause == cause, [(c.cause, c.score) for c in d.ranking]
    for k, v in p.items():
        got = d.parameters[k]
        if k in ("offset_samples", "delay_samples"):
            assert got == v
        elif k == "delay_s":
            assert abs(got - v) * FS < 0.05
        elif k == "frequency_hz" and cause == "periodic_disturbance":
            assert abs(got - v) / v < 0.002
        else:
            assert abs(got - v) / v < TOL[k], (k, got, v)
    assert d.fit_after.y - d.fit_before.y >= MARGIN[cause], (d.fit_before, d.fit_after)
    assert not d.evidence_after.significant.any()


def test_two_hidden_effects_are_both_found(nominal):
    rng = np.random.default_rng(21)
    y_std = _y_std(nominal)
    g = 1.0 + rng.uniform(0.15, 0.3)
    fd, amp = rng.uniform(10.0, 90.0), rng.uniform(0.1, 0.2) * y_std
    true = replace(nominal, plant_gain=g, disturbances=((fd, amp, 1.0, 0),))
    d = diagnose(nominal, _data(true, nominal, 21))
    applied = {c.cause: c.parameters for c in d.applied}
    assert set(applied) == {"gain_error", "periodic_disturbance"}
    assert abs(applied["gain_error"]["gain"] - g) / g < 0.01
    assert abs(applied["periodic_disturbance"]["frequency_hz"] - fd) / fd < 0.002
    ranked = [c.cause for c in d.ranking]
    assert ranked.index("gain_error") < ranked.index("none")
    assert ranked.index("periodic_disturbance") < ranked.index("none")


def test_noise_alone_gives_none_and_no_significant_bin(nominal):
    d = diagnose(nominal, _data(nominal, nominal, 31))
    assert d.cause == "none" and d.applied == []
    assert not d.evidence_before.significant.any()
    assert not d.evidence_before.loop_significant.any()
    assert d.controller is not None and not d.controller.differs, d.controller.fraction


def test_a_controller_on_the_machine_that_is_not_its_model_is_a_finding(nominal):
    """The machine runs the lead controller at 1.3 times the model's gain: the PFG from data
    and the PFG of the model's controller disagree, reported in the JSON's findings.

    ``max_causes=0``: the check is made on the identification before any cause is sought
    (the same fraction with or without them: 0.69 of the band flagged at 30 s, 0.64 at
    15 s; it flags above 0.03); the search for causes that could mimic a controller that
    is not the model's took 90 of the test's 94 s."""
    from mr_ident.diagnosis.report import report_dict

    K = nominal.controller
    true = replace(
        nominal, controller=TransferMatrix.siso([1.3 * c for c in K.num[0][0]], K.den[0][0], K.dt)
    )
    d = diagnose(nominal, _data(true, nominal, 61), max_causes=0)
    assert d.controller is not None and d.controller.differs, d.controller.fraction
    rep = report_dict(d, extended_model=None, alpha=0.01)
    assert rep["controller_check"]["differs"] and rep["controller_check"]["bands_hz"]
    assert any("controller on the machine differs" in f for f in rep["findings"])


def test_the_extended_model_diagnosed_again_gives_none(nominal):
    """The series resonance's case above (its diagnosis shared): the extended model, written
    and read back, explains the same record."""
    _, _, rec, first = _case(nominal, "series_resonance", 13)
    assert first.cause == "series_resonance"
    again = diagnose(model_from_dict(model_to_dict(first.extended)), rec)
    assert again.cause == "none"


def _write_case(
    tmp_path, model_text: str, duration: float = 40.0, fs: float = 240.0, ratio: int = 3
):
    mp = tmp_path / "model.yaml"
    mp.write_text(model_text)
    paper = load_model("config/paper_example.yaml")
    sim = simulate(paper, duration=duration, rng=np.random.default_rng(0))
    dp = tmp_path / "data.npz"
    np.savez(dp, r=sim.r, u=sim.u, y=sim.y, fs_high=fs, ratio=ratio)
    return mp, dp


PAPER_TEXT = open("config/paper_example.yaml").read()


@pytest.mark.parametrize(
    "model_text,duration,fs,ratio,match",
    [
        (PAPER_TEXT, 40.0, 250.0, 3, r"data.npz: fs_high is 250 Hz but the model says 240 Hz"),
        (PAPER_TEXT, 40.0, 240.0, 2, r"data.npz: the ratio F is 2 but the model says 3"),
        (PAPER_TEXT, 0.5, 240.0, 3, "too short for the LPM window"),
        (PAPER_TEXT + "plant_gian: 1.1\n", 40.0, 240.0, 3, "unknown key.*plant_gian"),
        (
            PAPER_TEXT + "additive_modes: [{frequency_hz: 80.0, damping: 0.05, q: 1}]\n",
            40.0,
            240.0,
            3,
            r"additive_modes\[0\]: unknown key",
        ),
    ],
    ids=["fs-disagrees", "ratio-disagrees", "too-short", "unknown-key", "unknown-mode-key"],
)
def test_bad_input_is_an_error_with_exit_2_and_no_output(
    tmp_path, capsys, model_text, duration, fs, ratio, match
):
    import re

    mp, dp = _write_case(tmp_path, model_text, duration, fs, ratio)
    out = tmp_path / "r.json"
    code = main(
        [
            "diagnose",
            str(mp),
            str(dp),
            "--json",
            str(out),
            "--report",
            str(tmp_path / "r.html"),
            "--out-model",
            str(tmp_path / "ext.yaml"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and re.search(match, err), err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.npz", "model.yaml"]


def test_cli_writes_the_report_the_model_and_the_json_fields(cli_gain_case):
    import json

    p, tmp_path = cli_gain_case
    rep = json.loads((tmp_path / "r.json").read_text())
    for key in (
        "cause",
        "parameters",
        "causes",
        "fit_before",
        "fit_after",
        "significant_bands",
        "extended_model",
    ):
        assert key in rep
    assert rep["cause"] == "gain_error" and rep["extended_model"] == str(tmp_path / "ext.yaml")
    assert rep["causes"][0]["cause"] == "gain_error" and rep["significant_bands"]
    ext = load_model(tmp_path / "ext.yaml")
    assert abs(ext.plant_gain - p["gain"]) / p["gain"] < 0.01
    page = (tmp_path / "r.html").read_text()
    assert page.count("data:image/png;base64,") == 4 and "gain_error" in page


def _random_loop(rng: np.random.Generator) -> Model:
    """A loop drawn at random: a modal plant of 1-2 modes (one may be an integrator pair's
    neighbour at low frequency), an input delay of 0-2.5 samples, F in {2, 3}, and a
    low-rate PD-like controller whose gain is halved until the loop is stable."""
    from mr_ident.numerics.systems.simulate import loop_poles

    Fr = int(rng.choice([2, 3]))
    num, den = np.array([0.0]), np.array([1.0])
    for _ in range(int(rng.integers(1, 3))):
        w = 2 * np.pi * rng.uniform(2.0, 0.4 * FS / 2)
        z = rng.uniform(0.02, 0.5)
        d = np.array([1.0, 2 * z * w, w * w])
        num = np.polyadd(np.polymul(num, d), rng.uniform(0.5, 2.0) * w * w * den)
        den = np.polymul(den, d)
    k = 1.0
    for _ in range(40):
        K = TransferMatrix.siso([k, -0.8 * k], [1.0, -0.2], Fr / FS)
        m = Model(
            fs_high=FS,
            ratio=Fr,
            plant=TransferMatrix.siso(num, den),
            controller=K,
            input_delay=float(rng.uniform(0.0, 2.5)) / FS,
            noise_std=0.0,
        )
        if np.max(np.abs(loop_poles(m))) < 0.98:
            return m
        k /= 2
    raise AssertionError("no stabilising gain")


@pytest.mark.parametrize("seed", [101, 102, 103])
def test_diagnose_on_random_loops_never_raises_a_traceback(tmp_path, seed):
    """Loops drawn at random, the model told without its input delay: diagnose reports
    (never an exception: a second-order plant with an input delay once gave scipy's
    BadCoefficients as a traceback) and names the delay. 10 s records (were 20 s: the
    delay found to 0.4 % of itself at both, in 2.4-3.3 s instead of 3.5-3.8 s)."""
    rng = np.random.default_rng(seed)
    true = _random_loop(rng)
    sim = simulate(replace(true, noise_std=0.0), duration=10.0, rng=rng)
    y_std = float(sim.y.std())
    sim = simulate(replace(true, noise_std=0.01 * y_std), duration=10.0, rng=rng)
    data = tmp_path / "d.npz"
    from mr_ident.io.datafile import write_data

    write_data(data, sim.r, sim.u, sim.y, fs_high=FS, ratio=true.ratio)
    nominal = tmp_path / "m.yaml"
    import yaml

    nominal.write_text(yaml.safe_dump(model_to_dict(replace(true, input_delay=0.0))))
    code = main(["diagnose", str(nominal), str(data), "--json", str(tmp_path / "r.json")])
    assert code == 0  # these three are diagnosable: the hidden delay is found (seen: all 3)
    import json

    report = json.loads((tmp_path / "r.json").read_text())
    assert report["cause"] == "input_delay", report["cause"]


def test_the_bins_whose_local_window_reaches_dc_are_not_tested():
    """A random loop of the benchmark (seed 107: 240 Hz, F = 3) whose model is exact: the
    local fit is biased at the first bins (56 sigma at 0.1 Hz, above the threshold's 6.8);
    the bins up to n of them are not tested, so nothing is flagged."""
    from mr_bench.scenarios import draw_loop
    from mr_ident.diagnosis.criterion.evidence import frf_evidence
    from mr_ident.numerics.identify import default_n

    rng = np.random.default_rng(107)
    loop = draw_loop(rng, duration=10.0)
    m = loop.nominal
    v = m.noise_std * rng.standard_normal(loop.y_clean.shape)
    rec = simulate(m, reference=loop.reference, noise=v)
    n = default_n("freq-lifted", 2, m.ratio, m.n_u, max(m.n_u, m.n_y))
    ev = frf_evidence(m, rec, n=n, degree=2, alpha=0.01)
    assert ev.sigma_error[0] > 3 * ev.threshold  # the bias is there, and shown (grey)
    assert not ev.significant.any() and ev.bands() == []
    assert np.flatnonzero(~ev.tested).tolist() == list(range(n))  # bins 1..n
    assert ev.loop_frequency.min() > n * m.fs_high / rec.n_samples
