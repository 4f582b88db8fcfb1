# SPDX-License-Identifier: Apache-2.0
"""Nonlinear distortion across records: two or more realizations of the excitation.

A linear loop gives the same FRF from every record, whatever realization of r drove it:
the records' plant estimates ``G_m`` (m = 1..M) differ by their noise alone. Nonlinear
distortion does not: the stochastic part of it depends on the realization (its random
phases), stays put within a periodic record (so the spread over its periods does not
see it) and moves from one record to the next. That is the robust method's split
(Pintelon and Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed.,
2012, sec. 3.6 and 4.3; :func:`~mr_ident.numerics.excitation.bla.best_linear_approximation`
for realizations of one record) with the records as the M realizations: per common
frequency line k

- the spread ``s²(k) = sum_m |G_m(k) - Ḡ(k)|² / (M - 1)`` (the variance of one record's
  estimate: noise and distortion),
- its noise part ``σ²(k) = mean_m σ²_m(k)`` (each record's own noise estimate: the spread
  over its periods, or the LPM's residual for a non-periodic record),
- the distortion ``nl_std² = max(s² - σ², 0) / M`` (of the mean, as ``BLA.nl_std``).

Per band (four log-spaced over the common lines), the level ``10 log10(mean s² / mean σ²)``
dB above the noise (0 dB: noise only). Under noise alone (Gaussian, the records
independent) the ratio of the two means is about F(2L(M-1), 2L·q) over L lines, q the sum
of the records' noise dofs; the band's threshold is its 1 - :data:`LEVEL_ALPHA` quantile,
and distortion is named where a band exceeds both it and
:data:`~.distortion.NL_THRESHOLD_DB`. This works whatever lines were
excited (every odd line, every line): it needs no detection line. A non-periodic record's
LPM noise already holds the distortion (random excitation mixes it with the noise), so
random records alone show none here: periodic records separate the two.

Records with the same realization (the same r on the common lines) are no realizations:
:func:`compare` then gives nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.excitation.bla import LEVEL_ALPHA
from ...numerics.results import Identification
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .distortion import NL_THRESHOLD_DB
from .evidence import identify_record, periodic_plant


@dataclass(frozen=True)
class SpreadLevels:
    """The records' spread per band, against their noise.

    Attributes
    ----------
    band : (float, float)
        Hz.
    level_db : float
        Spread over the records in dB above their noise (0 dB: noise only).
    threshold_db : float
        What noise alone exceeds with probability :data:`LEVEL_ALPHA` on as many lines.
    nl_std, noise_std : float
        RMS over the band's lines of the distortion's and the noise's std of the mean
        plant estimate (``BLA.nl_std``, ``BLA.noise_std``), relative to its magnitude.
    lines : int
        Common lines in the band.
    line_ratio_db : float
        The mean over the band's lines (and entries) of each line's own ratio
        ``s²(k) / σ²(k)``, dB: unlike :attr:`level_db` not dominated by the noisiest lines
        (:mod:`.timevarying`).
    """

    band: tuple[float, float]
    level_db: float
    threshold_db: float
    nl_std: float
    noise_std: float
    lines: int
    line_ratio_db: float = float("nan")


@dataclass(frozen=True)
class _Estimate:
    frequency: FloatArray
    G: ComplexArray  # (K, n_entries)
    var: FloatArray  # (K, n_entries)
    dof: int
    R: ComplexArray | None  # r's period-mean spectrum at the lines (periodic)


def _estimate(
    rec: LoopData, model: Model, n: int, degree: int, ident: Identification | None
) -> _Estimate | None:
    if rec.period is not None:
        if rec.n_samples // rec.period < 3:
            return None
        lines, P, std, Rm, dof = periodic_plant(rec)
        f = lines * rec.fs_high / rec.period
        return _Estimate(f, P.reshape(P.shape[0], -1), std.reshape(P.shape[0], -1) ** 2,
                         dof, Rm[lines, 0])  # fmt: skip
    ident = ident or identify_record(rec, model, n=n, degree=degree)
    if ident is None:
        return None
    p = ident.plant
    dof = ident.lifted_J.dof if ident.lifted_J is not None else 1
    K = p.response.shape[0]
    return _Estimate(p.frequency, p.response.reshape(K, -1), p.std.reshape(K, -1) ** 2,
                     int(dof), None)  # fmt: skip


def _on(e: _Estimate, f: FloatArray) -> tuple[ComplexArray, FloatArray]:
    """``e``'s estimate at the frequencies ``f`` (exact where its grid holds them)."""
    if e.frequency.size == f.size and np.allclose(e.frequency, f):
        return e.G, e.var
    G = np.column_stack(
        [np.interp(f, e.frequency, g.real) + 1j * np.interp(f, e.frequency, g.imag) for g in e.G.T]
    )
    v = np.column_stack([np.interp(f, e.frequency, x) for x in e.var.T])
    return G, v


def same_realization(a: ComplexArray, b: ComplexArray) -> bool:
    """Whether two records' r, at their common lines, are the same realization."""
    ua, ub = a / np.abs(a), b / np.abs(b)
    return bool(np.mean(np.abs(ua - ub)) < 0.1)


