# SPDX-License-Identifier: Apache-2.0
"""Whether a model is wrong thinly over many bins: the total of the σ-errors against its null.

The per-bin test (:mod:`.evidence`) is family-wise over every bin: an error spread thinly
over the band, each bin well below the Bonferroni threshold, passes it however many bins
it covers. Its total does not: over the N tested complex entries (the bins whose window
reaches DC left out, as there),

    T = Σ_k |P̂_k - P_k|² / σ̂_k².

Under "model right" each term is ``|e|² / σ̂²`` with ``|e|²/σ²`` exponential of mean 1 and
variance 1 (circular complex Gaussian) and ``σ̂²`` estimated from q residual dof:
``E{1/σ̂²} = q/(q-1) / σ²`` scales mean and sd. Neighbouring LPM estimates share their
windows (correlation ρ(l) of estimates l bins apart), and the covariance of ``|e_k|²`` and
``|e_{k+l}|²`` is ρ(l)² for circular Gaussian errors, so the variance of the sum is
N times the correlation length ``L = Σ_l ρ(l)²``:

    E{T} = q/(q-1) N,    sd{T} = q/(q-1) sqrt(N L),

the fit's cost band with no parameters
(:func:`~mr_ident.numerics.fit.frf_fit.expected_band`,
:func:`~mr_ident.numerics.fit.frf_fit.lpm_kernel`,
:func:`~mr_ident.numerics.fit.frf_fit.correlation_length`). For N in the tens and more T
is close to Gaussian; the model is significantly wrong over the band when
``T > E{T} + z_{1-α} sd{T}``, one test at the level α of the per-bin one. A periodic
record's lines come from period means, independent from line to line (L = 1). Its use:
where no single bin is significant but T is, the correction of
:mod:`~mr_ident.diagnosis.selection.correction` is still tried; the validation decides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats

from ...numerics.fit.frf_fit import correlation_length, expected_band, lpm_kernel
from .evidence import Evidence


@dataclass(frozen=True)
class Broadband:
    """The total of the squared σ-errors over the tested bins against its null.

    ``total`` T; ``expected``, ``sd`` its mean and std under "model right"; ``n_terms`` N,
    the complex entries summed; ``correlation`` L; ``threshold`` ``expected + z_{1-α}
    sd`` (module docstring).
    """

    total: float
    expected: float
    sd: float
    n_terms: int
    correlation: float
    threshold: float

    @property
    def significant(self) -> bool:
        """T above the threshold: the model is wrong over the band."""
        return self.n_terms > 0 and self.total > self.threshold

    @property
    def z(self) -> float:
        """``(T - E{T}) / sd{T}``."""
        return (self.total - self.expected) / self.sd if self.sd > 0 else 0.0

    def summary(self) -> dict[str, object]:
        """JSON-ready."""
        return {
            "total": float(self.total),
            "expected": float(self.expected),
            "sd": float(self.sd),
            "z": float(self.z),
            "n_terms": int(self.n_terms),
            "correlation_length": float(self.correlation),
            "threshold": float(self.threshold),
            "significant": bool(self.significant),
        }


def null_band(
    n_terms: int, dof: float | None, n: int, degree: int, alpha: float
) -> tuple[float, float, float, float]:
    """``(E{T}, sd{T}, L, threshold)``: N terms of an LPM of half-width n (0: independent)."""
    L = correlation_length(lpm_kernel(n, degree) if n > 0 else None)
    mean, sd = expected_band(n_terms, 0, dof, L)
    return mean, sd, L, mean + float(scipy.stats.norm.isf(alpha)) * sd


def broadband(ev: Evidence, *, n: int, degree: int, alpha: float) -> Broadband:
    """The broadband test of ``ev``'s plant (module docstring).

    ``n``: the LPM's window half-width (0 for a periodic record's lines, independent);
    ``degree`` its polynomial degree; ``alpha`` the test's level.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        z2 = np.abs(ev.P_hat - ev.P_model) ** 2 / ev.P_std**2
    z2 = z2[ev.tested]
    z2 = z2[np.isfinite(z2)]
    mean, sd, L, thr = null_band(int(z2.size), float(ev.dof), n, degree, alpha)
    return Broadband(float(z2.sum()), mean, sd, int(z2.size), L, thr)
