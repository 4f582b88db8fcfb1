# SPDX-License-Identifier: Apache-2.0
"""Local polynomial method (LPM), MIMO, batched over all frequency bins.

Model in the window ``r = -n..n`` around every centre bin k
(Pintelon & Schoukens 2012, ch. 7)::

    Y(k+r) = sum_s G_s (r/n)^s U(k+r) + sum_s T_s (r/n)^s + V(k+r),   s = 0..R

``G(k) = G_0`` is the estimate, the ``T_s`` model the transient (leakage).
The noise covariance ``C_v`` follows from the residuals with
``q = 2n+1 - (R+1)(n_u+1)`` degrees of freedom, and
``Cov(G[a,b], G[a2,b2]) = C_v[a,a2] * (K^H K)^-1[(0,b),(0,b2)]``.

How it is fast
--------------
* One regressor (built from the inputs only) serves all outputs: J and S of the
  indirect method are fitted in one pass.
* Every entry of ``K^H K``, ``K^H Y`` and ``Y^H Y`` is a windowed sum of a product
  signal with a kernel ``(r/n)^q``; those sums are computed for all bins at once
  (:mod:`~mr_ident.numerics.local.window_sums`: a banded Toeplitz product for narrow
  windows, moments merged by doubling for wide ones, at a cost that no longer grows
  with n).
* The polynomial (transient) part is the same in every window: its Cholesky factor
  is constant, and the transient columns of the factor and of the forward solve come
  straight out of the windowed sums (kernels from the window's orthonormal
  polynomials), so eliminating the transient only lengthens the inner products.
* The small Hermitian systems are solved by a left-looking Cholesky factorisation
  vectorised over bins (arrays laid out bins-last), never a Python loop per bin.
* Chunks of bins are independent and run on threads (NumPy releases the GIL).

Numerics: the regressors are scaled (``r/n`` in [-1, 1]); the normal equations are
formed from exact windowed sums and solved by Cholesky, so the error is about
``eps * cond(K)^2`` with cond(K) the condition number of the *scaled* regressor
(tens for a broadband excitation): about 1e-12, far below any noise level. Bins
whose regressor is rank deficient (no excitation) come out as NaN with a warning.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...errors import ConfigError, DataError, DimensionError, FieldError
from ..arrays import ComplexArray, readonly
from ..budget import chunk_bins
from ..threads import resolve_workers, thread_map
from .normal import Layout, chunk_sums, factor, noise_cov
from .strided import lpm_strided


@dataclass(frozen=True)
class LPMFit:
    """Raw LPM result for K centre bins.

    Attributes
    ----------
    G : ndarray, shape (K, n_out, n_in), complex128
    noise_cov : ndarray, shape (K, n_out, n_out), complex128
        ``C_v[a, a2] = E[V_a conj(V_a2)]`` per DFT bin.
    inv_gram : ndarray, shape (K, n_in, n_in), complex128
        The G_0 block of ``(K^H K)^-1``.
    dof : int
        Residual degrees of freedom q.

    Raises
    ------
    DimensionError
        If the shapes do not agree: G (K, n_out, n_in), noise_cov (K, n_out, n_out),
        inv_gram (K, n_in, n_in).

    Notes
    -----
    The covariance of G at a bin is ``inv_gram (x) noise_cov`` (Kronecker, [1]_).

    References
    ----------
    .. [1] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012, ch. 7.
    """

    G: ComplexArray
    noise_cov: ComplexArray
    inv_gram: ComplexArray
    dof: int

    def __post_init__(self) -> None:
        G = readonly(self.G, np.complex128)
        K, n_out, n_in = G.shape if G.ndim == 3 else (-1, -1, -1)
        if (
            K < 0
            or self.noise_cov.shape != (K, n_out, n_out)
            or self.inv_gram.shape != (K, n_in, n_in)
        ):
            raise DimensionError(
                f"LPMFit: G (K, n_out, n_in), noise_cov (K, n_out, n_out), inv_gram "
                f"(K, n_in, n_in) expected, got {G.shape}, {self.noise_cov.shape}, "
                f"{self.inv_gram.shape}"
            )
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "noise_cov", readonly(self.noise_cov, np.complex128))
        object.__setattr__(self, "inv_gram", readonly(self.inv_gram, np.complex128))


def dof(n: int, degree: int, n_in: int) -> int:
    """Residual degrees of freedom of one LPM window: ``q = 2n+1 - (R+1)(n_in+1)``.

    2n+1 bins, each giving one equation per output; (R+1) n_in coefficients of G and R+1
    of the transient per output.
    """
    return 2 * n + 1 - (degree + 1) * (n_in + 1)


def smallest_n(degree: int, n_in: int, n_out: int, margin: int = 0) -> int:
    """The smallest window half-width n with ``dof(n, degree, n_in) > n_out + margin``.

    >>> smallest_n(2, 3, 6)             # 2n + 1 - 3 * 4 > 6 first holds at n = 9
    9
    """
    return (n_out + margin + (degree + 1) * (n_in + 1) - 1) // 2 + 1


def grid_bins(frequency: ArrayLike, df: float) -> NDArray[np.int64]:
    """The lines ``frequency`` (Hz) as bins of the grid ``df`` (Hz): ``rint(f / df)``.

    >>> grid_bins([0.1, 0.2, 0.3], 0.1).tolist()
    [1, 2, 3]
    """
    return np.rint(np.asarray(frequency, float) / df).astype(np.int64)


def reaches_dc(frequency: ArrayLike, df: float, n: ArrayLike) -> NDArray[np.bool_]:
    """The bins whose window (half-width ``n``, one or one per bin) reaches DC.

    Bin ``k = rint(f / df)`` of the grid ``df`` (Hz, ``fs / N``) with ``k <= n``: its window
    is one-sided there, and where the plant bends fast (an integrator's 1/f) its estimate's
    bias exceeds its std, so a test against a model leaves it out (and out of its count).
    A lifted fit's aliases of those bins, ``k = j N/F ± m`` with ``m <= n``, share the
    windows but not the bias, which follows the plant's bend at the low frequency
    (docs/diagnose.md: on 23 random loops with their exact model they stayed below half
    the threshold while the bins ``k <= n`` crossed it in 3): they are tested.

    >>> reaches_dc([0.1, 0.2, 0.3, 0.4], 0.1, 2).tolist()
    [True, True, False, False]
    """
    if not df > 0:
        raise ValueError(f"df must be positive (Hz), got {df}")
    return np.asarray(grid_bins(frequency, df) <= np.asarray(n, float), bool)


def check_window(n: int, degree: int) -> None:
    """ConfigError unless n (window half-width) is an integer >= 1 and the degree >= 0."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ConfigError(f"n (window half-width) must be an integer >= 1, got {n!r}")
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)) or degree < 0:
        raise ConfigError(f"degree R must be an integer >= 0, got {degree!r}")


