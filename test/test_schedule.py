# SPDX-License-Identifier: Apache-2.0
"""A design played in a loop: labels by index, cutting a record back, stamps from the index,
and the loop that follows a reference arriving block by block."""

from __future__ import annotations

import numpy as np
import pytest

from mr_ident.errors import ConfigError, DataError
from mr_ident.live.sampling import Sampler, grid_stamps
from mr_ident.numerics.excitation.schedule import Schedule, realizations_of
from mr_ident.numerics.excitation.sources import Follower
from mr_ident.numerics.systems.simulate import LoopStream


def test_labels_follow_realization_then_period_then_sample_and_loop():
    s = Schedule(period=4, periods=2, realizations=3)
    lab = s.labels(0, 2 * s.cycle)
    assert s.cycle == 24
    np.testing.assert_array_equal(lab[:9, 2], [0, 1, 2, 3, 0, 1, 2, 3, 0])
    np.testing.assert_array_equal(lab[:9, 1], [0, 0, 0, 0, 1, 1, 1, 1, 0])
    np.testing.assert_array_equal(lab[:9, 0], [0] * 8 + [1])
    np.testing.assert_array_equal(lab[24:], lab[:24])  # looped
    np.testing.assert_array_equal(s.labels(13, 5), lab[13:18])  # any start


def test_take_plays_the_realizations_in_turn():
    rng = np.random.default_rng(0)
    r = rng.standard_normal((3, 8, 2))
    s = Schedule.of(r, 4)
    x = s.take(r, 5, 40)
    flat = r.reshape(24, 2)
    np.testing.assert_array_equal(x, flat[(5 + np.arange(40)) % 24])
    with pytest.raises(ConfigError, match="multiple of period = 3"):
        Schedule.of(r, 3)


def test_realizations_of_cuts_whole_periods_after_the_transient_of_each_run():
    """A record that starts mid-period and loops the design twice: each realization's whole
    periods after its first one, both runs of a realization joined, cut to the least count."""
    s = Schedule(period=5, periods=3, realizations=2)
    first = 7  # mid-period of realization 0
    n = 2 * s.cycle - first - 3
    lab = s.labels(first, n)
    pos = realizations_of(lab, 5, transient=1)
    idx = first + pos  # schedule indices
    assert pos.shape[0] == 2 and pos.shape[1] % 5 == 0
    got = s.labels(0, 2 * s.cycle)[idx % s.cycle]  # labels of what was cut
    for j in range(2):
        assert (got[j, :, 0] == j).all()
        periods = got[j, ::5, 1]
        assert 0 not in periods  # the first period of each run (transient) dropped
        assert (got[j].reshape(-1, 5, 3)[:, :, 2] == np.arange(5)).all()
    with pytest.raises(DataError, match="no realization holds a whole period"):
        realizations_of(lab[:9], 5)


def test_grid_stamps_come_from_the_index_and_do_not_drift():
    t0 = 1_700_000_000_123_456_789
    a = grid_stamps(t0, 0, 100_000, 240.0)
    b = np.concatenate([grid_stamps(t0, k, 1000, 240.0) for k in range(0, 100_000, 1000)])
    np.testing.assert_array_equal(a, b)  # cut into blocks anywhere: the same stamps
    far = 10**10  # 1.3 years at 240 Hz: still exact to the ns
    assert grid_stamps(t0, far, 1, 240.0)[0] == t0 + (2 * far * 10**9 + 240) // 480
    np.testing.assert_array_equal(grid_stamps(0, 3, 3, 2500.0), [1_200_000, 1_600_000, 2_000_000])
    idx, ok = Sampler(240.0, t0=t0).indices(a)  # the reader's rule maps them back exactly
    np.testing.assert_array_equal(idx, np.arange(a.size))
    assert ok.all()


def test_the_follower_equals_one_simulation_whatever_the_blocks(paper_model):
    """Blocks of any length, not multiples of F, starting off a multiple of F: the loop starts
    at the next multiple of F and equals one simulation of the reference from there."""
    rng = np.random.default_rng(3)
    r = rng.standard_normal((2000, 1))
    f = Follower(paper_model)
    out, first, k = [], 2, 2
    for n in rng.integers(1, 90, 100):
        if k + n > r.shape[0]:
            break
        got = f.offer(k, r[k : k + n])
        k += n
        if got is not None:
            out.append(got)
    assert out[0][0] == 3 and f.start == 3
    u = np.concatenate([o[1] for o in out])
    y = np.concatenate([o[2] for o in out])
    n = u.shape[0]
    u_ref, y_ref = LoopStream(paper_model).next(r[3 : 3 + n])
    np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-12 * np.abs(u_ref).max())
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-12 * np.abs(y_ref).max())
    assert f.simulated == n and first == 2


def test_the_follower_runs_a_missing_stretch_with_zero_and_ignores_repeats(paper_model):
    r = np.ones((30, 1))
    f = Follower(paper_model)
    a = f.offer(0, r[:9])
    assert a is not None and a[0] == 0 and a[1].shape == (9, 1)
    assert f.offer(3, r[3:9]) is None and f.repeated_samples == 6
    b = f.offer(15, r[15:21])  # 9 .. 14 never came
    assert b is not None and b[0] == 9 and b[1].shape == (12, 1) and f.gap_samples == 6
    u_ref, _ = LoopStream(paper_model).next(np.concatenate([r[:9], np.zeros((6, 1)), r[15:21]]))
    np.testing.assert_allclose(np.concatenate([a[1], b[1]]), u_ref, rtol=0, atol=1e-9)
