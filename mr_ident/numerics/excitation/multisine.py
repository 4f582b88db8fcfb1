# SPDX-License-Identifier: Apache-2.0
"""Periodic multisine excitation: lines, random phases, a low crest factor.

A multisine of period N samples at fs excites DFT lines k (frequency ``k fs / N``) with
amplitudes A_k and phases φ_k: ``r[n] = sum_k 2 A_k cos(2π k n / N + φ_k)``, scaled to the
asked RMS. Designs (Pintelon and Schoukens, *System Identification: A Frequency Domain
Approach*, 2nd ed., 2012, ch. 5):

- ``full``: every line in the band;
- ``odd``: the odd lines (even nonlinear distortion then falls on the unexcited even lines);
- ``odd-random``: the odd lines, of every group of ``group`` consecutive odd lines one left
  out at random (a *detection line*: odd nonlinear distortion shows there).

Phases are random (uniform), then the crest factor ``max |r| / rms(r)`` is lowered by
iterative clipping in the time domain with the amplitudes restored in the frequency
domain (Van der Ouderaa, Schoukens and Renneboog, "Peak factor minimization using a
time-frequency domain swapping algorithm", IEEE Trans. Instrum. Meas. 37(1), 1988).

**Multirate** (``ratio`` F): in frequency lifting the N-sample period has M = N/F low-rate
bins, and lifted bin κ collects the high-rate lines κ + l M (l = 0..F-1), negative
frequencies included (line N - k is the conjugate of line k). ``lifted=True`` keeps, in
increasing frequency, only lines whose alias family and its conjugate's are still free, so
that each lifted bin sees at most one excited alias. ``rotate=True`` (with ``lifted``)
moves, in realization m, every line m places along its *alias family* (the F lines in
(0, N/2] whose lifted bin is its own or its conjugate's), so that F realizations excite
every alias of every lifted bin once: the lifted input then has full rank F over the
realizations, which an output measured at the low rate needs
(:mod:`~mr_ident.numerics.lifted.slow_periodic`); the family reaches beyond the band, up to
fs/2.

**Several inputs**: the excited lines are dealt out in turn (input i gets lines i, i + n_u,
...): the inputs' spectra never share a line, so they are orthogonal over every period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, FieldError
from ..arrays import FloatArray, IntArray

#: The designs of :func:`design`.
KINDS = ("full", "odd", "odd-random")


@dataclass(frozen=True)
class Multisine:
    """A multisine design and its signals.

    Attributes
    ----------
    r : ndarray, shape (M, P * N, n_in)
        M realizations (independent random phases), P periods of N samples, n_in inputs.
    fs_high : float
    period : int
        N, samples per period.
    lines : ndarray of int, shape (n_in, L)
        Excited DFT lines of each input (frequency ``lines * fs_high / period``); -1 pads
        an input with fewer lines.
    detection : ndarray of int, shape (D,)
        Odd lines left out on purpose (``odd-random``); empty otherwise.
    kind : str
    crest_factor : ndarray, shape (M, n_in)
        ``max |r| / rms(r)`` over one period.
    realization_lines : ndarray of int, shape (M, n_in, L), optional
        A rotated design's lines per realization (``lines`` is the first's); None when
        every realization excites ``lines``.
    """

    r: FloatArray
    fs_high: float
    period: int
    lines: IntArray
    detection: IntArray
    kind: str
    crest_factor: FloatArray
    realization_lines: IntArray | None = None

    @property
    def frequencies(self) -> FloatArray:
        """Excited frequencies (Hz) of every input together, sorted."""
        k = self.lines[self.lines >= 0]
        return np.sort(k) * self.fs_high / self.period


def band_lines(fs_high: float, period: int, band: tuple[float, float]) -> IntArray:
    """The DFT lines 1 <= k < N/2 with ``band[0] <= k fs / N <= band[1]``."""
    lo, hi = band
    nyq = fs_high / 2
    if not (0 <= lo < hi):
        raise ConfigError(f"band must be LO,HI with 0 <= LO < HI, got {lo:g},{hi:g}")
    if hi > nyq:
        raise ConfigError(f"band must end at or below fs_high/2 = {nyq:g} Hz, got {hi:g} Hz")
    k = np.arange(1, (period + 1) // 2)
    f = k * fs_high / period
    out = k[(f >= lo) & (f <= hi)]
    if out.size == 0:
        raise ConfigError(
            f"no line of a {period}-sample period (resolution {fs_high / period:g} Hz) lies "
            f"in {lo:g}-{hi:g} Hz: widen the band or lengthen the period"
        )
    return out


def choose_lines(
    candidates: IntArray,
    kind: str,
    rng: np.random.Generator,
    *,
    group: int = 3,
) -> tuple[IntArray, IntArray]:
    """(excited, detection) lines of ``kind`` among ``candidates`` (see the module)."""
    if kind not in KINDS:
        raise ConfigError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    empty = np.zeros(0, np.int64)
    if kind == "full":
        return candidates.astype(np.int64), empty
    odd = candidates[candidates % 2 == 1].astype(np.int64)
    if kind == "odd" or odd.size == 0:
        return odd, empty
    if group < 2:
        raise ConfigError(f"group must be >= 2 odd lines, got {group}")
    n_groups = odd.size // group
    drop = np.arange(n_groups) * group + rng.integers(0, group, n_groups)
    keep = np.ones(odd.size, bool)
    keep[drop] = False
    return odd[keep], odd[drop]


def unaliased(lines: IntArray, period: int, ratio: int) -> IntArray:
    """``lines`` without those whose lifted bin (or its conjugate's) is taken already.

    Lifted bin of line k: ``k mod M``, M = period / ratio; the conjugate line N - k falls in
    ``(-k) mod M``. Lower lines are kept first; a line with ``2k = 0 mod M`` (at a multiple
    of fs_low/2) never, since it meets its own conjugate.
    """
    if period % ratio:
        raise ConfigError(
            f"period must be a multiple of ratio F = {ratio} for lifted lines, got {period}"
        )
    M = period // ratio
    used = np.zeros(M, bool)
    keep = []
    for k in np.sort(lines):  # a loop over the lines of one design, not per sample or bin
        a, b = int(k % M), int((-k) % M)
        if a == b:  # 2k = 0 mod M: the line meets its own conjugate in one lifted bin
            continue
        if not (used[a] or used[b]):
            used[a] = used[b] = True
            keep.append(int(k))
    return np.asarray(keep, np.int64)


def alias_family(line: int, period: int, ratio: int) -> IntArray:
    """The lines in (0, N/2] whose lifted bin is ``line``'s or its conjugate's, increasing.

    F of them (a line at a multiple of fs_low/2 is its own conjugate's: fewer).
    """
    M = period // ratio
    k = np.arange(1, period // 2 + 1)
    a = line % M
    out: IntArray = k[(k % M == a) | ((-k) % M == a)]
    return out


def rotated(lines: IntArray, period: int, ratio: int, shift: int) -> IntArray:
    """Every line moved ``shift`` places (cyclically) along its :func:`alias_family`."""
    out = np.empty_like(lines)
    for i, k in enumerate(lines):  # a loop over a design's lines, not per sample or bin
        fam = alias_family(int(k), period, ratio)
        j = int(np.searchsorted(fam, k))
        out[i] = fam[(j + shift) % fam.size]
    return out


def _synth(amp: FloatArray, lines: IntArray, phase: FloatArray, period: int) -> FloatArray:
    X = np.zeros(period // 2 + 1, complex)
    X[lines] = amp * np.exp(1j * phase)
    return np.asarray(np.fft.irfft(X, n=period), float)


def low_crest(
    amp: FloatArray,
    lines: IntArray,
    period: int,
    rng: np.random.Generator,
    *,
    iterations: int = 200,
) -> tuple[FloatArray, float]:
    """Random phases, then iterative clipping (module docstring): (one period, crest factor).

    Each iteration clips the period at a level that shrinks from 0.9 to 0.75 of its peak,
    takes the phases of the clipped signal's spectrum at the lines and restores the
    amplitudes; the best crest factor met is kept.
    """
    phase = rng.uniform(0.0, 2 * np.pi, lines.size)
    best = _synth(amp, lines, phase, period)

    def crest(x: FloatArray) -> float:
        return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))

    best_cf = crest(best)
    x = best
    for it in range(iterations):
        level = (0.9 - 0.15 * it / max(iterations - 1, 1)) * np.max(np.abs(x))
        X = np.fft.rfft(np.clip(x, -level, level))
        phase = np.asarray(np.angle(X[lines]), float)
        x = _synth(amp, lines, phase, period)
        cf = crest(x)
        if cf < best_cf:
            best, best_cf = x, cf
    return best, best_cf


def design(
    *,
    fs_high: float,
    period: int,
    band: tuple[float, float],
    kind: str = "odd-random",
    rms: float = 1.0,
    periods: int = 1,
    realizations: int = 1,
    inputs: int = 1,
    ratio: int = 1,
    lifted: bool = False,
    slope_db_per_decade: float = 0.0,
    group: int = 3,
    seed: int = 0,
    rotate: bool = False,
) -> Multisine:
    """A multisine (module docstring); every argument is checked with a clear error.

    ``slope_db_per_decade``: the amplitude spectrum, 0 flat, -20 falling as 1/f; ``rms``
    each input's RMS; ``lifted`` with ``ratio`` F: lines whose lifted aliases do not collide;
    ``rotate`` (lifted, ``kind="full"``, realizations a multiple of F): realization m's
    lines moved m places along their alias families.
    """
    checks: list[tuple[str, float, bool, str]] = [
        ("fs_high", fs_high, fs_high > 0 and math.isfinite(fs_high), "> 0"),
        ("period", period, period >= 4, ">= 4 samples"),
        ("rms", rms, rms > 0 and math.isfinite(rms), "> 0"),
        ("periods", periods, periods >= 1, ">= 1"),
        ("realizations", realizations, realizations >= 1, ">= 1"),
        ("inputs", inputs, inputs >= 1, ">= 1"),
        ("ratio", ratio, ratio >= 1, ">= 1"),
    ]
    for name, value, ok, want in checks:
        if not ok:
            raise ConfigError(f"{name} must be {want}, got {value!r}")
    if rotate and not (
        lifted and ratio > 1 and kind == "full" and realizations % ratio == 0 and period % 2 == 0
    ):
        raise ConfigError(
            "rotate needs lifted=True, ratio F > 1, kind full, realizations a multiple of F "
            f"and an even period; got lifted={lifted}, ratio={ratio}, kind={kind!r}, "
            f"realizations={realizations}, period={period}"
        )
    rng = np.random.default_rng(seed)
    cand = band_lines(fs_high, period, band)
    if lifted and ratio > 1:
        cand = unaliased(cand, period, ratio)
    lines, detection = choose_lines(cand, kind, rng, group=group)
    if lines.size == 0:
        raise FieldError(
            f"no {kind} line in {band[0]:g}-{band[1]:g} Hz at a resolution of "
            f"{fs_high / period:g} Hz: widen the {{band}}, lengthen the {{period}} or use "
            "{kind} full",
            "band",
            "period",
            "kind",
        )
    if lines.size < inputs:
        raise ConfigError(
            f"the design has {lines.size} excited line(s), fewer than the {inputs} inputs"
        )
    per_input = [lines[i::inputs] for i in range(inputs)]
    width = max(p.size for p in per_input)
    table = np.full((realizations, inputs, width), -1, np.int64)
    r = np.zeros((realizations, periods * period, inputs))
    cf = np.zeros((realizations, inputs))
    f0 = lines[0] * fs_high / period
    for i, base in enumerate(per_input):
        for m in range(realizations):
            ks = rotated(base, period, ratio, m % ratio) if rotate else base
            table[m, i, : ks.size] = ks
            amp = (ks * fs_high / period / f0) ** (slope_db_per_decade / 20.0)
            x, cf[m, i] = low_crest(amp, ks, period, rng)
            x *= rms / np.sqrt(np.mean(x**2))
            r[m, :, i] = np.tile(x, periods)
    return Multisine(
        r, float(fs_high), int(period), table[0], detection, kind, cf, table if rotate else None
    )
