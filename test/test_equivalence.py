# SPDX-License-Identifier: Apache-2.0
"""Equivalent explanations: causes the data cannot tell apart are stated, not hidden.

A loop drawn by the scenario generator (not made here: seed 1020000 of the benchmark's
input-delay cases, 240 Hz, F = 3, a sixth-order cascaded plant with an integrator under a
PID, SNR 30 dB) hides an input delay of 4.62 ms. Over the band its 30 s record excites, a
first-order low-pass at 1/(2π·4.62 ms) = 34.4 Hz bends the phase the same way: the
diagnosis must name one and state the other as explaining the data as well, with values
that agree (delay = 1/(2π f) within 3 %) and a BIC difference below the selection's margin.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mr_bench.scenarios import HiddenCause, draw_scenario
from mr_bench.verdict import judge
from mr_ident.diagnosis.selection.forward import ACCEPT_MARGIN


@pytest.fixture(scope="module")
def delay_case():
    from mr_ident.diagnosis import diagnose

    sc = draw_scenario(("input_delay",), np.random.default_rng(1020000), duration=30.0)
    return sc, diagnose(sc.nominal, sc.data)


def test_an_input_delay_and_a_low_pass_are_stated_as_equivalent(delay_case):
    sc, d = delay_case
    assert len(d.applied) == 1, [a.cause for a in d.applied]
    first = d.applied[0]
    pair = {"input_delay", "series_lowpass"}
    assert first.cause in pair
    other = next(q for q in first.equivalents if q.cause in pair - {first.cause})
    assert abs(other.delta_bic) < ACCEPT_MARGIN
    values = {first.cause: first.parameters, other.cause: other.parameters}
    delay, corner = values["input_delay"]["delay_s"], values["series_lowpass"]["frequency_hz"]
    assert abs(delay * 2 * math.pi * corner - 1.0) < 0.03, (delay, corner)
    true = sc.hidden[0].parameters["delay_s"]
    assert abs(delay - true) < 0.1 / sc.nominal.fs_high  # the benchmark's tolerance
    assert other.std and all(v >= 0 for v in other.std.values())
    assert "or, as well" not in other.description  # the cause's own words


def test_the_report_lists_the_equivalents(delay_case):
    from mr_ident.diagnosis.report import report_dict

    _, d = delay_case
    rep = report_dict(d, extended_model=None, alpha=0.01)
    eq = rep["applied"][0]["equivalents"]
    assert eq and {"cause", "parameters", "std", "description", "delta_bic"} <= set(eq[0])
    assert all(e["delta_bic"] < ACCEPT_MARGIN for e in eq)


def test_the_judge_counts_a_stated_equivalent_only_as_stated():
    sc = draw_scenario(("gain_error",), np.random.default_rng(1), duration=5.0)
    g = sc.hidden[0].parameters["gain"]
    named = [("additive_mode", {"frequency_hz": 10.0})]
    alt = [[("gain_error", {"gain": g}, {"gain": 0.01 * g})]]
    v = judge(sc, named, 0.0, [{}], alt)
    assert not v.success and not v.consistent and v.stated
    assert not judge(sc, named, 0.0, [{}], [[("gain_error", {"gain": 2 * g}, {})]]).stated
    assert not judge(sc, named, 0.0, [{}]).stated  # nothing stated
    pair = replace(sc, hidden=(*sc.hidden, HiddenCause("control_delay", {"delay_samples": 2}, {})))
    both = [("control_delay", {"delay_samples": 2.0}), ("additive_mode", {})]
    v = judge(pair, both, 0.0, [{}, {}], [[], alt[0]])
    assert not v.success and v.stated
