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
lines, each as its SNR allows. Per segment m and block j of lines (contiguous in the
lines' bins folded onto the low rate, :func:`fold_bins`: a lifted fit's aliases and their
conjugates share its windows) the relative change ``D_mj = S_mj / W_j``, the weighted
least-squares fit of ``G_m - Ḡ = D_mj Ḡ`` over the block's lines: ``S_mj = Σ_k g_k (G_mk
- Ḡ_k)``, ``g_k = conj(Ḡ_k) / σ²_k``, ``W_j = Σ_k h²_k``, ``h_k = |Ḡ_k| / σ_k``. Under a
time-invariant loop each line's relative error, turned to Ḡ's phase and scaled by its
SNR, ``z_mk = g_k (G_mk - G_k) / h_k``, has variance s² (a scale the test never needs:
the LPM's σ² may be off by a factor) and correlates over the lines of one fit as the local
fit's overlapping windows make it, ``E z_k conj(z_k') = s² ρ(|k - k'|)``: ρ the local
polynomial's kernel (``lpm_kernel(n, R)`` of ``numerics.fit.frf_fit``: the centre
weights' autocorrelation) for lines on one branch of the folding (a half of a low-rate
period, ``2k // (N/F)``: one fit's neighbours, k and k' both on the grid's bins), 0
otherwise. So ``S_mj = Σ_k h_k z_mk`` and the block vector ``D_m`` is complex normal with
covariance ``s² C``,

    ``C_jj' = Σ_{k in j, k' in j'} h_k h_k' ρ(|k - k'|) / (W_j W_j')``,

independent over the segments (whose mean takes one of them away: M - 1 remain). A change
common to every line, ``D_mj = δ_m``, has the generalized least-squares estimate ``δ_m =
1ᵀC⁻¹D_m / u``, ``u = 1ᵀC⁻¹1``: ``u Σ_m |δ_m|²`` is ``s² χ²(2(M - 1)) / 2``, the
residual ``Σ_m (D_m - δ_m 1)ᴴ C⁻¹ (D_m - δ_m 1)`` is ``s² χ²(2(M - 1)(J - 1)) / 2`` and
independent of it: per degree of freedom their ratio is F(2(M - 1), 2(M - 1)(J - 1))
whatever s². Uncorrelated lines (``ρ = [1]``) make ``C = diag(1 / W_j)`` and the test the
plain F test of the segments' change against the blocks' scatter, which needs blocks two
windows wide to stay calibrated (neighbours then correlate by 0.03): a 10 s record at
240 Hz, F = 5 held no two of them, at F = 3 two or three. With C the blocks can be half a
window wide (n + 1 folded bins; neighbours correlate by about 0.15 through C; a quarter
window: 0.6, where the kernel's accuracy would decide), :data:`BLOCKS` at most (wider
where the lines allow). Named also where the false-alarm probability is below
:data:`POOLED_ALPHA`. Measured on the benchmark's loops (docs/diagnose.md): the LPM's
errors correlate a little less than the kernel says (ρ(1) 0.77-0.86 against 0.92;
neighbouring half-window blocks 0.11-0.15 against 0.15) and its σ² differs from the
segments' scatter by band (0.6-0.8 of it in the lowest blocks, 1.1-1.3 in the highest),
both of which leave the test conservative there. Neither it nor the level names a record
with missing samples (it is not computed there; the level is reported): each hole's
estimate errs in every bin of its segment alike (its column ``e^{-j2πkm/N}``), an error
correlated over all the lines, as the kernel does not say, and a common change of the
lines is what both look for (at 2 % of u and y missing the pooled test named 24 of 1120
time-invariant benchmark records, p down to 1e-33; at 5 % the level named 3 of 280,
2.0-11.2 dB).

A third test pools the whole band into one gain per segment, in time
(:mod:`.gain_drift`: the instrumental-variable gain of the plant model's output driven by
the measured u, the closed-loop prediction from r the instrument, against a long-run
variance from the record's spectra); named also below :data:`DRIFT_ALPHA`.

Segments: a random record is cut into :data:`SEGMENTS` equal parts (multiples of F),
fewer where a part would be shorter than diagnose takes; a periodic one into whole
periods, at least 4 per segment (the first is dropped as transient); none when fewer than
two segments fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import DataError
from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.identify import min_samples
from ...numerics.local.lpm import grid_bins
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .gain_drift import GainDrift, gain_drift
from .realizations import SpreadLevels, aligned, levels

#: Segments a record is cut into (at most).
SEGMENTS = 4
#: Mean per-line spread over noise (dB) above which the plant is named time-varying. Under
#: a time-invariant loop the statistic sits near 0 dB (at most 0.99 dB over 1120 records of
#: the benchmark's random loops, 10 and 30 s of white r, nothing or one cause hidden, a
#: pole-zero pair or a second delay path: benchmarks/bench_timevarying.py); a gain moving
#: by 10-30 % with a period of 0.3-1 record reached 1.5 dB in 72 of 100 10 s records.
VARYING_DB = 1.5
#: False-alarm probability of the pooled relative change (module docstring) below which
#: the plant is named time-varying (calibration: docs/diagnose.md,
#: benchmarks/bench_timevarying.py).
POOLED_ALPHA = 1e-4
#: False-alarm probability of the segments' time-domain gains (:mod:`.gain_drift`) below
#: which the plant is named time-varying (Bonferroni with :data:`POOLED_ALPHA`: the two
#: p-tests together false-alarm with at most their sum).
DRIFT_ALPHA = 1e-4
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
    f: FloatArray,
    G: ComplexArray,
    V: FloatArray,
    *,
    df: float,
    low_bins: int,
    window: int,
    degree: int = 2,
) -> Pooled | None:
    """The pooled relative change of the estimates ``G`` (M, K, e) (module docstring).

    ``V`` their noise variances (the weights); ``df`` the spacing of the grid the lines
    ``f`` (K,) lie on, ascending (Hz: ``fs_high`` over the segment's samples); ``low_bins``
    the low-rate bins of that grid, ``N / F`` (a lifted fit's window at low-rate bin m
    serves every high-rate bin k with ``k mod N/F`` equal to m or ``N/F - m``, so the lines
    are folded onto ``min(m, N/F - m)``; 0: not folded); ``window`` the fit's width in
    those bins (2n + 1) and ``degree`` its polynomial's (the kernel ρ). None where fewer
    than two blocks half a window wide fit.
    """
    import scipy.stats  # not at the top: identify's start-up stays light

    if df <= 0:
        raise ValueError(f"df must be positive (Hz), got {df}")
    M = G.shape[0]
    mean, var = G.mean(axis=0), V.mean(axis=0)
    ok = np.isfinite(mean) & np.isfinite(var) & (var > 0) & (np.abs(mean) > 0)
    ok &= np.all(np.isfinite(G), axis=0)
    safe = np.where(ok, var, 1.0)
    h = np.where(ok, np.abs(mean) / np.sqrt(safe), 0.0)  # (K, e): sqrt of the weights
    g = np.where(ok, np.conj(mean) / safe, 0.0)
    dev = np.where(ok, G - mean, 0.0)  # (M, K, e)
    folded = fold_bins(f, df, low_bins)
    lo, hi = int(folded.min()), int(folded.max()) + 1  # the blocks cover [lo, hi) bins
    J = min((hi - lo) // (window // 2 + 1), BLOCKS)  # wider where the lines allow
    if J < 2:  # narrower blocks would lean on the kernel's accuracy
        return None
    edges = np.linspace(lo, hi, J + 1)
    block = np.clip(np.searchsorted(edges, folded, side="right") - 1, 0, J - 1)
    W = np.zeros(J)
    S = np.zeros((M, J), dtype=complex)
    for e in range(g.shape[1]):
        W += np.bincount(block, h[:, e] ** 2, J)
        for m in range(M):
            x = g[:, e] * dev[m, :, e]
            S[m] += np.bincount(block, x.real, J) + 1j * np.bincount(block, x.imag, J)
    k = grid_bins(f, df)
    piece = 2 * k // low_bins if low_bins > 0 else np.zeros_like(k)  # one fit's neighbours
    C = _block_covariance(k, piece, block, h, J, (window - 1) // 2, degree=degree)
    used = W > 0
    J = int(np.count_nonzero(used))
    if J < 2:
        return None
    Wa = W[used]
    D = S[:, used] / Wa  # (M, J)
    C = C[np.ix_(used, used)] / np.outer(Wa, Wa)
    try:
        Ci1 = np.linalg.solve(C, np.ones(J))  # C⁻¹ 1 (C real symmetric)
        u = float(np.sum(Ci1))
        delta = D @ Ci1 / u  # 1ᵀC⁻¹D_m
        R = D - delta[:, None]
        res = float(np.real(np.sum(np.conj(R) * np.linalg.solve(C, R.T).T)))
    except np.linalg.LinAlgError:
        return None
    num = u * float(np.sum(np.abs(delta) ** 2)) / (M - 1)
    den = res / ((M - 1) * (J - 1))
    d1, d2 = 2 * (M - 1), 2 * (M - 1) * (J - 1)
    ratio = num / den if den > 0 else math.inf
    p = float(scipy.stats.f.sf(ratio, d1, d2))
    change = math.sqrt(float(np.mean(np.abs(delta) ** 2)))
    return Pooled(change, ratio, (d1, d2), p, J, int(folded.size))


def _block_covariance(
    k: np.ndarray,
    piece: np.ndarray,
    block: np.ndarray,
    h: FloatArray,
    J: int,
    n: int,
    *,
    degree: int,
) -> FloatArray:
    """``Σ h_k h_k' ρ(|k - k'|)`` over the lines of blocks j, j' (module docstring).

    ``k`` (K,) the lines' bins on the grid, ascending; ``piece`` the branch of the folding
    each lies on (``2k // (N/F)``: the half of a low-rate period, over which the folded
    bin moves with k), pairs counted within one only; ``block`` (K,) each line's block
    (< J); ``h`` (K, e); ``n``, ``degree`` the fit's half-width and degree (the kernel
    ρ, of reach 2n).
    """
    from ...numerics.fit.frf_fit import lpm_kernel  # not at the top: start-up stays light

    rho = lpm_kernel(n, degree)
    C = np.zeros((J, J))
    for e in range(h.shape[1]):
        np.add.at(C, (block, block), h[:, e] ** 2)
    for lag in range(1, rho.size):
        at = np.minimum(np.searchsorted(k, k + lag), k.size - 1)
        pair = (k[at] == k + lag) & (piece[at] == piece)
        a, b = np.nonzero(pair)[0], at[pair]
        for e in range(h.shape[1]):
            v = rho[lag] * h[a, e] * h[b, e]
            np.add.at(C, (block[a], block[b]), v)
            np.add.at(C, (block[b], block[a]), v)
    return C


def fold_bins(f: FloatArray, df: float, low_bins: int) -> np.ndarray:
    """The lines ``f`` as bins of the grid ``df``, folded onto the low rate (:func:`pooled`).

    ``k = rint(f / df)``, ``m = k mod low_bins``, ``min(m, low_bins - m)``; ``k`` where
    ``low_bins`` is 0.
    """
    k = grid_bins(f, df)
    if low_bins <= 0:
        return k
    m = np.mod(k, low_bins)
    return np.minimum(m, low_bins - m)


@dataclass(frozen=True)
class Segments:
    """A record's segments compared (module docstring).

    ``bands``: their spread per band (:class:`~.realizations.SpreadLevels`); ``parts``:
    how many segments; ``level_db``: the mean per-line spread over noise, dB. Where a
    segment's missing samples are more than its lifted fit carries (DataError), ``bands``
    empty, ``level_db`` NaN and ``pooled`` None: the time-domain gains alone. ``lossy``:
    the record has missing samples, so neither the level nor the pooled test names it (a
    hole errs in every line of its segment alike): the time-domain gains alone decide.
    """

    bands: list[SpreadLevels]
    parts: int
    level_db: float
    pooled: Pooled | None = None
    drift: GainDrift | None = None
    lossy: bool = False

    @property
    def varying(self) -> bool:
        """The segments differ beyond their noise (module docstring).

        The level above :data:`VARYING_DB`, the pooled relative change's false-alarm
        probability below :data:`POOLED_ALPHA` or the segments' time-domain gains'
        (:mod:`.gain_drift`) below :data:`DRIFT_ALPHA`.
        """
        return (
            (not self.lossy and math.isfinite(self.level_db) and self.level_db > VARYING_DB)
            or (self.pooled is not None and self.pooled.p < POOLED_ALPHA)
            or (self.drift is not None and self.drift.p < DRIFT_ALPHA)
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
        drift = self.drift
        if drift is not None and drift.p < DRIFT_ALPHA:
            gain += (
                f"; its gain, one per segment of {len(drift.gains)} in time, moves by "
                f"{100 * drift.change:.0f} % rms (p = {drift.p:.1g})"
            )
        if not self.bands or self.lossy:  # missing samples: the gains decided
            return (
                f"the plant changes within the record: {gain.removeprefix('; ')} (a "
                "time-invariant model, and any correction of one, describes the average "
                "over the record)"
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
    try:
        got = aligned(segs, model, n=n, degree=degree, realizations=False)
    except DataError:  # a segment's holes past what its lifted fit carries: the gains alone
        drift = gain_drift(rec, model)
        return None if drift is None else Segments([], len(segs), math.nan, None, drift, True)
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
    lossy = bool(np.isnan(rec.u).any() or np.isnan(rec.y).any())  # not done (above)
    pool = (
        None
        if lossy
        else pooled(
            *got[:3],
            df=model.fs_high / grid,
            low_bins=grid // unit,
            window=2 * n + 1,
            degree=degree,
        )
    )
    return Segments(bands, len(segs), level, pool, gain_drift(rec, model), lossy)
