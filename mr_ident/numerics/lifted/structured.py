# SPDX-License-Identifier: Apache-2.0
"""The structured lifted estimator: the lifted loop's diagonal plant used, not re-estimated.

In frequency lifting the loop ``Ỹ = J̃ R̃``, ``Ũ = S̃ R̃`` has a *diagonal* plant,
``Ỹ = P̃ Ũ + Ṽ`` with ``P̃ = diag(P_h(k + l M))``: alias l of the output is the plant at the
high-rate bin ``κ = k + l M`` times alias l of the input, an LTI relation along the whole
high-rate axis. The lifted LPM (``freq-lifted``) ignores that and fits the full F×F maps
J̃ and S̃ (``(R+1)(F+1)`` unknowns per output in a window of 2n+1 bins), and the LTI LPM
(``lpm``) regresses on r at κ only, so the part of u that the other F-1 aliases of r drive
acts as noise and leaves an alias bias. Here, two stages (an instrumental-variable
estimate with the lifted r as instruments, Pintelon & Schoukens 2012, sec. 7.2-7.3 for
the LPM; van Haren, Blanken, Oomen 2022 for the lifting):

1. **Instrument.** LPM of Ũ on R̃ (lifted, F inputs, the S̃ half of ``freq-lifted``,
   degree :func:`instrument_degree`):
   ``Z_l(k) = Σ_m S̃_0(k)[l, m] R_m(k)``, the part of u_l driven by *all* F aliases of r
   (the best linear instrument in r; a function of r and of noise only through Ŝ).
2. **Per alias, along the high-rate axis.** LPM with input Z_l on the outputs
   ``[Y_l; U_l]`` in the window ``κ-n..κ+n`` (the bins ``k-n..k+n`` of alias l), then the
   indirect step ``P_h(κ) = J'_l S'_l^-1``. With noise-free data ``U_l = Z_l`` up to the
   LPM's own polynomial error, so ``J' = P_h S'`` and the estimate is exact like the
   lifted one; with noise, each alias fits ``(R+1)(n_u+1)`` unknowns per output, as the LTI
   LPM does, and no alias term is left in its residual.

Covariance (first order, the instrument treated as given): the second stage is an LPM,
so ``Cov(vec[J'; S']) = C_v ⊗ (KᴴK)⁻¹`` and, as for the indirect step of every method,
``Var P[a, b] = (E C_v Eᴴ)[a, a] · (S'^-T A^-1 conj S'^-1)[b, b]`` with ``E = [I, -P]``.
``E C_v Eᴴ`` is the covariance of ``y_l - P u_l``: the output noise at κ.

Shapes: lifted spectra are alias-major (``l·c + ch``); the fits are bins-last, as
:func:`~mr_ident.numerics.local.lpm.lpm_bins_last` returns them.
"""

from __future__ import annotations

import numpy as np

from ..arrays import ComplexArray, FloatArray, IntArray
from ..local.fit import LocalFit, local_fit


def instrument_degree(degree: int) -> int:
    """Polynomial degree of the first stage: ``max(R - 1, 0)``.

    The instrument need only be a good function of r: an error e in it leaves
    ``U = S' Z + e`` in the second stage, e acting like the alias term of the LTI LPM but
    scaled by its small size (paper's loop, 600 s, noise-free: 1.7e-10 with R - 1 against
    4e-11 with R; with noise no difference), and R - 1 takes (F n_r + 1) unknowns per
    output off the costlier, lifted fit (a quarter of the time).
    """
    return max(degree - 1, 0)


