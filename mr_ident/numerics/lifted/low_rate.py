# SPDX-License-Identifier: Apache-2.0
"""The lifting rules of an output measured at the low rate only (``freq-lifted``).

``y_l[m] = y_h[m F + q]`` (q: the high-rate sample of each low-rate period at which y is
taken). Its M-point DFT sums the aliases of the high-rate one::

    sqrt(F) Y_l(k) = sum_l exp(2j pi kappa_l q / N) Y_h(kappa_l),   kappa_l = k + l M,

so with Y_h = P_h U_h the lifted map from U_tilde (alias-major) to sqrt(F) Y_l is one
block row, block l = exp(2j pi kappa_l q / N) P_h(kappa_l): every high-rate bin's plant.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..arrays import ComplexArray, FloatArray, IntArray
from ..lifting import check_ratio, spectrum_bins, unlift_bins


def low_rate_lift_half(
    half: list[ComplexArray], bins: range | IntArray, ratio: int, n_low: int
) -> ComplexArray:
    """``sqrt(F) Y_l(k)`` of a low-rate signal on consecutive low-rate bins (the row's output).

    Parameters
    ----------
    half : list of ndarray, each (M//2+1,)
        :func:`~mr_ident.numerics.fourier.half_spectrum` of the low-rate signal (M =
        ``n_low`` samples, c columns).
    bins : range or ndarray of int
        Low-rate bins k, usually consecutive (may reach below 0 or beyond M).
    ratio, n_low : int
        F and M.

    Returns
    -------
    ndarray, shape (len(bins), c)
    """
    F = check_ratio(ratio)
    idx = np.asarray(bins, dtype=np.int64)[:, None] % n_low
    out: ComplexArray = np.sqrt(F) * spectrum_bins(half, idx, n_low)[:, 0]
    return out


def unlift_row(
    G_row: ArrayLike, ratio: int, bins: ArrayLike, n_samples: int, y_phase: int = 0
) -> ComplexArray:
    """The high-rate FRF from the lifted map to a low-rate output (one block row).

    ``G(k + l M) = exp(-2j pi (k + l M) q / N) G_row(k)[:, block l]`` (the module docstring).

    Parameters
    ----------
    G_row : array_like, shape (K, n_out, F*n_in)
        Alias-major columns (index ``l*n_in + i``).
    ratio : int
    bins : array_like of int, shape (K,)
        The low-rate bins k of ``G_row``.
    n_samples : int
        N (high-rate samples).
    y_phase : int
        q, the high-rate sample (0..F-1) of each low-rate period at which y was taken.

    Returns
    -------
    ndarray, shape (K, F, n_out, n_in)
        Entry ``[j, l]`` at high-rate bin ``bins[j] + l M``, as
        :func:`~mr_ident.numerics.lifting.unlift_frf`.
    """
    F = check_ratio(ratio)
    G = np.asarray(G_row, dtype=complex)
    K, ny = G.shape[:2]
    kappa = unlift_bins(bins, F, n_samples)
    shift = np.exp(-2j * np.pi * kappa * (int(y_phase) / n_samples))  # (K, F)
    out: ComplexArray = G.reshape(K, ny, F, -1).transpose(0, 2, 1, 3) * shift[:, :, None, None]
    return out


def unlift_row_variance(row_diag: ArrayLike, col_diag: ArrayLike, ratio: int) -> FloatArray:
    """Variance ``E|dG|^2`` of every entry of :func:`unlift_row` (Kronecker covariance).

    ``row_diag`` (K, n_out) and ``col_diag`` (K, F*n_in) are the diagonals of the factors;
    returns (K, F, n_out, n_in) (the phase factor has modulus 1).
    """
    F = check_ratio(ratio)
    r = np.real(np.asarray(row_diag))
    c = np.real(np.asarray(col_diag))
    K = r.shape[0]
    var: FloatArray = r[:, None, :, None] * c.reshape(K, F, 1, -1)
    return var
