# SPDX-License-Identifier: Apache-2.0
"""The local model of every LPM method, one call: polynomial (the LPM) or rational (the LRM).

``polynomial`` (:mod:`mr_ident.numerics.local.lpm`, the default) fits G and the transient as
polynomials of degree R in each window; ``rational`` (:mod:`mr_ident.numerics.local.lrm`) adds a
common denominator of order R, for lightly damped modes with few bins across their
half-power band. The methods (:mod:`mr_ident.numerics.lifted.methods`,
:mod:`mr_ident.numerics.lifted.structured`) call :func:`local_fit` and never the engines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError
from ..arrays import ComplexArray, FloatArray, IntArray
from ..catalog import LOCAL_MODELS
from . import lpm, lrm
from .lrm import DenominatorTerm


def check_local(local: object) -> str:
    """``local`` if it names a local model; ConfigError naming the choices otherwise."""
    if local not in LOCAL_MODELS:
        raise ConfigError(f"local must be one of {', '.join(LOCAL_MODELS)}; got {local!r}")
    return str(local)


def check_options(local: str, n: int, degree: int, n_in: int, n_out: int) -> int:
    """Validate window and orders for ``n_in`` inputs and ``n_out`` outputs per map; the dof.

    The rational check counts the denominator against the ``n_out`` outputs of one map
    (the fits hold at least those, so their own q is no smaller).
    """
    if check_local(local) == "rational":  # its rule is the stricter one
        return lrm.check_lrm_options(n, degree, n_in, n_out, n_out)
    return lpm.check_lpm_options(n, degree, n_in, n_out)


def smallest_n(local: str, degree: int, n_in: int, n_out: int, margin: int = 0) -> int:
    """The smallest n whose dof exceed ``n_out + margin`` (see :func:`check_options`)."""
    if check_local(local) == "rational":
        return lrm.smallest_n(degree, n_in, n_out, n_out, margin)
    return lpm.smallest_n(degree, n_in, n_out, margin)


@dataclass(frozen=True)
class LocalFit:
    """A local fit at K centre bins, bins last.

    Attributes
    ----------
    G : ndarray, shape (n_out, n_in, K), complex128
    noise_cov : ndarray, shape (n_out, n_out, K), complex128
    inv_gram : ndarray, shape (n_in, n_in, K), complex128
        ``Cov(G[a, b], G[a2, b2]) = noise_cov[a, a2] inv_gram[b, b2]`` (+ ``den``).
    n_bad : int
        Bins with a rank-deficient regressor (NaN there).
    dof : int
        Residual degrees of freedom q of ``noise_cov``.
    den : DenominatorTerm or None
        The rational model's denominator term of the covariance; None for polynomial.
    """

    G: ComplexArray
    noise_cov: ComplexArray
    inv_gram: ComplexArray
    n_bad: int
    dof: int
    den: DenominatorTerm | None = None

    def take(self, keep: IntArray) -> LocalFit:
        """The fit at the centre bins ``keep`` only.

        As :class:`~mr_ident.numerics.local.segments.Segments` selects them; ``n_bad`` counts the
        kept bins whose G is not finite.
        """
        G = self.G[..., keep]
        den = self.den
        if den is not None:
            den = DenominatorTerm(den.gain[..., keep], den.cov[..., keep])
        n_bad = int((~np.isfinite(G).all(axis=(0, 1))).sum())
        return LocalFit(
            G, self.noise_cov[..., keep], self.inv_gram[..., keep], n_bad, self.dof, den
        )


def local_fit(
    local: str,
    U: ComplexArray,
    Y: ComplexArray,
    n: int,
    degree: int,
    *,
    workers: int = 1,
    missing: FloatArray | None = None,
    centres: IntArray | None = None,
    offsets: int = 0,
) -> LocalFit:
    """Fit ``local`` at every centre bin of padded spectra U (K+2n, n_in), Y (K+2n, n_out).

    Options are checked by the caller (:func:`check_options`); every output of Y is
    fitted in one pass (for ``rational``: with one denominator). ``missing`` (n_out,): the
    share of estimated (filled) samples in each output's signal; the noise covariance
    (and a rational fit's denominator term) is scaled by
    :func:`~mr_ident.numerics.local.fit.missing_factor` for them. ``centres`` (increasing,
    in 0..K-1): the centre bins to fit, the result's bins (default all K); the polynomial
    engine solves at those only, the rational one fits all and keeps them. ``offsets`` > 0
    (polynomial only): every ``2 offsets + 1`` windows one is solved and evaluated at the
    bins around its centre (:mod:`mr_ident.numerics.local.strided`).
    """
    n_in, n_out = U.shape[1], Y.shape[1]
    if local == "rational":
        q = lrm.dof(n, degree, n_in, n_out)
        G, Cv, Ainv, n_bad, den = lrm.lrm_bins_last(U, Y, n, degree, q, workers)
        if missing is not None:
            f = missing_factor(missing, n, q)
            Cv = Cv * np.sqrt(f[:, None, None] * f[None, :, None])
            den = DenominatorTerm(den.gain, den.cov * float(f.max()))
        fit = LocalFit(G, Cv, Ainv, n_bad, q, den)
        return fit if centres is None else fit.take(centres)
    q = lpm.dof(n, degree, n_in)
    G, Cv, Ainv, n_bad = lpm.lpm_bins_last(
        U, Y, n, degree, q, workers, centres=centres, offsets=offsets
    )
    if missing is not None:
        f = missing_factor(missing, n, q)
        Cv = Cv * np.sqrt(f[:, None, None] * f[None, :, None])
    return LocalFit(G, Cv, Ainv, n_bad, q)


def missing_factor(share: FloatArray, n: int, dof: int) -> FloatArray:
    """The scale of a filled record's noise covariance, per output (n_out,).

    ``share``: p, the share of missing (estimated) samples of each output's signal. Their
    estimates take ``p (2n+1)`` of the q residual degrees of freedom of a window (of one
    window-equivalent of 2n+1 bins: the record's ``N q / (2n+1)`` real residual degrees of
    freedom lose ``p N``), and the joint fit's G lose the share p of their information::

        f = q / (q - (2n+1) p) / (1 - p)

    (1 where nothing is missing; the method page, "Missing samples").
    """
    p = np.asarray(share, dtype=float)
    f: FloatArray = dof / (dof - (2 * n + 1) * p) / (1.0 - p)
    return f


def merge_fits(bins: list[IntArray], fits: list[LocalFit], n_bins: int) -> LocalFit:
    """Fits at the centre bins ``bins[i]`` put on every bin 0..n_bins-1, bins last (NaN else)."""

    def put(parts: list[ComplexArray]) -> ComplexArray:
        out = np.full(parts[0].shape[:-1] + (n_bins,), np.nan + 0j)
        for where, part in zip(bins, parts, strict=True):
            out[..., where] = part
        return out

    den = None
    if fits[0].den is not None:
        dens = [f.den for f in fits if f.den is not None]
        den = DenominatorTerm(put([d.gain for d in dens]), put([d.cov for d in dens]))
    return LocalFit(
        put([f.G for f in fits]),
        put([f.noise_cov for f in fits]),
        put([f.inv_gram for f in fits]),
        sum(f.n_bad for f in fits),
        min(f.dof for f in fits),
        den,
    )