def instrument(S: ComplexArray, R_lifted: ComplexArray) -> ComplexArray:
    """``Z(k) = S̃(k) R̃(k)``: the part of the lifted input driven by the lifted reference.

    Parameters
    ----------
    S : ndarray, shape (F*n_u, F*n_r, K), complex
        The lifted r -> u map, bins last. NaN bins give a zero instrument (no excitation:
        the second stage flags its windows instead of spreading NaN).
    R_lifted : ndarray, shape (K, F*n_r), complex

    Returns
    -------
    ndarray, shape (K, F*n_u), complex128
    """
    Z: ComplexArray = np.einsum("abk,kb->ka", S, R_lifted)
    Z[~np.isfinite(Z)] = 0.0
    return Z


def structured_block(
    R_lifted: ComplexArray,
    Y_lifted: ComplexArray,
    U_lifted: ComplexArray,
    ratio: int,
    n: int,
    degree: int,
    *,
    local: str = "polynomial",
    missing: FloatArray | None = None,
    centres: IntArray | None = None,
) -> LocalFit:
    """Both stages on one block of B consecutive low-rate bins.

    Parameters
    ----------
    R_lifted, Y_lifted, U_lifted : ndarray, shapes (B + 4n, F*n_c), c = r, y, u
        Frequency-lifted spectra on the bins ``k0-2n .. k0+B+2n-1`` (the block with 2n
        bins of context each side: n for the second stage's window, n more for the
        first's).
    ratio, n, degree : int
        F, the window half-width (both stages) and the polynomial degree R (the second
        stage; the first uses :func:`instrument_degree`).
    missing : ndarray, shape (n_y + n_u,), optional
        The share of filled samples of every channel of [y; u] (std correction,
        :func:`~mr_ident.numerics.local.fit.local_fit`).
    local : {"polynomial", "rational"}
        The local model of both stages (:mod:`mr_ident.numerics.local.fit`); a rational first
        stage keeps the order R (its denominator follows the loop's modes).
    centres : ndarray of int, optional
        The block's bins (increasing, in 0..B-1) to fit in the second stage; default all B.

    Returns
    -------
    LocalFit
        The second stage: G ``[J'; S']`` (n_y + n_u, n_u, F * B) of every alias, bins
        ordered ``l * B + j`` (alias l of bin k0 + j; B of ``centres`` when given), its noise
        covariance and inverse
        Gram matrix (and denominator term); ``n_bad`` counts the bins whose estimate is
        NaN: a rank-deficient regressor in either stage (a bin without excitation gives a
        zero instrument, so its second-stage windows are flagged rather than fed NaN).

    Raises
    ------
    ConfigError
        From the degrees-of-freedom rule (checked by the caller, via the method's options).
    """
    F = ratio
    ny, nu = Y_lifted.shape[1] // F, U_lifted.shape[1] // F
    B = R_lifted.shape[0] - 4 * n
    # Stage 1: the lifted S on the block and n bins each side; the instrument there.
    d1 = instrument_degree(degree) if local == "polynomial" else degree
    Z = instrument(local_fit(local, R_lifted, U_lifted, n, d1).G, R_lifted[n:-n])  # (B+2n, F nu)
    # Stage 2: the F aliases one after another along the bins, one LPM for all; the
    # windows that straddle two aliases (2n per alias) are computed and dropped.
    W = B + 2 * n
    ext = slice(n, n + W)
    Zc = Z.reshape(W, F, nu).transpose(1, 0, 2).reshape(F * W, nu)
    Yc = Y_lifted[ext].reshape(W, F, ny).transpose(1, 0, 2)
    Uc = U_lifted[ext].reshape(W, F, nu).transpose(1, 0, 2)
    Oc = np.concatenate([Yc, Uc], axis=2).reshape(F * W, ny + nu)
    own = np.arange(B) if centres is None else centres
    keep = (np.arange(F)[:, None] * W + own[None, :]).ravel()
    fit = local_fit(local, Zc, Oc, n, degree, missing=missing, centres=keep)
    bad = ~np.isfinite(fit.G).all(axis=(0, 1))
    return LocalFit(fit.G, fit.noise_cov, fit.inv_gram, int(bad.sum()), fit.dof, fit.den)
