# SPDX-License-Identifier: Apache-2.0
"""Best linear approximation from periodic multisine data: noise and nonlinear distortion.

Data: M realizations (independent random phases) of P periods of N samples of r, u, y
(steady state: drop the first periods before). Per realization m, excited line k,
period p: U_mp(k), Y_mp(k) (DFT of one period). Following Pintelon and Schoukens,
*System Identification: A Frequency Domain Approach*, 2nd ed. (2012), sec. 3.6 and 4.3
(the "robust method"):

- the period means Ū_m(k), Ȳ_m(k) keep what r drives, the noise averages out; their
  sample (co)variances over the P periods, divided by P, are the noise (co)variances of
  the means;
- per realization ``G_m = Ȳ_m / Ū_m``; with known periodic r this holds in closed loop as
  well (the noise is not periodic), and in the multirate loop too: the plant is LTI at
  the high rate, so y = P_h u at every high-rate line; with a design whose F lifted
  aliases do not collide (``mr-ident excite --lifted``), no other excited line's alias
  reaches line k through the sampled controller;
- noise variance of G_m (first order): ``(σ²_Y + |G_m|² σ²_U - 2 Re(conj(G_m) σ_YU)) / |Ū_m|²``;
- the BLA ``Ĝ = mean_m G_m``; its total variance ``var_m(G_m) / M`` (noise and the
  stochastic nonlinear contributions, which vary with the random phases); its noise
  variance ``mean_m(σ²_{G,m}) / M``; the nonlinear variance their difference (clipped at 0,
  the total then the noise's).

Unexcited lines between the excited ones show the distortion's kind: with an odd
design, even lines hold even nonlinear distortion, the left-out odd lines (detection
lines) odd distortion; their level is the mean power of Ȳ there less the noise's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray
from ..lifting import fold_half, unlift_bins


@dataclass(frozen=True)
class BLA:
    """The best linear approximation on the excited lines, and the distortion's levels.

    Attributes
    ----------
    lines : ndarray of int, shape (K,)
        Excited DFT lines of the period (frequency ``lines fs / N``).
    response : ndarray, shape (K,)
        The BLA.
    std, noise_std, nl_std : ndarray, shape (K,)
        Its total std, the part from noise, the part from stochastic nonlinear distortion
        (``std² = noise_std² + nl_std²``); noise_std is nan with one period, nl_std with
        one realization.
    odd_level, even_level : ndarray, shape (n_y,)
        Mean power of Ȳ over the unexcited odd (detection) and even lines in the excited
        band, less the noise's there (0 when within noise); nan without such lines.
    noise_level : ndarray, shape (n_y,)
        Mean noise power of Ȳ over the same lines.
    periods, realizations : int
    pfg, pfg_std : ndarray, shape (K,), optional
        The PFG from data at each excited line and its std (:func:`lifted_line_pfg`): nan
        at a line whose lifted bin holds another excited line.
    """

    lines: IntArray
    response: ComplexArray
    std: FloatArray
    noise_std: FloatArray
    nl_std: FloatArray
    odd_level: FloatArray
    even_level: FloatArray
    noise_level: FloatArray
    periods: int
    realizations: int
    pfg: FloatArray | None = None
    pfg_std: FloatArray | None = None

    @property
    def odd_db(self) -> FloatArray:
        """The odd distortion level in dB above the noise on those lines, shape (n_y,).

        ``10 log10((odd_level + noise) / noise)``, as :func:`distortion_by_band` counts
        (0 dB: noise only); nan without unexcited odd lines or a noise estimate.
        """
        return _above_noise_db(self.odd_level, self.noise_level)

    @property
    def even_db(self) -> FloatArray:
        """The even distortion level in dB above the noise, as :attr:`odd_db`."""
        return _above_noise_db(self.even_level, self.noise_level)


def _above_noise_db(level: FloatArray, noise: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore", invalid="ignore"):
        out: FloatArray = 10.0 * np.log10((level + noise) / noise)
    return out


def _periods(x: FloatArray, period: int, name: str) -> ComplexArray:
    """(M, P, N//2+1) spectra of every period of x (M, P·N)."""
    M, n = x.shape
    if n % period:
        raise ConfigError(
            f"{name} has {n} samples per realization, not a multiple of the period {period}"
        )
    return np.fft.rfft(x.reshape(M, n // period, period), axis=2)


def excited_lines(R: ComplexArray) -> IntArray:
    """Lines where r's mean period spectrum (first realization) is within 60 dB of its peak.

    A measured or quantised reference has a floor well above numerical zero.
    """
    Rm = np.abs(R[0].mean(axis=0))
    k = np.flatnonzero(Rm > 1e-3 * Rm.max())
    return k[k > 0].astype(np.int64)


def unexcited_lines(excited: IntArray, period: int, ratio: int = 1) -> IntArray:
    """Lines 1..N//2 that no excited line reaches: where only distortion and noise show.

    With F = ``ratio`` > 1 the sampled controller folds a line k of u and y onto its lifted
    family, the lines ``±k mod M + l M`` (M = N/F, l = 0..F-1): in a multirate closed loop
    those carry the *linear* response to line k, so they are no detection lines. A line
    is unexcited when no excited line's family holds it (F = 1: when it is not excited).

    Raises
    ------
    ConfigError
        ``period`` not a multiple of ``ratio`` (the loop is then not N-periodic).
    """
    if ratio < 1 or period % ratio:
        raise ConfigError(
            f"period must be a multiple of the ratio F = {ratio} for multirate periodic data, "
            f"got {period}"
        )
    M = period // ratio
    k = np.asarray(excited, np.int64)
    fam = np.concatenate([k % M, (-k) % M])[:, None] + M * np.arange(ratio)[None, :]
    reached = np.minimum(fam, period - fam).ravel()  # onto 0..N/2 (conjugate lines)
    out: IntArray = np.setdiff1d(np.arange(1, period // 2 + 1), reached)
    return out


@dataclass(frozen=True)
class BandLevels:
    """Per band (Hz): Ȳ's power over excited, unexcited odd and unexcited even lines.

    Each in dB above the noise power of Ȳ on those lines (nan without such lines).
    ``odd_threshold_db``, ``even_threshold_db``: the level that noise alone exceeds with
    probability :data:`LEVEL_ALPHA` on as many lines and periods (the ratio of the two
    means is F(2L, 2L(P-1)) distributed); few lines give a high threshold.
    """

    band: tuple[float, float]
    excited_db: float
    odd_db: float
    even_db: float
    odd_threshold_db: float = float("nan")
    even_threshold_db: float = float("nan")


#: False-alarm probability of a band's odd or even level under noise alone.
LEVEL_ALPHA = 1e-3


def noise_level_threshold_db(lines: int, periods: int, alpha: float = LEVEL_ALPHA) -> float:
    """The level (dB above the noise) that noise alone exceeds with probability ``alpha``.

    For the mean power of ``lines`` period means, the noise estimated from ``periods``
    periods (nan without a line or with one period). Under noise alone each line's |Ȳ|²
    is (σ²/P)·χ²₂/2 and its noise estimate (σ²/P)·χ²_{2(P-1)}/(2(P-1)): the ratio of the
    means over L lines is F(2L, 2L(P-1)).
    """
    if lines < 1 or periods < 2:
        return float("nan")
    import scipy.stats  # not at the top: identify's start-up stays light

    return float(10.0 * np.log10(scipy.stats.f.isf(alpha, 2 * lines, 2 * lines * (periods - 1))))


def distortion_by_band(
    r: FloatArray,
    y: FloatArray,
    period: int,
    fs: float,
    edges: FloatArray | None = None,
    *,
    ratio: int = 1,
) -> list[BandLevels]:
    """Levels above the noise per band between ``edges`` (Hz), from P >= 2 periods.

    ``r, y``: (M, P·N) or (P·N,); the first realization is used. The excited lines are
    those of :func:`excited_lines`; ``edges`` None: four log-spaced bands over them ([]
    with fewer than two). With an odd (or odd-odd) design, power at the unexcited odd lines
    is odd nonlinear distortion, at the even lines even distortion; near 0 dB it is noise
    only. ``ratio`` F of a multirate loop: the unexcited lines are those of
    :func:`unexcited_lines` (no excited line's lifted alias).
    """
    R, Y = (
        _periods(np.atleast_2d(np.asarray(a, float)), period, n) for a, n in ((r, "r"), (y, "y"))
    )
    P = Y.shape[1]
    if P < 2:
        raise ConfigError(f"levels above the noise need >= 2 periods, got {P}")
    Ym = Y[0].mean(axis=0)
    noise = np.sum(np.abs(Y[0] - Ym) ** 2, axis=0) / (P - 1) / P
    ex = excited_lines(R)
    free = unexcited_lines(ex, period, ratio)
    k = np.arange(Ym.size)
    f = k * fs / period
    if edges is None:
        if ex.size < 2:
            return []
        edges = np.geomspace(f[ex[0]], f[ex[-1]] * (1 + 1e-9), 5)
    out = []

    def db(which: IntArray) -> float:
        if which.size == 0:
            return float("nan")
        return float(10 * np.log10(np.mean(np.abs(Ym[which]) ** 2) / np.mean(noise[which])))

    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        inb = k[(f >= lo) & (f < hi) & (k > 0)]
        quiet = np.intersect1d(inb, free)
        odd, even = quiet[quiet % 2 == 1], quiet[quiet % 2 == 0]
        out.append(
            BandLevels(
                (float(lo), float(hi)),
                db(np.intersect1d(inb, ex)),
                db(odd),
                db(even),
                noise_level_threshold_db(odd.size, P),
                noise_level_threshold_db(even.size, P),
            )
        )
    return out


def best_linear_approximation(
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    period: int,
    lines: IntArray | None = None,
    *,
    ratio: int = 1,
) -> BLA:
    """The BLA of u -> y from M realizations of P periods (module docstring).

    ``r, u, y``: shape (M, P·N) (one channel each); ``lines``: the excited lines, else
    :func:`excited_lines`; ``ratio`` F of a multirate loop: the odd and even levels from
    :func:`unexcited_lines` (not the lifted aliases of the excited lines).
    ConfigError/DimensionError for shapes that do not fit, fewer than 2 periods and 2
    realizations together.
    """
    arrs = [np.atleast_2d(np.asarray(a, float)) for a in (r, u, y)]
    if not (arrs[0].shape == arrs[1].shape == arrs[2].shape):
        raise DimensionError(
            f"r, u, y must have one shape (M, P*N); got {[a.shape for a in arrs]}"
        )
    R, U, Y = (_periods(a, period, name) for a, name in zip(arrs, "ruy", strict=True))
    M, P = U.shape[:2]
    if P < 2 and M < 2:
        raise ConfigError(
            "the noise and nonlinear parts need at least 2 periods or 2 realizations; "
            "got 1 of each"
        )
    if lines is None:
        lines = excited_lines(R)
        lines = lines[lines > 0]
    lines = np.asarray(lines, np.int64)
    Um, Ym = U.mean(axis=1), Y.mean(axis=1)  # (M, L)
    Uk, Yk = Um[:, lines], Ym[:, lines]
    G = Yk / Uk  # (M, K)
    if P > 1:
        dU, dY = U - Um[:, None], Y - Ym[:, None]
        var_u = np.sum(np.abs(dU) ** 2, axis=1) / (P - 1) / P  # of the means, (M, L)
        var_y = np.sum(np.abs(dY) ** 2, axis=1) / (P - 1) / P
        cov_yu = np.sum(dY * np.conj(dU), axis=1) / (P - 1) / P
        var_g = (
            var_y[:, lines]
            + np.abs(G) ** 2 * var_u[:, lines]
            - 2 * np.real(np.conj(G) * cov_yu[:, lines])
        ) / np.abs(Uk) ** 2
        noise_var = np.maximum(var_g.mean(axis=0), 0.0) / M
    else:
        var_y = np.full(Ym.shape, np.nan)
        noise_var = np.full(lines.size, np.nan)
    bla = G.mean(axis=0)
    total_var = np.var(G, axis=0, ddof=1) / M if M > 1 else noise_var.copy()
    nl_var = np.maximum(total_var - noise_var, 0.0) if M > 1 else np.full(lines.size, np.nan)
    if M > 1 and P > 1:  # a spread below the noise's is the noise's (std² = noise² + nl²)
        total_var = noise_var + nl_var
    # the unexcited lines inside the excited band: odd (detection) and even
    band = np.arange(lines.min(), lines.max() + 1) if lines.size else np.zeros(0, np.int64)
    quiet = np.intersect1d(band, unexcited_lines(lines, period, ratio))
    power = np.mean(np.abs(Ym) ** 2, axis=0)  # (L,)
    noise_p = np.mean(var_y, axis=0) if P > 1 else np.full(power.shape, np.nan)

    def level(which: IntArray) -> tuple[float, float]:
        if which.size == 0:
            return float("nan"), float("nan")
        nz = float(np.mean(noise_p[which]))
        return max(float(np.mean(power[which])) - nz, 0.0), nz

    pfg, pfg_std = lifted_line_pfg(
        R.mean(axis=1), Ym, var_y if P > 1 else None, lines, period, ratio
    )
    odd_l, nz_odd = level(quiet[quiet % 2 == 1])
    even_l, nz_even = level(quiet[quiet % 2 == 0])
    known = [v for v in (nz_odd, nz_even) if np.isfinite(v)]
    noise_level = float(np.mean(known)) if known else float("nan")
    return BLA(
        lines,
        bla,
        np.sqrt(total_var),
        np.sqrt(noise_var),
        np.sqrt(nl_var),
        np.array([odd_l]),
        np.array([even_l]),
        np.array([noise_level]),
        int(P),
        int(M),
        pfg,
        pfg_std,
    )


#: The source of a PFG measured at the lines of a lifted design (:func:`lifted_line_pfg`).
LINE_PFG_SOURCE = "data:lifted lines"


def lifted_line_pfg(
    R: ComplexArray,
    Y: ComplexArray,
    var_y: FloatArray | None,
    lines: IntArray,
    period: int,
    ratio: int,
) -> tuple[FloatArray, FloatArray]:
    """The PFG from data at each excited line of a lifted design, and its std.

    The PFG at line kappa is the 2-norm of block column l of the lifted closed-loop map
    J(k), k = kappa mod M, M = period / F (:mod:`~mr_ident.numerics.lifted.pfg`). Where kappa is
    the only excited line in its lifted bin (and in its conjugate's: ``mr-ident excite
    --lifted``), r excites that column alone, so in periodic steady state it is measured
    exactly: the output's F aliases over r at kappa,
    ``J(k)[:, l] = [Y(k + i M)]_i / R(kappa)``, averaged over realizations; no local model
    and no alias range (:mod:`~mr_ident.numerics.lifted.alias_range`) enter. Elsewhere nan.

    ``R, Y``: (M_r, period//2+1) period-mean spectra of r and y per realization;
    ``var_y``: the noise variance of Y (same shape) or None; the std is first order in the
    variance of the column's entries (the larger of the noise's and the spread over
    realizations), ``var |c| = sum |c_i|² v_i / (2 |c|²)``.
    """
    K = lines.size
    nan = np.full(K, np.nan)
    if K == 0 or ratio < 1 or period % ratio:
        return nan, nan.copy()
    F, Ml = int(ratio), period // int(ratio)
    a, b = lines % Ml, (-lines) % Ml
    count = np.bincount(np.concatenate([a, b]), minlength=Ml)
    alone = (count[a] == 1) & (count[b] == 1)  # a == b counts twice: never alone
    half, flip = fold_half(unlift_bins(a, F, period), period)  # (K, F) aliases, in 0..N//2

    def full(X: ComplexArray) -> ComplexArray:
        Xa = X[:, half]
        return np.where(flip[None], np.conj(Xa), Xa)

    Rk = R[:, lines][:, :, None]  # (M_r, K, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cols = full(Y) / Rk  # (M_r, K, F)
        c = cols.mean(axis=0)
        n_real = cols.shape[0]
        v = np.zeros(c.shape)
        if n_real > 1:
            v = np.var(cols, axis=0, ddof=1) / n_real
        if var_y is not None:
            noise = np.mean(var_y[:, half] / np.abs(Rk) ** 2, axis=0) / n_real
            v = np.maximum(v, noise)
        gain = np.linalg.norm(c, axis=1)
        std = np.sqrt(np.sum(np.abs(c) ** 2 * v, axis=1) / (2 * gain**2))
    if n_real < 2 and var_y is None:
        std = nan.copy()
    return np.where(alone, gain, np.nan), np.where(alone, std, np.nan)
