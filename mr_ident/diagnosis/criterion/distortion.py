# SPDX-License-Identifier: Apache-2.0
"""Nonlinear distortion on one periodic record: the lines its excitation leaves out.

With an odd design the unexcited even lines hold even distortion and the odd lines left
out (detection lines, ``--kind odd-random``) odd distortion
(:func:`~mr_ident.numerics.excitation.bla.distortion_by_band`). A design that excites
every odd line leaves no detection line: odd distortion, a dead zone's or a saturation's,
then falls on the excited lines only, where one record cannot tell it from the plant. Other
realizations can (:mod:`.realizations`); :func:`blind_text` says so.
"""

from __future__ import annotations

import numpy as np

from ...numerics.excitation.bla import BandLevels, distortion_by_band
from ...numerics.signals import LoopData

#: A band whose unexcited lines stand this many dB above the noise shows distortion.
NL_THRESHOLD_DB = 6.0


def distortion(rec: LoopData) -> list[BandLevels]:
    """Distortion levels per band of periodic single-output data; [] for other data.

    Four log-spaced bands over the excited range, the first (transient) period dropped.
    """
    if rec.period is None or rec.y.shape[1] != 1 or rec.n_samples // rec.period < 3:
        return []
    Pn, fs = rec.period, rec.rates()[0]
    n = (rec.n_samples // Pn - 1) * Pn  # whole periods after the first
    return distortion_by_band(
        rec.r[Pn : Pn + n, 0], rec.y[Pn : Pn + n, 0], Pn, fs, ratio=rec.ratio or 1
    )


def lines_nonlinear(bands: list[BandLevels]) -> bool:
    """A band's odd or even level above :data:`NL_THRESHOLD_DB` and above its threshold."""
    return any(
        level > max(NL_THRESHOLD_DB, threshold if np.isfinite(threshold) else -np.inf)
        for b in bands
        for level, threshold in ((b.odd_db, b.odd_threshold_db), (b.even_db, b.even_threshold_db))
        if np.isfinite(level)
    )


def lines_text(bands: list[BandLevels]) -> str:
    """The finding on the unexcited lines in words, or ""."""
    if not lines_nonlinear(bands):
        return ""
    worst = max(bands, key=lambda b: np.nanmax([b.odd_db, b.even_db]))
    odd = max((b.odd_db for b in bands if np.isfinite(b.odd_db)), default=np.nan)
    even = max((b.even_db for b in bands if np.isfinite(b.even_db)), default=np.nan)
    levels = " and ".join(  # a parity the design leaves no line of is not named
        f"{v:.0f} dB ({name} lines)"
        for v, name in ((odd, "odd"), (even, "even"))
        if np.isfinite(v)
    )
    return (
        f"nonlinear distortion up to {levels} "
        f"above the noise, most at {worst.band[0]:.3g}-{worst.band[1]:.3g} Hz (counted as "
        "noise in the criterion; any linear cause describes the best linear approximation)"
    )


def blind_text(bands: list[BandLevels], records: int) -> str:
    """Why one periodic record cannot show odd distortion, and what would; "" when it can.

    ``bands``: the record's :func:`distortion`; ``records``: how many realizations were
    compared (with two or more the spread across them shows it).
    """
    if records > 1 or not bands or any(np.isfinite(b.odd_db) for b in bands):
        return ""
    return (
        "odd nonlinear distortion (a dead zone, a saturation, friction) cannot show in this "
        "record: its excitation leaves no odd line out (no detection line) and it is one "
        "realization; design one with `mr-ident excite --kind odd-random`, or give records "
        "of other realizations (--validate DATA2 [DATA3 ...]) to compare"
    )
