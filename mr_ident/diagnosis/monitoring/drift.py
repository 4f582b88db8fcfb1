# SPDX-License-Identifier: Apache-2.0
"""Has the plant drifted from a reference? An estimate held against it, bin by bin.

The reference is a model's exact P_h (std 0) or an earlier identification (with its std).
Per bin and entry the σ-error ``|P̂ - P_ref| / sqrt(σ̂² + σ_ref²)`` is compared with the
test of :mod:`~mr_ident.diagnosis.criterion.evidence` (F(2, 2q) at ``1 - alpha / n_tests``,
Bonferroni over the bins and entries tested, q the estimate's degrees of freedom), so that
an unchanged plant raises an alarm with probability at most ``alpha`` per estimate.
Contiguous significant bins are reported as bands. The drift's *size* is the median
relative deviation ``e = |P̂ - P_ref| / |P_ref|`` over the significant bins (the largest
would add the noise's own peak), in dB as
``20 log10(1 + e)`` (a plant gain up by 30 % is 2.3 dB, a phase lag of 30° at unchanged
magnitude 3.6 dB): ``ok`` without a significant bin, ``error`` at or beyond ``error_db``,
``warn`` between.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats
from numpy.typing import ArrayLike, NDArray

from ...errors import ConfigError, DimensionError
from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.results import FRF
from ...numerics.systems.model import Model

#: The drift levels, in order of severity.
LEVELS = ("ok", "warn", "error")


@dataclass(frozen=True)
class Drift:
    """An estimate against the reference (see the module docstring).

    Attributes
    ----------
    frequency : ndarray, shape (K,)
        Hz, the estimate's bins.
    deviation : ndarray, shape (K,)
        ``max_entries |P̂ - P_ref| / |P_ref|``; nan where the reference has no value.
    sigma_error : ndarray, shape (K,)
        ``max_entries |P̂ - P_ref| / sqrt(σ̂² + σ_ref²)``; nan where not tested.
    threshold : ndarray, shape (K,)
        σ-error above which each bin is significant (its own dof).
    significant : ndarray of bool, shape (K,)
    size_db : float
        ``20 log10(1 + median deviation over the significant bins)``; 0 without any.
    level : str
        ``"ok"``, ``"warn"`` or ``"error"``.
    """

    frequency: FloatArray
    deviation: FloatArray
    sigma_error: FloatArray
    threshold: FloatArray
    significant: NDArray[np.bool_]
    size_db: float
    level: str

    def bands(self, merge_bins: int = 3) -> list[tuple[float, float]]:
        """Significant bands [(f_lo, f_hi), ...] in Hz (gaps up to ``merge_bins`` bridged)."""
        idx = np.flatnonzero(self.significant)
        if idx.size == 0:
            return []
        cut = np.flatnonzero(np.diff(idx) > merge_bins)
        starts = np.concatenate([[idx[0]], idx[cut + 1]])
        ends = np.concatenate([idx[cut], [idx[-1]]])
        f = self.frequency
        return [(float(f[a]), float(f[b])) for a, b in zip(starts, ends, strict=True)]

    def describe(self) -> str:
        """In words: "drift 2.3 dB at 4.1-38 Hz" or "matches the reference"."""
        if self.level == "ok":
            return "matches the reference"
        bands = ", ".join(f"{lo:.3g}-{hi:.3g} Hz" for lo, hi in self.bands()[:4])
        more = f" (+{len(self.bands()) - 4} more)" if len(self.bands()) > 4 else ""
        return f"drift {self.size_db:.1f} dB at {bands}{more}"


@dataclass(frozen=True)
class Reference:
    """What an estimate is held against: P_ref with its std on any bins.

    From :meth:`of_model` (exact, std 0) or :meth:`of_frf` (an identification: linear
    interpolation of the response and the std inside its band, nan outside).
    """

    model: Model | None = None
    frf: FRF | None = None

    @classmethod
    def of_model(cls, model: Model) -> Reference:
        """The model's plant P_h, exact."""
        return cls(model=model)

    @classmethod
    def of_frf(cls, frf: FRF) -> Reference:
        """An identified plant with its std."""
        return cls(frf=frf)

    def at(self, frequency: FloatArray) -> tuple[ComplexArray, FloatArray]:
        """P_ref and its std at ``frequency`` Hz, shapes (K, n_y, n_u)."""
        f = np.asarray(frequency, float)
        if self.model is not None:
            P = self.model.plant_discrete().freqresp(f)
            return P, np.zeros(P.shape)
        if self.frf is None:
            raise ConfigError("a Reference needs a model or an FRF")
        ref = self.frf
        K, ny, nu = ref.response.shape
        P = np.full((f.size, ny, nu), np.nan + 0j)
        S = np.full((f.size, ny, nu), np.nan)
        inside = (f >= ref.frequency[0]) & (f <= ref.frequency[-1])
        for o in range(ny):  # entries: a handful; every bin at once
            for i in range(nu):
                g = ref.response[:, o, i]
                P[inside, o, i] = np.interp(f[inside], ref.frequency, g.real) + 1j * np.interp(
                    f[inside], ref.frequency, g.imag
                )
                S[inside, o, i] = np.interp(f[inside], ref.frequency, ref.std[:, o, i])
        return P, S


