"""The PFG straight from data: the lifted closed-loop map r -> y, no controller model.

The PFG at high-rate bin ``k + l M`` is the 2-norm of block column l of the
frequency-lifted map ``J(k)`` (:mod:`mr_ident.numerics.pfg`). An LPM of the lifted
spectra r -> y identifies ``J(k)`` with its Kronecker covariance, so the PFG and its
first-order std follow from r_h and y_h alone (van Haren, Blanken, Oomen, MSSP 235, 2025,
identify the lifted closed loop directly). ``freq-lifted`` fits r -> [y; u] anyway: it
hands its J block by block to :func:`store_lifted_pfg`; the other methods call
:func:`fit_data_pfg`, one more lifted fit of r -> y.

Block by block, like the lifted methods: the lifted maps of a long record are never held
whole.
"""

from __future__ import annotations

import warnings

import numpy as np

from .arrays import ComplexArray, FloatArray
from .budget import block_bins
from .lifting import fold_half, freq_lift_half, half_spectrum, unlift_bins
from .lpm import lpm_bins_last
from .pfg import lifted_gains
from .threads import thread_map


def empty_pfg(n_samples: int) -> tuple[FloatArray, FloatArray]:
    """The arrays :func:`store_lifted_pfg` fills: gain and variance on bins 0..N//2 (NaN)."""
    return np.full(n_samples // 2 + 1, np.nan), np.full(n_samples // 2 + 1, np.nan)


def store_lifted_pfg(
    gain_half: FloatArray,
    var_half: FloatArray,
    bins: range,
    J: ComplexArray,
    row_cov: ComplexArray,
    col_cov: ComplexArray,
    ratio: int,
    n_samples: int,
) -> None:
    """The PFG of a block of a bins-last lifted fit, written to the half spectrum.

    Parameters
    ----------
    gain_half, var_half : ndarray, shape (N//2+1,)
        Written at the high-rate bins ``k + l M`` of ``bins`` (folded into 0..N//2: the
        PFG of a real loop is the same at kappa and N - kappa).
    bins : range
        Consecutive low-rate bins k of the block.
    J : ndarray, shape (F*n_y, F*n_r, K), bins last
    row_cov : ndarray, shape (F*n_y, F*n_y, K)
    col_cov : ndarray, shape (F*n_r, F*n_r, K)
        As :func:`~mr_ident.numerics.lpm.lpm_bins_last` returns them (the y rows of C_v).
    ratio, n_samples : int
    """
    gain, std = lifted_gains(
        J.transpose(2, 0, 1),
        ratio,
        row_cov=row_cov.transpose(2, 0, 1),
        col_cov=col_cov.transpose(2, 0, 1),
    )
    kappa = unlift_bins(np.arange(bins.start, bins.stop), ratio, n_samples)
    idx, _ = fold_half(kappa.ravel(), n_samples)
    gain_half[idx] = gain.ravel()
    var_half[idx] = std.ravel() ** 2


def fit_data_pfg(
    r: FloatArray,
    y: FloatArray,
    ratio: int,
    n: int,
    degree: int,
    dof: int,
    workers: int = 1,
) -> tuple[FloatArray, FloatArray]:
    """The PFG from a lifted LPM of r -> y: gain and variance on the bins 0..N//2.

    Parameters
    ----------
    r : ndarray, shape (N, n_r)
    y : ndarray, shape (N, n_y)
        High-rate signals, N a multiple of F (checked by the caller).
    ratio, n, degree, dof : int
        F and the LPM options (``dof`` their residual degrees of freedom, already checked
        for F*n_r lifted inputs).
    workers : int
        Threads over blocks of bins.

    Returns
    -------
    gain, var : ndarray, shape (N//2+1,)
        The PFG and its variance ``E dg^2`` (first order).
    """
    F, N = ratio, r.shape[0]
    M = N // F
    Rh, Yh = (half_spectrum(x, workers=workers) for x in (r, y))
    gain_half, var_half = empty_pfg(N)
    step = block_bins(F, r.shape[1], y.shape[1])
    ny = y.shape[1]

    def block(b0: int) -> int:
        kb = range(b0, min(b0 + step, M // 2 + 1))
        window = range(kb.start - n, kb.stop + n)
        G, Cv, Ainv, n_bad = lpm_bins_last(
            freq_lift_half(Rh, window, F, N), freq_lift_half(Yh, window, F, N), n, degree, dof
        )
        store_lifted_pfg(gain_half, var_half, kb, G, Cv[: F * ny, : F * ny], Ainv, F, N)
        return n_bad

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
