# SPDX-License-Identifier: Apache-2.0
"""Does the plant change within a record? The estimates of its segments compared.

A time-invariant loop gives the same FRF from every stretch of a record: the plant
estimates of consecutive segments differ by their noise alone, whatever the excitation
(under a random r each segment is another realization, whose nonlinear distortion the
LPM's noise already holds; under a periodic r the same realization repeats, distortion
included). A plant whose gain or dynamics change during the record (a load, a
temperature, a wearing part, a gain scheduled on the operating point) gives segment
estimates that differ beyond their noise. The spread is the one across records
(:func:`~.realizations.levels`, the :data:`SEGMENTS` segments as the M estimates); the
statistic is each line's own ratio ``s²(k) / σ²(k)`` (spread over noise) averaged over
every common line, in dB (``SpreadLevels.line_ratio_db``, weighted by the bands' lines):
a gain that drifts moves every line by the same relative amount, so each line counts
alike, not the noisiest most. Named above :data:`VARYING_DB`. No time-invariant model, nor
any correction of one, describes such a plant: it describes the plant's average over the
record.

A change that moves every line alike (a gain) is tested with more power by pooling the
lines, each as its SNR allows: per segment m and block j of lines the relative change
``D_mj``, the weighted least-squares fit of ``G_m - Ḡ = D_mj Ḡ`` over the block's lines
(weights ``|Ḡ|² / σ²``, summing to ``W_j``), and over all blocks ``δ_m`` (weights
``W_j``). The segments' change ``W Σ_m |δ_m|² / (M - 1)`` is held against the blocks'
scatter about it, ``Σ_j W_j Σ_m |D_mj - δ_m|² / ((M - 1)(J - 1))``: under a
time-invariant loop their ratio is F(2(M - 1), 2(M - 1)(J - 1)) whatever the scale of the
LPM's σ² and however neighbouring lines correlate (a local fit's windows overlap, which
made a χ² over the lines 2-10 times too large on time-invariant loops); the blocks are
contiguous in the lines' bins folded onto the low rate (:func:`fold_bins`: a lifted fit's
aliases and their conjugates share its windows), at least two windows wide, at most
:data:`BLOCKS`. Named also where its
false-alarm probability is below :data:`POOLED_ALPHA`.

Segments: a random record is cut into :data:`SEGMENTS` equal parts (multiples of F),
fewer where a part would be shorter than diagnose takes; a periodic one into whole
periods, at least 4 per segment (the first is dropped as transient); none when fewer than
two segments fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.identify import min_samples
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .realizations import SpreadLevels, aligned, levels

#: Segments a record is cut into (at most).
SEGMENTS = 4
#: Mean per-line spread over noise (dB) above which the plant is named time-varying. Under
#: a time-invariant loop the statistic sits near 0 dB (at most 0.88 dB over 320 records of
#: the benchmark's random loops, 10 and 30 s of white r, nothing or one cause hidden, a
#: pole-zero pair or a second delay path: 2026-11-26); a gain moving by 10-30 % over a few
#: seconds of a 10 s record reached 1.5 dB in 20 of 25.
VARYING_DB = 1.5
#: False-alarm probability of the pooled relative change (module docstring) below which
#: the plant is named time-varying. The test is calibrated: over 320 time-invariant records
#: of the benchmark's random loops (10 s of white r; nothing or one cause hidden, a
#: pole-zero pair, a second delay path) its smallest p was 9e-4, as 320 uniform draws give;
#: it named 36 of 40 time-varying gains (10-30 %), the level alone 32 (2026-11-26, with the
#: blocks stuck at 12 by a bug since fixed: docs/diagnose.md says what changed).
POOLED_ALPHA = 1e-4
#: Most blocks of lines the pooled test compares the segments' change against.
BLOCKS = 12


@dataclass(frozen=True)
class Pooled:
    """The segments' relative change pooled over the lines (module docstring).

    ``change``: the rms over the segments of ``|δ_m - δ̄|`` (relative: 0.1 is 10 %);
    ``ratio``: the F ratio of the change against the blocks' scatter, with ``dof`` (the
    numerator's and the denominator's); ``p``: the probability that noise alone reaches it;
    ``blocks``: how many; ``lines``: the lines they hold (every usable one).
    """

    change: float
    ratio: float
    dof: tuple[int, int]
    p: float
    blocks: int
    lines: int = 0


def pooled(
    f: FloatArray, G: ComplexArray, V: FloatArray, *, df: float, low_bins: int, window: int
) -> Pooled | None:
    """The pooled relative change of the estimates ``G`` (M, K, e) (module docstring).

    ``V`` their noise variances (the weights); ``df`` the spacing of the grid the lines
    ``f`` lie on (Hz: ``fs_high`` over the segment's samples); ``low_bins`` the low-rate
    bins of that grid, ``N / F`` (a lifted fit's window at low-rate bin m serves every
    high-rate bin k with ``k mod N/F`` equal to m or ``N/F - m``, so the lines are folded
    onto ``min(m, N/F - m)``; 0: not folded); ``window`` the fit's width in those bins.
    None where fewer than two blocks two windows wide fit.
    """
    import scipy.stats  # not at the top: identify's start-up stays light

    if df <= 0:
        raise ValueError(f"df must be positive (Hz), got {df}")
    M = G.shape[0]
    mean, var = G.mean(axis=0), V.mean(axis=0)
    ok = np.isfinite(mean) & np.isfinite(var) & (var > 0) & (np.abs(mean) > 0)
    ok &= np.all(np.isfinite(G), axis=0)
    safe = np.where(ok, var, 1.0)
    w = np.where(ok, np.abs(mean) ** 2 / safe, 0.0)  # (K, e)
    g = np.where(ok, np.conj(mean) / safe, 0.0)
    dev = np.where(ok, G - mean, 0.0)  # (M, K, e)
    folded = fold_bins(f, df, low_bins)
    lo, hi = int(folded.min()), int(folded.max()) + 1  # the blocks cover [lo, hi) bins
    J = min((hi - lo) // (2 * window), BLOCKS)
    if J < 2:  # narrower blocks share windows: their scatter would understate the noise
        return None
    edges = np.linspace(lo, hi, J + 1)
    W, D, lines = [], [], 0
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        sel = (folded >= a) & (folded < b)
        wj = float(w[sel].sum())
        lines += int(np.count_nonzero(sel))
        if wj > 0:
            W.append(wj)
            D.append(np.sum(g[sel] * dev[:, sel], axis=(1, 2)) / wj)
    if len(W) < 2:
        return None
    Wa, Da = np.array(W), np.array(D).T  # (J,), (M, J)
    delta = Da @ Wa / Wa.sum()  # (M,)
    J = Wa.size
    num = Wa.sum() * float(np.sum(np.abs(delta) ** 2)) / (M - 1)
    den = float(np.sum(Wa * np.abs(Da - delta[:, None]) ** 2)) / ((M - 1) * (J - 1))
    d1, d2 = 2 * (M - 1), 2 * (M - 1) * (J - 1)
    ratio = num / den if den > 0 else math.inf
    p = float(scipy.stats.f.sf(ratio, d1, d2))
    change = math.sqrt(float(np.mean(np.abs(delta) ** 2)))
    return Pooled(change, ratio, (d1, d2), p, J, lines)


def fold_bins(f: FloatArray, df: float, low_bins: int) -> np.ndarray:
    """The lines ``f`` as bins of the grid ``df``, folded onto the low rate (:func:`pooled`).

    ``k = rint(f / df)``, ``m = k mod low_bins``, ``min(m, low_bins - m)``; ``k`` where
    ``low_bins`` is 0.
    """
    k = np.rint(np.asarray(f, dtype=float) / df).astype(np.int64)
    if low_bins <= 0:
        return k
    m = np.mod(k, low_bins)
    return np.minimum(m, low_bins - m)


@dataclass(frozen=True)
class Segments:
    """A record's segments compared (module docstring).

    ``bands``: their spread per band (:class:`~.realizations.SpreadLevels`); ``parts``:
    how many segments; ``level_db``: the mean per-line spread over noise, dB.
    """

    bands: list[SpreadLevels]
    parts: int
    level_db: float
    pooled: Pooled | None = None

    @property
    def varying(self) -> bool:
        """The segments differ beyond their noise (module docstring).

        The level above :data:`VARYING_DB`, or the pooled relative change's false-alarm
        probability below :data:`POOLED_ALPHA`.
        """
        return (math.isfinite(self.level_db) and self.level_db > VARYING_DB) or (
            self.pooled is not None and self.pooled.p < POOLED_ALPHA
        )

    def text(self) -> str:
        """The finding in words, with its level per band, or ""."""
        if not self.varying:
            return ""
        per = ", ".join(
            f"{b.band[0]:.3g}-{b.band[1]:.3g} Hz {b.line_ratio_db:.1f} dB" for b in self.bands
        )
        pool = self.pooled
        gain = (
            f"; their gain moves by {100 * pool.change:.0f} % rms (pooled over the lines, "
            f"p = {pool.p:.1g})"
            if pool is not None and pool.p < POOLED_ALPHA
            else ""
        )
        return (
            f"the plant changes within the record: the plant estimates of its {self.parts} "
            f"consecutive segments differ beyond their noise, {self.level_db:.1f} dB on "
            f"average over the lines ({per}){gain} (a time-invariant model, and any "
            "correction of one, describes the average over the record)"
        )


def segments(rec: LoopData, n: int, parts: int = SEGMENTS) -> list[LoopData]:
    """``rec`` cut into up to ``parts`` consecutive equal segments (module docstring)."""
    if parts < 2:
        raise ValueError(f"parts must be at least 2, got {parts}")
    unit = rec.ratio or 1
    if rec.period is not None:
        periods = rec.n_samples // rec.period
        k = min(parts, periods // 4)
        size = periods // max(k, 1) * rec.period
    else:
        k = min(parts, rec.n_samples // (2 * min_samples("freq-lifted", n, unit)))
        size = rec.n_samples // max(k, 1) // unit * unit
    if k < 2:
        return []
    return [rec.part(j * size, (j + 1) * size) for j in range(k)]


def within(rec: LoopData, model: Model, *, n: int = 8, degree: int = 2) -> Segments | None:
    """``rec``'s segments compared (:class:`Segments`); None when fewer than two fit."""
    segs = segments(rec, n)
    if len(segs) < 2:
        return None
    got = aligned(segs, model, n=n, degree=degree, realizations=False)
    if got is None:
        return None
    bands = levels(*got)
    lines = sum(b.lines for b in bands)
    if not lines:
        return None
    mean = sum(b.lines * 10.0 ** (b.line_ratio_db / 10.0) for b in bands) / lines
    level = 10.0 * math.log10(mean) if mean > 0 else -math.inf
    unit = rec.ratio or model.ratio
    grid = rec.period if rec.period is not None else segs[0].n_samples  # the lines' grid
    pool = pooled(*got[:3], df=model.fs_high / grid, low_bins=grid // unit, window=2 * n + 1)
    return Segments(bands, len(segs), level, pool)
