# SPDX-License-Identifier: Apache-2.0
"""Does the plant change within a record? The estimates of its segments compared.

A time-invariant loop gives the same FRF from every stretch of a record: the plant
estimates of consecutive segments differ by their noise alone, whatever the excitation
(under a random r each segment is another realization, whose nonlinear distortion the
LPM's noise already holds; under a periodic r the same realization repeats, distortion
included). A plant whose gain or dynamics change during the record (a load, a
temperature, a wearing part, a gain scheduled on the operating point) gives segment
estimates that differ beyond their noise. The spread is the one across records
(:func:`~.realizations.compare`, the :data:`SEGMENTS` segments as the M estimates); the
statistic is each line's own ratio ``s²(k) / σ²(k)`` (spread over noise) averaged over
every common line, in dB (``SpreadLevels.line_ratio_db``, weighted by the bands' lines):
a gain that drifts moves every line by the same relative amount, so each line counts
alike, not the noisiest most. Named above :data:`VARYING_DB`. No time-invariant model, nor
any correction of one, describes such a plant: it describes the plant's average over the
record.

Segments: a random record is cut into :data:`SEGMENTS` equal parts (multiples of F),
fewer where a part would be shorter than diagnose takes; a periodic one into whole
periods, at least 4 per segment (the first is dropped as transient); none when fewer than
two segments fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ...numerics.identify import min_samples
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from .realizations import SpreadLevels, compare

#: Segments a record is cut into (at most).
SEGMENTS = 4
#: Mean per-line spread over noise (dB) above which the plant is named time-varying. Under
#: a time-invariant loop the statistic sits near 0 dB (at most 0.88 dB over 320 records of
#: the benchmark's random loops, 10 and 30 s of white r, nothing or one cause hidden, a
#: pole-zero pair or a second delay path: 2026-11-26); a gain moving by 10-30 % over a few
#: seconds of a 10 s record reached 1.5 dB in 20 of 25.
VARYING_DB = 1.5


@dataclass(frozen=True)
class Segments:
    """A record's segments compared (module docstring).

    ``bands``: their spread per band (:class:`~.realizations.SpreadLevels`); ``parts``:
    how many segments; ``level_db``: the mean per-line spread over noise, dB.
    """

    bands: list[SpreadLevels]
    parts: int
    level_db: float

    @property
    def varying(self) -> bool:
        """The segments differ beyond their noise: level above :data:`VARYING_DB`."""
        return math.isfinite(self.level_db) and self.level_db > VARYING_DB

    def text(self) -> str:
        """The finding in words, with its level per band, or ""."""
        if not self.varying:
            return ""
        per = ", ".join(
            f"{b.band[0]:.3g}-{b.band[1]:.3g} Hz {b.line_ratio_db:.1f} dB" for b in self.bands
        )
        return (
            f"the plant changes within the record: the plant estimates of its {self.parts} "
            f"consecutive segments differ beyond their noise, {self.level_db:.1f} dB on "
            f"average over the lines ({per}; a time-invariant model, and any correction of one, "
            "describes the average over the record)"
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
    bands = compare(segs, model, n=n, degree=degree, realizations=False)
    lines = sum(b.lines for b in bands)
    if not lines:
        return None
    mean = sum(b.lines * 10.0 ** (b.line_ratio_db / 10.0) for b in bands) / lines
    return Segments(bands, len(segs), 10.0 * math.log10(mean) if mean > 0 else -math.inf)