def check_lpm_options(n: int, degree: int, n_in: int, n_out: int) -> int:
    """Validate the window half-width, degree and dimensions; return the dof q.

    Raises
    ------
    ConfigError
        If ``n < 1``, ``degree < 0`` or ``q = dof(n, R, n_in) <= n_out``.
    """
    check_window(n, degree)
    q = dof(n, degree, n_in)
    if q <= n_out:
        need = smallest_n(degree, n_in, n_out)
        raise FieldError(
            f"LPM degrees of freedom: 2n+1 - (R+1)(n_in+1) = {2 * n + 1} - "
            f"{degree + 1}*{n_in + 1} = {q} must exceed n_out = {n_out} "
            f"(n={n}, R={degree}, n_in={n_in}); use {{n}} >= {need} or a lower {{degree}}",
            "n",
            "degree",
        )
    return q


def lpm_bins_last(
    Ua: NDArray[np.complex128],
    Ya: NDArray[np.complex128],
    n: int,
    degree: int,
    q: int,
    workers: int = 1,
    *,
    centres: NDArray[np.intp] | None = None,
    offsets: int = 0,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.complex128], int]:
    """The engine of :func:`lpm` (options already checked, ``q`` their dof), bins last.

    Parameters
    ----------
    Ua, Ya : ndarray, shapes (K+2n, n_in), (K+2n, n_out), complex128
        Padded spectra, as :func:`lpm` takes them.
    n, degree, q : int
        Window half-width, degree R and the dof ``q = dof(n, degree, n_in)``.
    workers : int
        Threads over chunks of :func:`chunk_bins` bins (independent of each other).
    centres : ndarray of int, optional
        Increasing, in 0..K-1: fit those centre bins only (K of them in the outputs); the
        windowed sums run over the stretch they span in each chunk, the per-bin solve over
        them alone (a segment's windows that straddle two runs are not fitted).
    offsets : int
        > 0: every ``2 offsets + 1`` windows one is solved, and its local polynomial
        evaluated at the bins up to ``offsets`` from its centre
        (:func:`~mr_ident.numerics.local.strided.lpm_strided`).

    Returns
    -------
    G, noise_cov, inv_gram : ndarray, shapes (n_out, n_in, K), (n_out, n_out, K), (n_in, n_in, K)
        NaN at the bins whose regressor is rank deficient.
    n_bad : int
        The number of those bins.
    """
    n_in, n_out = Ua.shape[1], Ya.shape[1]
    if offsets:
        return lpm_strided(
            Ua, Ya, n, degree, q, workers, centres=centres, h=offsets, centred=lpm_bins_last
        )
    step = chunk_bins(n_in, n_out, degree)
    K_all = Ua.shape[0] - 2 * n
    K = K_all if centres is None else int(centres.size)
    lay = Layout.of(n, degree, n_in, n_out)
    G = np.empty((n_out, n_in, K), dtype=np.complex128)
    Cv = np.empty((n_out, n_out, K), dtype=np.complex128)
    Ainv = np.empty((n_in, n_in, K), dtype=np.complex128)

    def chunk(c0: int) -> int:
        # centre bins c0 .. c0 + step - 1 of the padded spectra; of them the selected ones,
        # written to the outputs from position k0; the sums are formed from centre bin first
        pick: NDArray[np.intp] | None = None
        if centres is None:
            k0, Kc, first = c0, min(step, K_all - c0), c0
        else:
            k0, stop = (int(i) for i in np.searchsorted(centres, (c0, c0 + step)))
            if stop == k0:
                return 0
            first = int(centres[k0])
            pick = centres[k0:stop] - first
            Kc = int(pick.size)
            if int(pick[-1]) + 1 == Kc:  # consecutive: nothing to drop
                pick = None
        span = Kc if pick is None else int(pick[-1]) + 1  # centres whose sums are formed
        sums = chunk_sums(Ua, Ya, first, span, pick, lay)
        L, W, bad = factor(sums, lay)
        # Back substitution for the trailing (G_0) block only: L_tt^H theta = W_t.
        t0 = lay.Q - n_in
        Ltt = L[t0:, t0:]
        theta = G[:, :, k0 : k0 + Kc]
        for j in range(n_in - 1, -1, -1):
            acc = W[t0 + j].copy()
            for m in range(j + 1, n_in):
                acc -= np.conj(Ltt[m, j]) * theta[:, m]
            theta[:, j] = acc / Ltt[j, j]
        # (A^-1)_tt = Ltt^-H Ltt^-1 via the lower-triangular inverse of Ltt.
        Li = np.zeros((n_in, n_in, Kc), dtype=np.complex128)
        for j in range(n_in):
            Li[j, j] = 1.0 / Ltt[j, j]
            for i in range(j + 1, n_in):
                Li[i, j] = -sum(Ltt[i, m] * Li[m, j] for m in range(j, i)) / Ltt[i, i]
        AI = Ainv[:, :, k0 : k0 + Kc]
        for row in range(n_in):
            for col in range(row, n_in):
                AI[row, col] = sum(np.conj(Li[m, row]) * Li[m, col] for m in range(col, n_in))
                AI[col, row] = np.conj(AI[row, col])
        noise_cov(sums[4], W, q, Cv[:, :, k0 : k0 + Kc])
        if bad.any():
            idx = np.nonzero(bad)[0] + k0
            G[:, :, idx] = np.nan
            Cv[:, :, idx] = np.nan
            Ainv[:, :, idx] = np.nan
        return int(bad.sum())

    n_bad = sum(thread_map(chunk, range(0, K_all, step), workers))
    d = np.arange(n_out)
    Cv[d, d] = np.maximum(Cv[d, d].real, 0.0)  # rounding can make tiny variances negative
    return G, Cv, Ainv, n_bad