def aligned(
    records: list[LoopData],
    model: Model,
    *,
    n: int = 8,
    degree: int = 2,
    idents: Sequence[Identification | None] = (),
    realizations: bool = True,
) -> tuple[FloatArray, ComplexArray, FloatArray, int] | None:
    """The records' plant estimates on their common lines: ``(f, G, V, q)``.

    ``f`` (K,) Hz; ``G`` (M, K, n_entries) the estimates; ``V`` (M, K, n_entries) their
    noise variances; ``q`` the sum of their noise dofs. None where :func:`compare` gives
    nothing (fewer than 2 usable records, fewer than 2 common lines, or with
    ``realizations`` the same periodic realization twice; False: segments of one record,
    :mod:`.timevarying`, where the same periodic realization is what makes the comparison).
    """
    known = list(idents) + [None] * (len(records) - len(idents))
    got = (_estimate(r, model, n, degree, i) for r, i in zip(records, known, strict=True))
    ests = [e for e in got if e is not None]
    if len(ests) < 2:
        return None
    ref = min(ests, key=lambda e: e.frequency.size)
    f = ref.frequency
    lo = max(float(e.frequency.min()) for e in ests)
    hi = min(float(e.frequency.max()) for e in ests)
    keep = (f >= lo) & (f <= hi) & (f > 0)
    if np.count_nonzero(keep) < 2:
        return None
    f = f[keep]
    periodic = [e for e in ests if e.R is not None]
    if (
        realizations
        and len(periodic) >= 2
        and all(e.frequency.size == periodic[0].frequency.size for e in periodic)
    ):
        first = periodic[0].R
        assert first is not None
        if any(same_realization(first, e.R) for e in periodic[1:] if e.R is not None):
            return None
    Gs, Vs = zip(*(_on(e, f) for e in ests), strict=True)
    return f, np.stack(Gs), np.stack(Vs), sum(e.dof for e in ests)


def _band_edges(f: FloatArray) -> FloatArray:
    """The four log-spaced bands' edges over the lines ``f`` (Hz)."""
    return np.geomspace(f[0], f[-1] * (1 + 1e-9), 5)


def compare(
    records: list[LoopData],
    model: Model,
    *,
    n: int = 8,
    degree: int = 2,
    idents: Sequence[Identification | None] = (),
) -> list[SpreadLevels]:
    """The records' FRF spread against their noise, per band: levels(aligned(...)).

    :func:`levels` of their :func:`aligned` estimates as realizations; [] for fewer than 2
    usable records or the same realization twice. ``idents``: the first records'
    :func:`~.evidence.identify_record` where at hand (None: computed).
    """
    got = aligned(records, model, n=n, degree=degree, idents=idents)
    return [] if got is None else levels(*got)


#: A line whose noise variance is below this share of its band's median is left out of
#: the lines' own ratios (an exact estimate: its ratio is no measure of the spread).
LINE_NOISE_FLOOR = 1e-3


def levels(f: FloatArray, G: ComplexArray, V: FloatArray, q: int) -> list[SpreadLevels]:
    """The spread of estimates against their noise, per band (module docstring).

    ``G`` (M, K, e) the estimates on the lines ``f`` (K,), ``V`` their noise variances,
    ``q`` the sum of their noise dofs (:func:`aligned`'s ``(f, G, V, q)``).
    """
    import scipy.stats  # not at the top: identify's start-up stays light

    M = G.shape[0]
    spread = np.sum(np.abs(G - G.mean(axis=0)) ** 2, axis=0) / (M - 1)  # (K, n_entries)
    noise = V.mean(axis=0)
    mag2 = np.abs(G.mean(axis=0)) ** 2
    edges = _band_edges(f)
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        inb = (f >= a) & (f < b)
        L = int(np.count_nonzero(inb))
        if L == 0:
            continue
        s2, n2 = float(np.mean(spread[inb])), float(np.mean(noise[inb]))
        with np.errstate(divide="ignore", invalid="ignore"):
            level = 10.0 * math.log10(s2 / n2) if n2 > 0 and s2 > 0 else float("nan")
            rel = np.mean(mag2[inb])
            nl = math.sqrt(max(s2 - n2, 0.0) / M / rel) if rel > 0 else float("nan")
            nz = math.sqrt(n2 / M / rel) if rel > 0 else float("nan")
            nb = noise[inb]
            ok = nb > LINE_NOISE_FLOOR * np.median(nb)  # exact lines carry no ratio
            ratio = (
                10.0 * float(np.log10(np.mean(spread[inb][ok] / nb[ok])))
                if ok.any()
                else float("nan")
            )
        thr = 10.0 * math.log10(
            float(scipy.stats.f.isf(LEVEL_ALPHA, 2 * L * (M - 1), 2 * L * max(q, 1)))
        )
        out.append(SpreadLevels((float(a), float(b)), level, thr, nl, nz, L, ratio))
    return out


def spread_nonlinear(bands: list[SpreadLevels]) -> bool:
    """A band's spread above :data:`~.distortion.NL_THRESHOLD_DB` and above its threshold."""
    return any(
        np.isfinite(b.level_db) and b.level_db > max(NL_THRESHOLD_DB, b.threshold_db)
        for b in bands
    )


def spread_text(bands: list[SpreadLevels], records: int) -> str:
    """The finding across records in words, with its level per band, or ""."""
    if not spread_nonlinear(bands):
        return ""
    per = ", ".join(f"{b.band[0]:.3g}-{b.band[1]:.3g} Hz {b.level_db:.0f} dB" for b in bands)
    return (
        f"nonlinear distortion across the {records} records (realizations of the "
        f"excitation): their plant estimates differ beyond their noise by {per} (a linear "
        "loop gives the same FRF from every realization; any linear cause describes the "
        "best linear approximation)"
    )


def records_spread(
    records: list[LoopData],
    model: Model,
    n: int,
    degree: int,
    idents: tuple[Identification | None, ...],
) -> tuple[list[SpreadLevels], int]:
    """The records' spread as realizations (:func:`compare`) and how many were compared."""
    if len(records) < 2:
        return [], 1
    spread = compare(records, model, n=n, degree=degree, idents=idents)
    return spread, len(records) if spread else 1
