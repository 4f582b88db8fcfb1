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
from mr_ident.diagnosis.criterion.timevarying import (
    POOLED_ALPHA,
    SEGMENTS,
    VARYING_DB,
    pooled,
    segments,
    within,
)
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
    assert got.pooled is not None and got.pooled.p > POOLED_ALPHA


def _lines(rng, M, K, change, width=9):
    """M estimates of a plant on K lines, relative changes ``change``, noise correlated over
    ``width`` neighbouring lines (as a local fit's overlapping windows make it)."""
    f = np.arange(1, K + 1, dtype=float)
    G0 = 1.0 / (1.0 + 1j * f / 40.0)
    e = rng.standard_normal((M, K + width)) + 1j * rng.standard_normal((M, K + width))
    noise = np.stack([np.convolve(x, np.ones(width) / np.sqrt(width), "valid")[:K] for x in e])
    sd = 0.05 * np.abs(G0)
    G = (1.0 + np.asarray(change))[:, None] * G0 + sd * noise / np.sqrt(2)
    V = np.broadcast_to(sd**2, (M, K))
    return f, G[..., None], np.array(V)[..., None]


def test_the_pooled_change_is_an_f_test_whatever_the_lines_correlation():
    """Noise correlated over 9 lines: a chi-square over the lines would be 9 times too large;
    the blocks' scatter scales it away (about 5 % below 0.05 under no change)."""
    rng = np.random.default_rng(0)
    ps = [
        pooled(*_lines(rng, 4, 600, [0.0] * 4), df=1.0, low_bins=0, window=9).p for _ in range(300)
    ]
    assert 0.02 < np.mean(np.array(ps) < 0.05) < 0.09
    got = pooled(*_lines(rng, 4, 600, [0.03, -0.03, 0.02, -0.02]), df=1.0, low_bins=0, window=9)
    assert got is not None and got.p < POOLED_ALPHA and 0.015 < got.change < 0.04
    assert (
        pooled(*_lines(rng, 4, 10, [0.0] * 4), df=1.0, low_bins=0, window=9) is None
    )  # one block


def test_the_pooled_blocks_are_two_windows_wide_in_the_bins_folded_onto_the_low_rate():
    """A lifted fit (F = 3, segments of 1500 samples, 500 low-rate bins): the high-rate lines
    1..750 fold onto the low-rate bins 0..250 (k mod 500, and m with 500 - m), 251 bins;
    blocks of at least two windows of 21: 5 of them, holding every line."""
    rng = np.random.default_rng(1)
    f, G, V = _lines(rng, 4, 750, [0.0] * 4)
    got = pooled(0.2 * f, G, V, df=0.2, low_bins=500, window=21)
    assert got is not None and got.blocks == 251 // 42 == 5 and got.lines == 750
    assert got.p > POOLED_ALPHA
    assert pooled(0.2 * f, G, V, df=0.2, low_bins=500, window=5).blocks == 12  # at most
    assert pooled(0.2 * f, G, V, df=0.2, low_bins=60, window=21) is None  # 31 bins
    assert pooled(f, G, V, df=1.0, low_bins=0, window=21).blocks == 12  # 17 fit, unfolded


def test_a_gain_change_the_mean_level_misses_is_found_by_pooling_the_lines():
    """The benchmark's case 6026004 (1 + 0.19 sin(2 pi t / 4.0 s), 10 s): 0.75 dB on average
    over the lines, below the level's threshold; the lines pooled name it."""
    b = draw_beyond("time_varying_gain", np.random.default_rng(6026004), duration=10.0)
    got = within(b.data, b.nominal)
    assert got is not None and got.level_db < VARYING_DB and got.pooled is not None
    assert got.pooled.p < POOLED_ALPHA and got.varying and "gain moves by" in got.text()


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