def lpm(
    U: ArrayLike,
    Y: ArrayLike,
    *,
    n: int = 8,
    degree: int = 2,
    map_outputs: int | None = None,
    workers: int | None = None,
) -> LPMFit:
    """Fit the LPM at every bin of padded spectra.

    Parameters
    ----------
    U : array_like, shape (K + 2n, n_in), complex
        Input spectra, with ``n`` bins of context before the first and after the
        last centre bin (circular padding for periodic spectra: :func:`pad_circular`).
    Y : array_like, shape (K + 2n, n_out), complex
        Output spectra on the same bins.
    n : int, default 8
        Window half-width: 2n+1 bins per fit.
    degree : int, default 2
        Polynomial degree R of G and of the transient.
    map_outputs : int, optional
        Outputs of one map for the degrees-of-freedom check (default ``n_out``).
        The indirect method fits J and S in one pass (``n_out = n_y + n_u``) but
        checks ``q > n_y`` per map, as the paper does; the joint noise covariance
        is then still unbiased, though of rank ``min(q, n_out)``.
    workers : int, optional
        Threads over blocks of bins (default: every CPU available to the process;
        1 runs serially). The result does not depend on it.

    Returns
    -------
    LPMFit
        Estimates at the K centre bins.

    Raises
    ------
    DimensionError
        If U and Y disagree in length or are not 2-D.
    DataError
        If there are fewer than 2n+1 bins.
    ConfigError
        If ``n < 1``, ``degree < 0``, the degrees-of-freedom condition
        ``2n+1-(R+1)(n_in+1) > n_out`` fails, or ``workers`` is not None or a positive
        integer.

    Warns
    -----
    RuntimeWarning
        When some windows have a rank-deficient regressor; those bins are NaN.

    See Also
    --------
    pad_circular : the padding of a periodic spectrum.

    References
    ----------
    .. [1] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012, ch. 7.

    Examples
    --------
    A static gain of 2 seen through 64 bins of a random input, no noise: every
    estimate is 2 and the noise covariance 0.

    >>> import numpy as np
    >>> from mr_ident import lpm
    >>> rng = np.random.default_rng(0)
    >>> U = rng.standard_normal((64, 1)) + 1j * rng.standard_normal((64, 1))
    >>> fit = lpm(U, 2.0 * U, n=8, degree=2)
    >>> fit.G.shape                        # 64 - 2n centre bins, n_out, n_in
    (48, 1, 1)
    >>> bool(np.allclose(fit.G, 2.0)), fit.dof
    (True, 11)
    """
    Ua, Ya = _check_spectra(U, Y, n)
    q = check_lpm_options(
        n, degree, Ua.shape[1], Ya.shape[1] if map_outputs is None else map_outputs
    )
    G, Cv, Ainv, n_bad = lpm_bins_last(Ua, Ya, n, degree, q, resolve_workers(workers))
    warn_rank_deficient(n_bad, G.shape[-1])
    return LPMFit(
        G=G.transpose(2, 0, 1),
        noise_cov=Cv.transpose(2, 0, 1),
        inv_gram=Ainv.transpose(2, 0, 1),
        dof=q,
    )


