# SPDX-License-Identifier: Apache-2.0
"""Strided LPM: a window solved every 2h + 1 bins, its polynomial evaluated around its centre.

Checked against an explicit least-squares fit of each bin's window (numpy.linalg.lstsq), its
polynomial evaluated at the bin's offset: G, the noise covariance and the inverse Gram
matrix's G block; the grouping against its definition.
"""

import numpy as np
import pytest
from conftest import lpm_regressor

from mr_ident.numerics.local.lpm import dof, lpm_bins_last
from mr_ident.numerics.local.strided import LONG_RUN, groups, offsets_for


def window_fit_at(U, Y, c, n, R, x):
    """Least squares on the window of padded centre c, at offset x = r/n: G, C_v, inv_gram."""
    ni = U.shape[1]
    Uw, Yw = U[c : c + 2 * n + 1], Y[c : c + 2 * n + 1]
    Km = lpm_regressor(Uw, n, R)
    th, *_ = np.linalg.lstsq(Km, Yw, rcond=None)
    w = np.zeros((Km.shape[1], ni))
    for s in range(R + 1):
        w[s * ni : (s + 1) * ni] = np.eye(ni) * x**s
    V = Yw - Km @ th
    Ai = np.linalg.inv(Km.conj().T @ Km)
    return (w.T @ th).T, V.T @ V.conj() / (2 * n + 1 - Km.shape[1]), w.T @ Ai @ w


def test_groups_cover_every_bin_once_within_its_run_and_at_most_h_from_its_centre():
    rng = np.random.default_rng(0)
    bins = np.unique(rng.integers(0, 400, 250))  # runs of all lengths with gaps
    for h in (1, 2, 3):
        solved, owner, offset = groups(bins, h)
        assert np.all(np.abs(offset) <= h) and owner.size == bins.size
        np.testing.assert_array_equal(solved[owner] + offset, bins)
        assert np.isin(solved, bins).all()  # a solved centre is one of the bins: its own run
        counts = np.bincount(owner)
        assert counts.max() <= 2 * h + 1 and counts.min() >= 1
        run = np.cumsum(np.r_[0, np.diff(bins) != 1])  # which run each bin is in
        assert np.all(run[np.searchsorted(bins, solved[owner])] == run)


@pytest.mark.parametrize("ni,no,n,h", [(1, 2, 9, 1), (3, 6, 27, 3), (2, 2, 12, 1)])
def test_every_bin_gets_its_groups_window_evaluated_at_its_offset(ni, no, n, h):
    rng = np.random.default_rng(ni + 10 * n)
    R, K = 2, 3 * (2 * h + 1) * LONG_RUN + 40  # one run long enough to go along the run
    U = rng.standard_normal((K + 2 * n, ni)) + 1j * rng.standard_normal((K + 2 * n, ni))
    Y = rng.standard_normal((K + 2 * n, no)) + 1j * rng.standard_normal((K + 2 * n, no))
    q = dof(n, R, ni)
    centred = lpm_bins_last(U, Y, n, R, q)
    short = np.r_[3:40, 100:101, 200:215]  # short runs: gathered, window by window
    for centres in (None, short):
        G, Cv, Ai, n_bad = lpm_bins_last(U, Y, n, R, q, 2, centres=centres, offsets=h)
        bins = np.arange(K) if centres is None else centres
        solved, owner, offset = groups(bins, h)
        assert n_bad == 0 and G.shape == (no, ni, bins.size)
        at0 = offset == 0  # the solved centres: the centred fit itself
        for got, ref in zip((G, Cv, Ai), centred[:3], strict=True):
            np.testing.assert_allclose(got[..., at0], ref[..., bins[at0]], rtol=1e-11, atol=1e-13)
        picks = np.r_[np.flatnonzero(offset != 0)[:6], np.flatnonzero(offset != 0)[-6:]]
        for b in picks:
            ref = window_fit_at(U, Y, solved[owner[b]], n, R, offset[b] / n)
            for got, want in zip((G, Cv, Ai), ref, strict=True):
                scale = np.abs(want).max()
                np.testing.assert_allclose(got[..., b], want, rtol=0, atol=1e-11 * scale)


def test_offsets_grow_with_the_width_and_leave_the_narrow_windows_centred():
    assert [offsets_for(n) for n in (1, 8, 9, 12, 18, 27, 36)] == [0, 0, 1, 1, 2, 3, 4]


def test_the_widest_window_is_strided_where_chosen_and_only_when_asked():
    from mr_ident.numerics.local.bandwidth import choose_widths

    H = 400
    P = np.ones((2, H, 1, 1), complex)
    V = np.empty((2, H, 1, 1))
    V[0], V[1] = 1.0, 0.3  # the wide one wins on the first half, the narrow one after
    P[1, H // 2 :] += 2.0
    widths, offsets = choose_widths((8, 27), P, V, np.arange(H), H, halfwidth=27, strided=True)
    wide = widths == 27
    assert wide[: H // 2 - 30].all() and not wide[H // 2 + 30 :].any()
    np.testing.assert_array_equal(offsets, np.where(wide, offsets_for(27), 0))
    _, offsets = choose_widths((8, 27), P, V, np.arange(H), H, halfwidth=27)
    assert not offsets.any()


def test_windows_whose_off_centre_bias_shows_are_solved_at_every_centre():
    # a sharp resonance in a smooth FRF, a little noise: near it the strided estimate would
    # carry the window's cubic bias, so those groups take the centred fit; far from it the
    # groups are strided (their off-centre values differ from the centred ones)
    rng = np.random.default_rng(3)
    n, h, R = 27, 3, 2
    K = 3 * (2 * h + 1) * LONG_RUN
    k = np.arange(K + 2 * n)
    G = 1.0 / (1.0 - ((k - K / 2) / 40.0) ** 2 + 0.02j * (k - K / 2) / 40.0 + 1e-3j)
    U = rng.standard_normal((K + 2 * n, 1)) + 1j * rng.standard_normal((K + 2 * n, 1))
    Y = G[:, None] * U + 1e-4 * (rng.standard_normal((K + 2 * n, 1)) + 0j)
    q = dof(n, R, 1)
    centred = lpm_bins_last(U, Y, n, R, q)[0][0, 0]
    strided = lpm_bins_last(U, Y, n, R, q, 1, offsets=h)[0][0, 0]
    same = np.isclose(strided, centred, rtol=1e-12, atol=0)
    near = np.abs(np.arange(K) + n - K / 2) < 60
    assert same[near].all()  # at the resonance: every window solved at its centre
    assert (~same[~near]).mean() > 0.5  # elsewhere mostly strided (the off-centre bins)
