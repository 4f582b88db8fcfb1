# SPDX-License-Identifier: Apache-2.0
"""Every test of nonlinear distortion, summed up: how strong, where, of what kind.

Three tests see it (each documented in its module): the unexcited lines of one periodic
record (:mod:`.distortion`: odd and even apart), the spread of the plant estimates of
records of other realizations (:mod:`.realizations`), and, under any excitation, the
higher-order correlations of the validated model's residual with its input
(:mod:`.correlation`). :func:`summarize` joins what they found into one
:class:`Nonlinearity`: the largest level above the noise, the bands where a test found
it, and its kind where a test tells it (odd or even from the lines; odd or even from the
correlations: the residual correlates with the input's square for an even
nonlinearity, with its cube for an odd one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...numerics.excitation.bla import BandLevels
from .correlation import Correlation
from .distortion import NL_THRESHOLD_DB
from .realizations import SpreadLevels


@dataclass(frozen=True)
class Nonlinearity:
    """What the tests of nonlinear distortion found together.

    Attributes
    ----------
    level_db : float
        The largest level above the noise a test measured (nan where the test that found
        it gives none).
    bands : list of (float, float)
        Hz, where a test found it.
    kind : str
        "odd", "even", "odd and even" or "" (not told by the data).
    by : tuple of str
        Which tests found it, in words.
    """

    level_db: float
    bands: list[tuple[float, float]]
    kind: str
    by: tuple[str, ...]

    def text(self) -> str:
        """The finding in one clause."""
        level = (
            f" {level_words(self.level_db)} above the noise"
            if math.isfinite(self.level_db)
            else ""
        )
        where = ", ".join(f"{lo:.3g}-{hi:.3g} Hz" for lo, hi in self.bands)
        kind = f"{self.kind} " if self.kind else ""
        return (
            f"{kind}nonlinear distortion{level}" + (f" at {where}" if where else "")
            + f" (seen {' and '.join(self.by)})"
        )  # fmt: skip


def level_words(db: float) -> str:
    """A level in dB as the verdict says it: whole dB from 10 on, tenths below.

    >>> level_words(29.6), level_words(1.37), level_words(3e-11)
    ('up to 30 dB', 'up to 1.4 dB', 'under 0.1 dB')
    """
    if db < 0.1:
        return "under 0.1 dB"
    return f"up to {db:.0f} dB" if db >= 10 else f"up to {db:.1f} dB"


def _above(level: float, threshold: float) -> bool:
    return math.isfinite(level) and level > max(
        NL_THRESHOLD_DB, threshold if math.isfinite(threshold) else -math.inf
    )


def summarize(
    lines: list[BandLevels],
    spread: list[SpreadLevels],
    correlation: Correlation | None = None,
) -> Nonlinearity | None:
    """The tests' findings as one :class:`Nonlinearity`; None where no test found any.

    ``correlation``: the residual's higher-order correlations (their kind, side and level
    count where they found distortion).
    """
    levels: list[float] = []
    bands: list[tuple[float, float]] = []
    kinds: set[str] = set()
    by: list[str] = []
    for b in lines:
        odd, even = _above(b.odd_db, b.odd_threshold_db), _above(b.even_db, b.even_threshold_db)
        if odd or even:
            bands.append(b.band)
            levels += [v for v, hit in ((b.odd_db, odd), (b.even_db, even)) if hit]
            kinds |= {k for k, hit in (("odd", odd), ("even", even)) if hit}
    if bands:
        by.append("on the unexcited lines")
    hit = [b for b in spread if _above(b.level_db, b.threshold_db)]
    if hit:
        by.append("across the records")
        levels += [b.level_db for b in hit]
        bands += [b.band for b in hit if b.band not in bands]
    if correlation is not None and correlation.detected:
        side = f", {correlation.side} side" if correlation.side else ""
        by.append(f"in the residual's higher-order correlations{side}")
        kinds |= set(correlation.kind.split(" and ")) - {""}
        levels.append(correlation.level_db)
    if not by:
        return None
    kind = " and ".join(k for k in ("odd", "even") if k in kinds)
    level = float(np.max(levels)) if levels else math.nan
    return Nonlinearity(level, sorted(bands), kind, tuple(by))