def _check_spectra(
    U: ArrayLike, Y: ArrayLike, n: int
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    Ua = np.asarray(U, dtype=np.complex128)
    Ya = np.asarray(Y, dtype=np.complex128)
    if Ua.ndim != 2 or Ya.ndim != 2:
        raise DimensionError(
            f"U and Y must be 2-D (bins, channels), got {Ua.shape} and {Ya.shape}"
        )
    if Ua.shape[0] != Ya.shape[0]:
        raise DimensionError(
            f"U and Y must have the same number of bins, got {Ua.shape[0]} and {Ya.shape[0]}"
        )
    if Ua.shape[0] < 2 * n + 1:
        raise DataError(f"LPM needs at least 2n+1 = {2 * n + 1} bins, got {Ua.shape[0]}")
    return Ua, Ya


def warn_rank_deficient(n_bad: int, K: int, stacklevel: int = 3) -> None:
    """Warn (RuntimeWarning) that ``n_bad`` of ``K`` bins had a rank-deficient regressor."""
    if n_bad:
        warnings.warn(
            f"LPM: {n_bad} of {K} bins have a rank-deficient regressor "
            f"(too little excitation in the window); their estimate is NaN",
            RuntimeWarning,
            stacklevel=stacklevel,
        )


def pad_circular(X: ArrayLike, centres: ArrayLike, n: int) -> NDArray[np.complex128]:
    """Gather the bins ``centres[0]-n .. centres[-1]+n`` of a periodic spectrum.

    Parameters
    ----------
    X : array_like, shape (N, c)
        One period of a periodic spectrum (a DFT).
    centres : array_like of int, shape (K,)
        Consecutive centre bins.
    n : int
        Window half-width.

    Returns
    -------
    ndarray, shape (K + 2n, c)
        Bin ``centres[0] - n + j`` of the period in row j (indices modulo N).

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import pad_circular
    >>> pad_circular(np.arange(6.0)[:, None], [0, 1], 1).ravel()  # wraps at both ends
    array([5., 0., 1., 2.])
    """
    Xa = np.asarray(X)
    c = np.asarray(centres, dtype=np.int64)
    idx = np.arange(c[0] - n, c[-1] + n + 1) % Xa.shape[0]
    out: ComplexArray = Xa[idx]
    return out
