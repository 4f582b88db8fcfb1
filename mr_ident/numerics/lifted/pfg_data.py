# SPDX-License-Identifier: Apache-2.0
"""The PFG straight from data: the lifted closed-loop map r -> y, no controller model.

The PFG at high-rate bin ``k + l M`` is the 2-norm of block column l of the
frequency-lifted map ``J(k)`` (:mod:`mr_ident.numerics.lifted.pfg`). An LPM of the lifted
spectra r -> y identifies ``J(k)`` with its Kronecker covariance, so the PFG and its
first-order std follow from r_h and y_h alone (van Haren, Blanken, Oomen, MSSP 235, 2025,
identify the lifted closed loop directly). ``freq-lifted`` fits r -> [y; u] anyway: it
hands its J block by block to :func:`store_lifted_pfg`; the other methods call
:func:`fit_data_pfg`, the same lifted fit once more (r -> [y; u] with the method's local
model, :mod:`mr_ident.numerics.local.fit`: a rational model's denominator is common to y and
u), so that every method gives the same PFG from data. How close it comes noise-free is
a matter of the alias range (:mod:`mr_ident.numerics.lifted.alias_range`).

Block by block, like the lifted methods: the lifted maps of a long record are never held
whole.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..arrays import ComplexArray, FloatArray, IntArray
from ..budget import block_bins
from ..lifting import fold_half, freq_lift_half, half_spectra, unlift_bins
from ..local.fit import local_fit
from ..local.lrm import DenominatorTerm
from ..threads import thread_map
from .pfg import lifted_gains


def empty_pfg(n_samples: int) -> tuple[FloatArray, FloatArray]:
    """The arrays :func:`store_lifted_pfg` fills: gain and variance on bins 0..N//2 (NaN)."""
    return np.full(n_samples // 2 + 1, np.nan), np.full(n_samples // 2 + 1, np.nan)


def store_lifted_pfg(
    gain_half: FloatArray,
    var_half: FloatArray,
    bins: range | IntArray,
    J: ComplexArray,
    row_cov: ComplexArray,
    col_cov: ComplexArray,
    *,
    ratio: int,
    n_samples: int,
    den: DenominatorTerm | None = None,
) -> None:
    """The PFG of a block of a bins-last lifted fit, written to the half spectrum.

    Parameters
    ----------
    gain_half, var_half : ndarray, shape (N//2+1,)
        Written at the high-rate bins ``k + l M`` of ``bins`` (folded into 0..N//2: the
        PFG of a real loop is the same at kappa and N - kappa).
    bins : range or ndarray of int
        The low-rate bins k of the block.
    J : ndarray, shape (F*n_y, F*n_r, K), bins last
    row_cov : ndarray, shape (F*n_y, F*n_y, K)
    col_cov : ndarray, shape (F*n_r, F*n_r, K)
        As :func:`~mr_ident.numerics.local.fit.local_fit` returns them (the y rows of C_v).
    ratio, n_samples : int
    den : DenominatorTerm, optional
        A rational fit's denominator term, its gain cut to the y rows (F*n_y, F*n_r, R_d, K).
    """
    gain, std = lifted_gains(
        J.transpose(2, 0, 1),
        ratio,
        row_cov=row_cov.transpose(2, 0, 1),
        col_cov=col_cov.transpose(2, 0, 1),
        den=den,
    )
    kappa = unlift_bins(np.asarray(bins), ratio, n_samples)
    idx, _ = fold_half(kappa.ravel(), n_samples)
    gain_half[idx] = gain.ravel()
    var_half[idx] = std.ravel() ** 2


def fit_data_pfg(
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    ratio: int,
    n: int,
    degree: int,
    *,
    local: str = "polynomial",
    workers: int = 1,
    missing: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The PFG from the lifted local fit of r -> [y; u]: gain and variance on bins 0..N//2.

    Parameters
    ----------
    r : ndarray, shape (N, n_r)
    u : ndarray, shape (N, n_u)
    y : ndarray, shape (N, n_y)
        High-rate signals, N a multiple of F (checked by the caller).
    ratio, n, degree : int
        F and the window's options (checked by the caller for F*n_r lifted inputs).
    local : {"polynomial", "rational"}
        The local model (:func:`~mr_ident.numerics.local.fit.local_fit`), the method's.
    workers : int
        Threads over blocks of bins.
    missing : ndarray, shape (n_y + n_u,), optional
        The share of filled samples of every channel of [y; u] (std correction).

    Returns
    -------
    gain, var : ndarray, shape (N//2+1,)
        The PFG and its variance ``E dg^2`` (first order; a rational fit's denominator
        term included).
    """
    F, N = ratio, r.shape[0]
    M = N // F
    Rh, Uh, Yh = half_spectra([r, u, y], workers=workers)
    gain_half, var_half = empty_pfg(N)
    ny = y.shape[1]
    step = block_bins(F, r.shape[1], max(ny, u.shape[1]))
    share = None
    if missing is not None:
        share = np.concatenate([np.tile(missing[:ny], F), np.tile(missing[ny:], F)])

    def block(b0: int) -> int:
        kb = range(b0, min(b0 + step, M // 2 + 1))
        window = range(kb.start - n, kb.stop + n)
        Yl, Ul = (freq_lift_half(X, window, F, N) for X in (Yh, Uh))
        fit = local_fit(
            local,
            freq_lift_half(Rh, window, F, N),
            np.concatenate([Yl, Ul], axis=1),
            n,
            degree,
            missing=share,
        )
        d, rows = fit.den, slice(0, F * ny)
        den = None if d is None else DenominatorTerm(d.gain[rows], d.cov)
        G, Cv = fit.G[rows], fit.noise_cov[rows, rows]
        store_lifted_pfg(
            gain_half, var_half, kb, G, Cv, fit.inv_gram, ratio=F, n_samples=N, den=den
        )
        return fit.n_bad

    n_bad = sum(thread_map(block, range(0, M // 2 + 1, step), workers))
    if n_bad:
        warnings.warn(
            f"PFG from data: {n_bad} of {M // 2 + 1} lifted bins have a rank-deficient "
            "regressor (r does not excite its F aliases independently there, e.g. a held r); "
            "the PFG is NaN at their bins",
            RuntimeWarning,
            stacklevel=4,
        )
    return gain_half, var_half