def drift(
    estimate: FRF,
    reference: Reference,
    *,
    dof: int | ArrayLike,
    alpha: float = 0.01,
    error_db: float = 6.0,
    untested: ArrayLike | None = None,
) -> Drift:
    """``estimate`` held against ``reference`` (see the module docstring).

    ``dof``: the estimate's degrees of freedom q (``numerics.local.lpm.dof`` of its window), one
    for every bin or one per bin (shape (K,), where the window width varies);
    ``alpha``: false-alarm probability per estimate over the whole band; ``error_db``: the
    size at which the level is ``error``; ``untested``: (K,) bool, the bins not tested nor
    counted in the correction (the LPM's first n bins fit their polynomial on one side
    only, which an integrator's 1/f there turns into bias, not noise: give
    :func:`~mr_ident.numerics.local.lpm.reaches_dc`).
    """
    if not 0.0 < alpha < 1.0:
        raise ConfigError(f"alpha must be in (0, 1), got {alpha}")
    if not (error_db > 0 and math.isfinite(error_db)):
        raise ConfigError(f"error_db must be > 0, got {error_db}")
    q = np.broadcast_to(np.asarray(dof, float), estimate.frequency.shape)
    if not np.all(q >= 1):
        raise ConfigError(f"dof must be >= 1, got {float(np.min(q)):g}")
    f = estimate.frequency
    P_ref, S_ref = reference.at(f)
    if P_ref.shape != estimate.response.shape:
        raise DimensionError(
            f"the reference is {P_ref.shape[1]}x{P_ref.shape[2]} (n_y x n_u) but the estimate "
            f"is {estimate.response.shape[1]}x{estimate.response.shape[2]}"
        )
    diff = np.abs(estimate.response - P_ref)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = diff / np.sqrt(estimate.std**2 + S_ref**2)
        rel = diff / np.abs(P_ref)
    skip = np.zeros(f.size, bool) if untested is None else np.asarray(untested, bool)
    if skip.shape != f.shape:
        raise DimensionError(f"untested must have shape {f.shape} (the bins), got {skip.shape}")
    z = np.where(np.isfinite(z) & ~skip[:, None, None], z, np.nan).reshape(f.size, -1)
    rel = np.where(np.isfinite(rel), rel, np.nan).reshape(f.size, -1)
    tested = np.isfinite(z)
    n_tests = max(int(tested.sum()), 1)
    thr = np.sqrt(scipy.stats.f.isf(alpha / n_tests, 2, 2 * q))
    any_tested = tested.any(axis=1)
    z_bin = np.full(f.size, np.nan)
    z_bin[any_tested] = np.nanmax(z[any_tested], axis=1)
    dev = np.full(f.size, np.nan)
    has_rel = np.isfinite(rel).any(axis=1)
    dev[has_rel] = np.nanmax(rel[has_rel], axis=1)
    sig = np.nan_to_num(z_bin, nan=0.0) > thr
    typical = float(np.nanmedian(dev[sig])) if sig.any() else 0.0
    size = 20.0 * math.log10(1.0 + (typical if math.isfinite(typical) else 0.0))
    level = "ok" if not sig.any() else ("error" if size >= error_db else "warn")
    return Drift(np.asarray(f, float), dev, z_bin, thr, sig, size, level)
