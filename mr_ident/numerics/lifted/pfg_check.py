# SPDX-License-Identifier: Apache-2.0
"""Is the controller on the machine the model's? The PFG from data against the PFG from K_l.

One identification gives two PFGs (:class:`~mr_ident.numerics.results.Identification`):
``pfg_data`` from the lifted closed-loop map r -> y alone, and ``pfg`` from the identified
plant P̂_h closed with the *model's* controller (K_l, sampling phase, delay). Whatever the
plant model says, both describe the same identified plant, so they differ only where the
controller running the loop differs from its model (its gain, its filters, its timing).

Per bin ``z = |g_data - g_model| / sqrt(s_data² + s_model²)``. With the right controller
the two errors are strongly correlated (both come from one fit; measured on random loops:
the spread of the difference is 0.03-0.34 of that root sum of squares), so a bin beyond
:data:`COVERAGE` is rare; a controller that differs moves
the PFG wherever the loop gain matters, over bands of bins, most at the low frequencies.
So the bins are weighed as on a log-frequency axis (weight 1/f: every decade counts the
same), and the finding is reported when more than :data:`MIN_FRACTION` of that axis lies
beyond COVERAGE. Measured on 30 random loops (``scenarios.draw_loop``, 30 s, SNR 20-59 dB,
F = 1-5; the machine's controller gain x1.2 or x0.8): with the right controller 0-0.007,
with the plant's gain x1.2 instead 0-0.016, with the changed controller 0.003-0.84 (above
0.03 in 28 of 30 loops; the two below: F = 1 at 22 dB, and F = 5 with a controller whose
gain barely shapes the PFG). Bins within the LPM's half-width of a
multiple of fs_low are left out: there the lifted fit's one-sided windows turn an
integrator's 1/f into bias in either PFG.

It sits with the PFG (beneath the diagnosis) because ``identify`` reports it on every
result with a model; ``diagnose`` uses it too, and its :data:`COVERAGE` is the coverage
level of the diagnosis's tests and of the benchmark's judge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arrays import FloatArray
from ..results import Identification

#: Standard deviations within which a loosely determined parameter counts as consistent
#: (the diagnosis's coverage level; the benchmark's verdict uses the same).
COVERAGE = 3.0

#: Share of the tested band (log-frequency axis) beyond COVERAGE std above which the
#: controller differs from its model.
MIN_FRACTION = 0.03


@dataclass(frozen=True)
class ControllerCheck:
    """The PFG from data against the PFG from the model's controller.

    Attributes
    ----------
    frequency : ndarray, shape (K,)
        Hz, the tested bins.
    z : ndarray, shape (K,)
        ``|g_data - g_model| / sqrt(s_data² + s_model²)``.
    fraction : float
        Share of the tested band with ``z > COVERAGE``, the bins weighed by 1/f (as on a
        log-frequency axis).
    relative : float
        Median ``|g_data - g_model| / g_model`` over the bins beyond COVERAGE (0 if none).
    bands : list of (float, float)
        Frequency bands (Hz) of the bins beyond COVERAGE.
    """

    frequency: FloatArray
    z: FloatArray
    fraction: float
    relative: float
    bands: list[tuple[float, float]]

    @property
    def differs(self) -> bool:
        """The controller on the machine differs from its model (see the module docstring)."""
        return self.fraction > MIN_FRACTION

    def text(self) -> str:
        """The finding in words, or "" when there is none."""
        if not self.differs:
            return ""
        where = ", ".join(f"{lo:.3g}-{hi:.3g} Hz" for lo, hi in self.bands[:4])
        more = f" (+{len(self.bands) - 4} more bands)" if len(self.bands) > 4 else ""
        return (
            f"the controller on the machine differs from its model: the PFG identified from "
            f"data differs from the PFG of the model's controller by more than {COVERAGE:g} std "
            f"over {100 * self.fraction:.0f} % of the band on a log axis (median "
            f"{100 * self.relative:.0f} %), at {where}{more}"
        )


def check_controller(ident: Identification, n: int) -> ControllerCheck | None:
    """The check on one identification with both PFGs; None when either is missing.

    ``n``: the LPM window half-width of the identification (low-rate bins left out around
    every multiple of fs_low).
    """
    gd, gm = ident.pfg_data, ident.pfg
    if gd is None or gm is None:
        return None
    f = gd.frequency
    N = int(round(ident.fs_high / f[0]))  # the bins are k fs_high / N, k = 1..N//2
    M = N // ident.ratio
    m = np.arange(M)
    far = np.resize(np.roll(np.minimum(m, M - m) > n, -1), f.size)  # bins 1, 2, ...: k mod M
    diff = np.abs(gd.gain - gm.gain)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = diff / np.hypot(gd.std, gm.std)
        keep = far & np.isfinite(z)
        f, z, rel = f[keep], z[keep], diff[keep] / gm.gain[keep]
    beyond = z > COVERAGE
    w = 1.0 / f
    return ControllerCheck(
        f,
        z,
        float(np.sum(w[beyond]) / np.sum(w)) if z.size else 0.0,
        float(np.median(rel[beyond])) if beyond.any() else 0.0,
        _bands(f, beyond),
    )


def _bands(f: FloatArray, mark: np.ndarray) -> list[tuple[float, float]]:
    """Runs of marked bins as (f_lo, f_hi); gaps of up to 3 bins are bridged."""
    idx = np.flatnonzero(mark)
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > 3)
    starts = np.concatenate([[idx[0]], idx[cut + 1]])
    ends = np.concatenate([idx[cut], [idx[-1]]])
    return [(float(f[a]), float(f[b])) for a, b in zip(starts, ends, strict=True)]
