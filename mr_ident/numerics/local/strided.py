# SPDX-License-Identifier: Apache-2.0
"""Wide LPM windows solved every ``2h + 1`` bins, each evaluated around its centre.

The LPM window of half-width n centred at bin c fits, for ``r = -n..n`` and ``x = r/n``,
``Y(c+r) = G_c(x) U(c+r) + T_c(x) + V(c+r)`` with the local polynomial
``G_c(x) = sum_s G_s x^s``. The centred estimate of bin c is ``G_c(0) = G_0``; the same fit
also estimates the FRF at the bins ``c + r`` near the centre, ``G_c(r/n)``. When n is wide
the windows of neighbouring bins share all but a few of their 2n + 1 bins, so solving
every window is mostly repeated work. Here the centre bins are cut into groups of
``2h + 1`` consecutive bins (:func:`groups`); the window of each group's middle bin is
solved, and every bin of the group takes that window's polynomial at its offset
``|r| <= h``.

Covariance: with the unknowns ``theta = A^-1 K^H Y`` (``A = K^H K``) and ``w_i(x)`` the
vector with ``x^s`` at the place of ``G_s[:, i]`` (0 elsewhere), ``G_c(x)[o, i] =
w_i^T theta[:, o]`` and, as for the centred estimate (:mod:`.lpm`),
``Cov(G(x)[a, b], G(x)[a2, b2]) = C_v[a, a2] w_b^T A^-1 w_b2``: ``inv_gram`` at offset x
is ``sum_{s,s'} x^s x^s' (A^-1)_GG[(s, b), (s', b2)]``. With ``A^-1 = L^-H L^-1`` the G
block ``(A^-1)_GG = Z^H Z``, ``Z = L_GG^-1`` (the transient comes first, so the G rows of
``L^-1 w`` are ``Z w_G``). The noise covariance is the window's.

How close to the centred fit: for the window's own noise, the variance of ``G_c(x)`` at
``|x| <= 1/9`` differs from the centred one by a few per cent at most (for R = 2 it is
lower off centre: the variance factor of a quadratic on a uniform design is
``9/4 - 9x^2/2 + 45x^4/4`` of its value per bin). The bias is another matter: off centre
the symmetric window's cancellation of the cubic term is lost, and near a resonance on a
short record the added bias can exceed the std. So along a run every solved window is
checked against its neighbours (:meth:`_Solved.unsafe`), and the groups where the
off-centre bias shows are solved at every centre. :data:`MAX_OFFSET` bounds ``h/n``.
The automatic window strides only its widest candidate, where chosen
(:mod:`mr_ident.numerics.local.bandwidth`); a fixed n solves every window.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from ..budget import chunk_bins
from ..threads import thread_map
from .normal import Layout, Sums, chunk_sums, factor, noise_cov

#: The largest offset from a solved window's centre, as a share of its half-width n:
#: ``h = floor(n * MAX_OFFSET)`` (n = 8: every window solved; 12: 1; 18: 2; 27: 3).
MAX_OFFSET = 1.0 / 9.0
#: A solved window's off-centre bias is checked against its neighbours (:meth:`_Solved.unsafe`):
#: where striding would add a squared bias above this share of the variance (at the
#: largest offset h), the window's group is solved at every centre instead.
BIAS_SHARE = 0.1
#: ``E|D|^2 / v`` per bin of distance from pure noise, D the difference of a window's
#: estimate at a bin off its centre and the centred estimate there: the two weight the same
#: data differently (a local quadratic on a uniform design, n = 27: 0.036, 0.071, 0.105 at
#: 1, 2, 3 bins; about linear).
NOISE_PER_OFFSET = 0.035
#: Window pairs each side in the moving mean of the check (a window of n = 27 spans 55 bins,
#: about 8 groups of 7).
CHECK_PAIRS = 4

#: Runs of at least this many groups have their windowed sums formed along the run, every
#: ``2h + 1`` bins; the groups of shorter runs (and the short groups at the runs' ends) are
#: gathered, window by window, into batches (one engine pass for many runs).
LONG_RUN = 256


def offsets_for(n: int) -> int:
    """The offset h used for half-width n: ``floor(n * MAX_OFFSET)``.

    >>> [offsets_for(n) for n in (8, 9, 12, 18, 27)]
    [0, 1, 1, 2, 3]
    """
    return int(n * MAX_OFFSET + 1e-9)


def groups(
    centres: NDArray[np.intp], h: int
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Cut increasing centre bins into groups of ``2h + 1`` consecutive bins.

    Each run of consecutive bins is cut from its start; its last ``t < 2h + 1`` bins (if
    any) form one shorter group around their middle. Returns the solved centres
    (increasing), and for every given centre the index of its group's solved centre and its
    offset from it (|offset| <= h).

    >>> solved, owner, offset = groups(np.array([0, 1, 2, 3, 4, 5, 6, 10, 11]), 1)
    >>> solved.tolist(), owner.tolist(), offset.tolist()
    ([1, 4, 6, 11], [0, 0, 0, 1, 1, 1, 2, 3, 3], [-1, 0, 1, -1, 0, 1, 0, -1, 0])
    """
    c = np.asarray(centres, dtype=np.intp)
    s = 2 * h + 1
    starts = np.flatnonzero(np.r_[True, np.diff(c) != 1])
    lengths = np.diff(np.r_[starts, c.size])
    first = np.repeat(c[starts], lengths)
    tail_at = np.repeat(c[starts] + lengths // s * s, lengths)  # first bin of the short group
    tail = np.repeat(lengths % s, lengths)
    mid = np.where(c < tail_at, first + (c - first) // s * s + h, tail_at + tail // 2)
    solved, owner = np.unique(mid, return_inverse=True)
    return solved, owner.astype(np.intp), (c - mid).astype(np.intp)


class _Solved:
    """The solved windows of one piece: their polynomial's coefficients and covariances."""

    def __init__(self, sums: Sums, lay: Layout, q: int) -> None:
        T, P, R, n_in, n_out = lay.T, lay.P, lay.degree, lay.n_in, lay.n_out
        L, W, self.bad = factor(sums, lay)
        Kc = W.shape[-1]
        Lg = L[T:, T:]
        # theta_G = L_GG^-H W_G (every G_s), Z = L_GG^-1, (A^-1)_GG = Z^H Z
        th = np.empty((P, n_out, Kc), dtype=np.complex128)
        for j in range(P - 1, -1, -1):
            acc = W[T + j].copy()
            for m in range(j + 1, P):
                acc -= np.conj(Lg[m, j]) * th[m]
            th[j] = acc / Lg[j, j].real
        Z = np.zeros((P, P, Kc), dtype=np.complex128)
        for c in range(P):
            Z[c, c] = 1.0 / Lg[c, c].real
            for r in range(c + 1, P):
                Z[r, c] = -np.einsum("mk,mk->k", Lg[r, c:r], Z[c:r, c]) / Lg[r, r].real
        Zc = np.conj(Z)
        iu, ju = np.triu_indices(n_in)
        self.iu, self.ju = iu, ju
        # (A^-1)_GG for the input pairs (i <= i2) only: (pairs, s, s', Kc), s = R..0
        A = np.empty((iu.size, R + 1, R + 1, Kc), dtype=np.complex128)
        for p, (i, i2) in enumerate(zip(iu, ju, strict=True)):
            for a in range(R + 1):
                for b in range(R + 1):
                    j1, j2 = a * n_in + i, b * n_in + i2
                    m0 = max(j1, j2)
                    A[p, a, b] = np.einsum("mk,mk->k", Zc[m0:, j1], Z[m0:, j2])
        self.A = A
        self.th = th.reshape(R + 1, n_in, n_out, Kc)  # [R - s, i, o]
        self.Cv = np.empty((n_out, n_out, Kc), dtype=np.complex128)
        noise_cov(sums[4], W, q, self.Cv)
        self.R, self.n = R, lay.n

    def unsafe(self, s: int, h: int, pair: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
        """The windows (of windows every s bins along a run) whose off-centre bias shows.

        ``pair`` (Kc - 1,): whether windows j and j+1 are neighbours (default: all are).
        For neighbours j, j+1 (centres s apart), D compares window j at offset +s with
        window j+1 at its centre, and window j+1 at -s with window j at its centre. The
        cubic bias that striding adds grows about as the offset, so at distance s it is
        ``(s/h)^2`` times its square at h; the noise of D is about
        :data:`NOISE_PER_OFFSET` ``s`` of the variance v. A window is unsafe where the
        moving mean (:data:`CHECK_PAIRS` pairs each side) of ``sum |D|^2 / sum v`` over the
        entries exceeds ``(s/h)^2`` :data:`BIAS_SHARE` ``+ NOISE_PER_OFFSET s``.
        """
        Kc = self.th.shape[-1]
        out = np.zeros(Kc, dtype=bool)
        if Kc < 2:
            return out
        g, ai = self.around(np.array([-s, 0, s]))  # (n_out, n_in, Kc, 3), (pairs, Kc, 3)
        diag = np.flatnonzero(self.iu == self.ju)  # the pairs (i, i)
        v = (
            np.real(np.diagonal(self.Cv, axis1=0, axis2=1)).T[:, None, :]
            * np.real(ai[diag, :, 1])[None, :, :]
        )  # (n_out, n_in, Kc): the centred estimate's variance
        d = (
            np.abs(g[:, :, :-1, 2] - g[:, :, 1:, 1]) ** 2
            + np.abs(g[:, :, 1:, 0] - g[:, :, :-1, 1]) ** 2
        )
        ratio = d.sum(axis=(0, 1)) / (v[:, :, :-1] + v[:, :, 1:]).sum(axis=(0, 1))
        real = np.isfinite(ratio) if pair is None else np.isfinite(ratio) & pair
        c = np.r_[0.0, np.cumsum(np.where(real, ratio, 0.0))]
        k = np.r_[0, np.cumsum(real)]
        m = np.arange(ratio.size)
        lo, hi = np.maximum(m - CHECK_PAIRS, 0), np.minimum(m + CHECK_PAIRS + 1, ratio.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = (c[hi] - c[lo]) / (k[hi] - k[lo])
        limit = (s / h) ** 2 * BIAS_SHARE + NOISE_PER_OFFSET * s
        flagged = real & (mean > limit)
        out[:-1] |= flagged
        out[1:] |= flagged
        return out

    def around(
        self, offsets: NDArray[np.intp]
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """G (n_out, n_in, Kc, D) and the input pairs' inv_gram (pairs, Kc, D) at D offsets."""
        X = (offsets[:, None] / self.n) ** np.arange(self.R, -1, -1)[None, :]  # (D, R+1)
        G = np.matmul(self.th.transpose(2, 1, 3, 0), X.T)  # (n_out, n_in, Kc, D)
        XX = (X[:, :, None] * X[:, None, :]).reshape(X.shape[0], -1)  # (D, (s, s'))
        pairs, S, _, Kc = self.A.shape
        Ai = np.matmul(self.A.reshape(pairs, S * S, Kc).transpose(0, 2, 1), XX.T)
        return G, Ai


class Engine(Protocol):
    """The centred engine's signature (:func:`~mr_ident.numerics.local.lpm.lpm_bins_last`)."""

    def __call__(
        self,
        Ua: NDArray[np.complex128],
        Ya: NDArray[np.complex128],
        n: int,
        degree: int,
        q: int,
        workers: int = 1,
        *,
        centres: NDArray[np.intp] | None = None,
        offsets: int = 0,
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128], int]:
        """G, its noise covariance and the inverse Gram (bins last); the rank-deficient count."""


def _call(job: Callable[[], int]) -> int:
    return job()


def _ranges(starts: NDArray[np.intp], lengths: NDArray[np.intp]) -> NDArray[np.intp]:
    """``starts[i] .. starts[i] + lengths[i] - 1`` for every i, concatenated.

    >>> _ranges(np.array([0, 10]), np.array([2, 3])).tolist()
    [0, 1, 10, 11, 12]
    """
    shift = starts - np.r_[0, np.cumsum(lengths)[:-1]]
    out: NDArray[np.intp] = np.repeat(shift, lengths) + np.arange(int(lengths.sum()))
    return out


def _pieces(
    req: NDArray[np.intp], s: int, h: int, step: int
) -> tuple[list[tuple[int, int, int]], list[tuple[int, int, int]]]:
    """The requested bins' groups of ``s = 2h + 1``: long runs in pieces, the rest gathered.

    Long runs: ``(first output index, first solved centre, count)`` every ``s`` bins, at
    most ``step`` groups a piece; the other groups (of short runs, and the short groups at
    the runs' ends): ``(first output index, centre, length)``.
    """
    grid: list[tuple[int, int, int]] = []
    short: list[tuple[int, int, int]] = []
    K = int(req.size)
    starts = np.flatnonzero(np.r_[True, np.diff(req) != 1])
    for a, b in zip(starts.tolist(), np.r_[starts[1:], K].tolist(), strict=True):  # runs
        first, full = int(req[a]), (b - a) // s
        if full >= LONG_RUN:
            for j0 in range(0, full, step):
                grid.append((a + j0 * s, first + j0 * s + h, min(step, full - j0)))
        else:
            short.extend((a + j * s, first + j * s + h, s) for j in range(full))
        t = b - a - full * s
        if t:
            short.append((a + full * s, first + full * s + t // 2, t))
    return grid, short


def lpm_strided(
    Ua: NDArray[np.complex128],
    Ya: NDArray[np.complex128],
    n: int,
    degree: int,
    q: int,
    workers: int,
    *,
    centres: NDArray[np.intp] | None,
    h: int,
    centred: Engine,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128], int]:
    """:func:`~mr_ident.numerics.local.lpm.lpm_bins_last` with offsets up to h.

    Same arguments and outputs (G (n_out, n_in, K), C_v (n_out, n_out, K), inv_gram
    (n_in, n_in, K), the number of bins whose window is rank deficient), every bin's
    values from the solved window of its group (:func:`groups`). The windowed sums are
    formed at the solved centres only: along each run every ``2h + 1`` bins
    (:func:`~mr_ident.numerics.local.window_sums.window_sums` with a stride), the short
    groups at the runs' ends from their windows gathered end to end. Along a run, the groups
    whose window's off-centre bias shows against its neighbours (:meth:`_Solved.unsafe`)
    are solved at every centre by ``centred`` (the engine with offsets 0).
    """
    n_in, n_out = Ua.shape[1], Ya.shape[1]
    K_all = Ua.shape[0] - 2 * n
    req = np.arange(K_all) if centres is None else np.asarray(centres, dtype=np.intp)
    K = int(req.size)
    lay = Layout.of(n, degree, n_in, n_out)
    s = 2 * h + 1
    step = chunk_bins(n_in, n_out, degree)
    G = np.empty((n_out, n_in, K), dtype=np.complex128)
    Cv = np.empty((n_out, n_out, K), dtype=np.complex128)
    Ainv = np.empty((n_in, n_in, K), dtype=np.complex128)
    grid, short = _pieces(req, s, h, step)

    def put(
        sv: _Solved, offsets: NDArray[np.intp], at: slice | NDArray[np.intp], sel: slice
    ) -> None:
        # the values of the solved windows ``sel`` at ``offsets``, to the bins ``at`` (in
        # the order window by window, offset by offset)
        g, ai = sv.around(offsets)
        D = offsets.size
        G[:, :, at] = g[:, :, sel].reshape(n_out, n_in, -1)
        pu, pv = (sv.iu, sv.ju) if isinstance(at, slice) else (sv.iu[:, None], sv.ju[:, None])
        a = ai[:, sel].reshape(ai.shape[0], -1)
        Ainv[pu, pv, at] = a
        Ainv[pv, pu, at] = np.conj(a)
        Cv[:, :, at] = np.repeat(sv.Cv[:, :, sel], D, axis=2)

    def nan(where: NDArray[np.intp]) -> int:
        G[:, :, where] = np.nan
        Cv[:, :, where] = np.nan
        Ainv[:, :, where] = np.nan
        return int(where.size)

    def settle(
        sv: _Solved,
        first: NDArray[np.intp],
        centre: NDArray[np.intp],
        length: NDArray[np.intp],
        pair: NDArray[np.bool_] | None = None,
    ) -> int:
        # the groups (output indices first.., centre bins, lengths) of the solved windows:
        # those whose off-centre bias shows solved at every centre, those without a window NaN
        redo = np.flatnonzero(sv.unsafe(s, h, pair) & ~sv.bad)
        if redo.size:
            out = _ranges(first[redo], length[redo])
            own = _ranges(centre[redo] - length[redo] // 2, length[redo])
            g, cv, ai, _ = centred(Ua, Ya, n, degree, q, 1, centres=own, offsets=0)
            G[:, :, out], Cv[:, :, out], Ainv[:, :, out] = g, cv, ai
        lost = np.flatnonzero(sv.bad)
        return nan(_ranges(first[lost], length[lost])) if lost.size else 0

    def run_grid(piece: tuple[int, int, int]) -> int:
        i0, c0, count = piece
        sv = _Solved(chunk_sums(Ua, Ya, c0, count, None, lay, stride=s), lay, q)
        put(sv, np.arange(-h, h + 1), slice(i0, i0 + count * s), slice(None))
        j = np.arange(count) * s
        return settle(sv, i0 + j, c0 + j, np.full(count, s))

    def run_short(batch: list[tuple[int, int, int]]) -> int:
        i0, c, t = (np.array(x, dtype=np.intp) for x in zip(*batch, strict=True))
        rows = (c[:, None] + np.arange(2 * n + 1)[None, :]).ravel()  # the windows, end to end
        sv = _Solved(
            chunk_sums(Ua[rows], Ya[rows], 0, c.size, None, lay, stride=2 * n + 1), lay, q
        )
        for length in np.unique(t).tolist():  # groups of one length: the same offsets
            sel = np.flatnonzero(t == length)
            offs = np.arange(length) - length // 2
            at = (i0[sel][:, None] + np.arange(length)[None, :]).ravel()
            put(sv, offs, at, sel)  # type: ignore[arg-type]
        # whole groups next to each other in a run: the same check as along a long run
        pair = (np.diff(c) == s) & (np.diff(i0) == s) & (t[:-1] == s) & (t[1:] == s)
        return settle(sv, i0, c, t, pair)

    jobs: list[Callable[[], int]] = [functools.partial(run_grid, p) for p in grid]
    jobs += [functools.partial(run_short, short[i : i + step]) for i in range(0, len(short), step)]
    n_bad = sum(thread_map(_call, jobs, workers))
    d = np.arange(n_out)
    Cv[d, d] = np.maximum(Cv[d, d].real, 0.0)
    return G, Cv, Ainv, n_bad
