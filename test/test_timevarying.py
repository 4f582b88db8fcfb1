# SPDX-License-Identifier: Apache-2.0
"""Does the plant change within a record? Its segments' plant estimates compared."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mr_bench.beyond import draw_beyond
from mr_bench.scenarios import draw_loop
from mr_ident import simulate
from mr_ident.diagnosis import diagnose
from mr_ident.diagnosis.criterion.timevarying import SEGMENTS, VARYING_DB, segments, within
from mr_ident.diagnosis.report import report_dict


def test_a_record_is_cut_into_equal_segments_of_whole_periods_or_multiples_of_f():
    loop = draw_loop(np.random.default_rng(0), duration=10.0)
    rec = simulate(loop.nominal, reference=loop.reference, noise=np.zeros_like(loop.y_clean))
    segs = segments(rec, n=8)
    F = loop.nominal.ratio
    assert len(segs) == SEGMENTS and len({s.n_samples for s in segs}) == 1
    assert all(s.n_samples % F == 0 for s in segs)
    assert [s.first for s in segs] == [j * segs[0].n_samples for j in range(SEGMENTS)]
    periodic = dataclasses.replace(rec.part(0, 12 * 64 * F), period=64 * F)
    got = segments(periodic, n=8)
    assert len(got) == 3 and all(s.n_samples == 4 * 64 * F for s in got)
    assert segments(rec.part(0, 100 * F), n=8) == []  # too short for two segments
    with pytest.raises(ValueError, match="parts must be at least 2, got 1"):
        segments(rec, n=8, parts=1)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_time_invariant_loop_is_not_named_time_varying(seed):
    """Random loops with output noise, 10 s of white r: the segments differ by their noise
    (the mean per-line ratio at most 0.88 dB over 320 loops of the benchmarks'
    generators)."""
    loop = draw_loop(np.random.default_rng(seed), duration=10.0)
    m = loop.nominal
    noise = m.noise_std * np.random.default_rng(seed + 10).standard_normal(loop.y_clean.shape)
    rec = simulate(m, reference=loop.reference, noise=noise)
    got = within(rec, m)
    assert got is not None and got.parts == SEGMENTS and got.bands
    assert got.level_db < VARYING_DB and not got.varying and got.text() == ""


def test_a_gain_that_changes_during_the_record_is_named_in_the_report():
    """The benchmark's time-varying gain (1 + 0.26 sin(2 pi t / 7 s), 10 s records): no
    time-invariant correction describes it; the diagnosis says the plant changes within
    the record. One cause allowed: none validates at any count, so the segments, the
    correction and the texts are the default search's (measured: the same 6.7 dB over 4
    segments, nothing applied) at a third of its time."""
    b = draw_beyond("time_varying_gain", np.random.default_rng(5026000), duration=10.0)
    d = diagnose(b.nominal, b.data, b.validation, max_causes=1)
    s = d.segments
    assert d.time_varying and s is not None and s.parts == SEGMENTS and s.level_db > VARYING_DB
    assert s.text().startswith("the plant changes within the record")
    rep = report_dict(d, extended_model=None, alpha=0.01)
    assert rep["time_varying"]["detected"] and s.text() in rep["findings"]
    assert len(rep["time_varying"]["bands"]) == len(s.bands)
    assert not (d.applied and d.fit_after.y < d.fit_before.y)
