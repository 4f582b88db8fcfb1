# SPDX-License-Identifier: Apache-2.0
"""The controller's FRF from the data (diagnosis.controller.frf), with its std.

The paper's plant under a softer lead controller, F = 3, 240 Hz; the machine's controller
differs from the model's (its gain 1.25 times, or a control delay one period longer). On a
command log (u the controller's output, no noise between them) the estimate is the
machine's controller up to the local polynomial's approximation of it over a window
(measured 1e-7 of |K| at most; claimed 1e-5). With a measured u (white noise of its own,
5 % of u's std, not fed back) the squared error over the estimated variance,
``|K̂ - K|² / std²``, is F(2, 2q) distributed: mean q / (q - 1), checked on bins 2n + 1
apart (independent windows) over 20 seeds against five standard deviations of that mean.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.controller.frf import controller_frf, held_fill
from mr_ident.diagnosis.report import report_dict
from mr_ident.htmlreport import report_html
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
N_WINDOW = 8


def _model():
    m = load_model(ROOT / "config" / "paper_example.yaml")
    K = TransferMatrix.siso([3000.0, -2700.0], [1.0, -0.3], 3 / 240.0)
    m = replace(m, controller=K)
    y_std = simulate(m, duration=10.0, rng=np.random.default_rng(0)).y.std()
    return replace(m, noise_std=0.02 * y_std)


def _machine(m, kind: str):
    if kind == "gain":
        K = TransferMatrix.siso([3750.0, -3375.0], [1.0, -0.3], 3 / 240.0)
        return replace(m, controller=K)
    return replace(m, control_delay=m.control_delay + m.ratio)  # a period: seen at its rate


def _measured_u(rec: LoopData, seed: int) -> LoopData:
    noise = 0.05 * rec.u.std() * np.random.default_rng(1000 + seed).standard_normal(rec.u.shape)
    return replace(rec, u=rec.u + noise)


@pytest.mark.parametrize("kind", ["gain", "delay"])
def test_a_command_log_gives_the_machines_controller(kind):
    m = _model()
    true = _machine(m, kind)
    rec = simulate(true, duration=30.0, rng=np.random.default_rng(1))
    c = controller_frf(rec, m, true, n=N_WINDOW)
    assert c is not None and c.fit is not None
    scale = np.max(np.abs(c.fit.response))
    assert np.max(np.abs(c.identified.response - c.fit.response)) < 1e-5 * scale
    assert np.max(c.identified.std) < 1e-5 * scale  # no noise between y_s and u_c
    # the model's controller is off by the gain (0.25 of K) or the delay's phase
    assert c.relative(c.model) > 0.05


def test_the_std_is_the_spread_over_seeds():
    m = _model()
    true = _machine(m, "gain")
    ratios = []
    for seed in range(20):
        rec = _measured_u(simulate(true, duration=20.0, rng=np.random.default_rng(seed)), seed)
        c = controller_frf(rec, m, true, n=N_WINDOW)
        assert c is not None and c.fit is not None
        e = np.abs(c.identified.response - c.fit.response)[:: 2 * N_WINDOW + 1, 0, 0]
        ratios.append(e**2 / c.identified.std[:: 2 * N_WINDOW + 1, 0, 0] ** 2)
    r = np.concatenate(ratios)
    q = c.dof
    # |e|²/σ̂² ~ F(2, 2q): mean q/(q-1), variance 8q³ / ((2q-2)² (2q-4))
    sd_mean = np.sqrt(8 * q**3 / ((2 * q - 2) ** 2 * (2 * q - 4)) / r.size)
    assert abs(r.mean() - q / (q - 1)) < 5 * sd_mean


def test_no_estimate_without_a_controller():
    m = _model()
    rec = simulate(m, duration=10.0, rng=np.random.default_rng(2))
    assert controller_frf(rec, replace(m, controller=None), None, n=N_WINDOW) is None


def test_a_run_past_the_records_start_keeps_the_delays_phase():
    """The machine's control delay one period longer: on the run 700..2399 (a burst of
    y lost before it) the estimate, its phase turned by the model's timing, is the fitted
    controller's, whose delay turns it by a period more (measured 6.6e-6 of |K|; claimed
    1e-4, the bound of the shorter run below)."""
    m = _model()
    true = _machine(m, "delay")
    rec = simulate(true, duration=30.0, rng=np.random.default_rng(1))
    y = rec.y.copy()
    y[2000:2100] = np.nan
    c = controller_frf(replace(rec, y=y), m, true, n=N_WINDOW)
    assert c is not None and c.available and c.fit is not None and c.span == (700, 2400)
    scale = np.max(np.abs(c.fit.response))
    assert np.max(np.abs(c.identified.response - c.fit.response)) < 1e-4 * scale


def test_with_missing_samples_the_longest_complete_run_gives_the_machines_controller():
    """A burst of lost y, one lost y sample and two of u (their hold gives them back): the
    estimate is made on the longest run of complete periods and is the machine's
    controller there (to the polynomial's approximation over a window: its bins 2.5 times
    a whole record's, the degree-2 error about 2.5³ times larger; measured 1.1e-5 of |K|,
    claimed 1e-4)."""
    m = _model()
    true = _machine(m, "gain")
    rec = simulate(true, duration=30.0, rng=np.random.default_rng(1))
    y, u = rec.y.copy(), rec.u.copy()
    y[2000:2100] = np.nan  # periods 666-700 lost
    y[4998] = np.nan  # the sample period 1666's controller takes (phase 0)
    u[2500:2502] = np.nan  # a held output's sample, the hold's third gives it back
    c = controller_frf(replace(rec, y=y, u=u), m, true, n=N_WINDOW)
    assert c is not None and c.available and c.fit is not None
    assert c.span == (700, 1666) and c.periods == 2400
    scale = np.max(np.abs(c.fit.response))
    assert np.max(np.abs(c.identified.response - c.fit.response)) < 1e-4 * scale
    assert "periods 700-1665, the longest run without missing samples (40 %" in c.text()
    assert c.summary()["span"] == [700, 1666]


@pytest.mark.parametrize("ratio", [2, 3, 5])
def test_a_held_logs_missing_samples_come_from_their_hold(ratio):
    """A log held over F samples from any residue, 10 % of it lost: every sample whose
    hold interval kept one comes back exactly; a signal not held is left as it is."""
    rng = np.random.default_rng(ratio)
    for s in range(ratio):
        n = 600 + s
        x = rng.standard_normal((n // ratio + 3, 2))[(np.arange(n) - s) // ratio + 1]
        lost = rng.random(x.shape) < 0.1
        got = held_fill(np.where(lost, np.nan, x), ratio)
        kept = ~np.isnan(got)
        assert np.array_equal(got[kept], x[kept])
        # an interval loses all its samples with probability 0.1^F: kept 0.99 of x for
        # F = 2, its std over 1200 samples 0.003; 0.98 is 3 std below
        assert kept.sum() > 0.98 * x.size
    white = rng.standard_normal((600, 1))
    white[5] = np.nan
    assert np.isnan(held_fill(white, 3)[5, 0])
    held = rng.standard_normal((1000, 1))[np.arange(3000) // 3]
    held[301] = 5.0  # one change off the grid: its interval's samples disagree
    held[[300, 901]] = np.nan
    got = held_fill(held, 3)
    assert np.isnan(got[300, 0]) and got[901, 0] == got[900, 0]


def test_a_record_lost_too_often_says_why_it_has_no_estimate():
    m = _model()
    rec = simulate(m, duration=10.0, rng=np.random.default_rng(2))
    y = rec.y.copy()
    y[::60] = np.nan  # every 20th period's sample (phase 0) lost: runs of 19 periods
    c = controller_frf(replace(rec, y=y), m, None, n=N_WINDOW)
    assert c is not None and not c.available
    assert c.reason == (
        "the record holds 800 periods, its longest run without missing samples 19; "
        "the local fit needs 34"
    )
    assert c.summary() == {"available": False, "reason": c.reason, "periods": 800}
    assert c.text().startswith("the controller is not identified from the data: ")


def test_diagnose_shows_it_where_the_controller_differs():
    m = _model()
    true = _machine(m, "gain")
    data, val = (simulate(true, duration=20.0, rng=np.random.default_rng(s)) for s in (3, 4))
    d = diagnose(m, data, val)
    assert [a.cause for a in d.applied][:1] == ["controller_gain"]
    c = d.controller_frf
    assert c is not None and c.fit is not None
    assert c.relative(c.fit) < 1e-5  # the fitted gain's controller is the machine's
    assert abs(c.relative(c.model) - 0.25) < 1e-3  # (1.25 K - K) / K
    rep = report_dict(d, extended_model=None, alpha=0.01)["controller_frf"]
    assert rep["relative_to_fit"] < 1e-5 and len(rep["frequency_hz"]) <= 200
    assert len(rep["identified"]["re"]) == len(rep["frequency_hz"])
    summary = report_dict(d, extended_model=None, alpha=0.01)
    assert "Controller: identified from the data" in report_html(d, summary, None, "t")
    same = diagnose(m, simulate(m, duration=20.0, rng=np.random.default_rng(5)))
    assert same.controller_frf is None  # the model's controller runs: nothing to show
