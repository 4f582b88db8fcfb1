# SPDX-License-Identifier: Apache-2.0
"""Lifting of signals, spectra and FRFs, and their inverses: every lifting rule in one place.

Conventions (see DEVELOPERS.md):

* DFT ``X(k) = N**-0.5 * sum_n x[n] exp(-2j pi n k / N)``, see :func:`dft`.
* Time lifting of ``x`` (N, c) with factor F: ``x_bar[m] = [x[mF], x[mF+1], ..., x[mF+F-1]]``,
  shape (M, F*c) with M = N/F; column ``i*c + ch`` holds sample ``mF+i`` of channel ``ch``.
* Frequency lifting of a spectrum ``X`` (N, c): ``X_tilde(k) = [X(k), X(k+M), ..., X(k+(F-1)M)]``,
  shape (M, F*c); column ``l*c + ch`` holds alias ``l`` of channel ``ch``.
* The two are related by the unitary ``T(k) = W D(k)``:
  ``X_tilde(k) = T(k) X_bar(k)`` with ``W[l, i] = F**-0.5 exp(-2j pi i l / F)`` and
  ``D(k) = diag(exp(-2j pi i k / N))``, where ``X_bar`` is the M-point DFT of ``x_bar``.
* Real signals: their DFT is kept on bins 0..N//2 (:func:`half_spectrum`); any bin is
  read through ``X(N - k) = conj X(k)`` (:func:`spectrum_bins`, :func:`half_to_full`,
  :func:`fold_half`).

The DFT and the half spectra live in :mod:`~mr_ident.numerics.fourier`; their names are
re-exported here, beside the rules that lift them.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError, DimensionError
from .arrays import AnyArray, ComplexArray, FloatArray, IntArray
from .fourier import dft as dft
from .fourier import fold_half as fold_half
from .fourier import half_spectra as half_spectra
from .fourier import half_spectrum as half_spectrum
from .fourier import half_to_full as half_to_full
from .fourier import idft as idft
from .fourier import spectrum_bins as spectrum_bins

Domain = Literal["frequency", "time"]


def check_ratio(ratio: object) -> int:
    """The lifting factor F as an int; ConfigError unless an integer >= 1."""
    if isinstance(ratio, bool) or not isinstance(ratio, (int, np.integer)) or ratio < 1:
        raise ConfigError(f"ratio must be an integer >= 1, got {ratio!r}")
    return int(ratio)


def check_sample_of_period(name: str, value: object, ratio: int) -> int:
    """A sample of the low-rate period (0..F-1) as an int; ConfigError naming ``name``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, np.integer))
        or not (0 <= value < ratio)
    ):
        raise ConfigError(f"{name} must be an integer in 0..F-1 = 0..{ratio - 1}, got {value!r}")
    return int(value)


def check_multiple(n: int, ratio: int, name: str) -> int:
    """``n // ratio``; DimensionError (never a silent cut) when ``n`` is not a multiple."""
    if n % ratio:
        raise DimensionError(
            f"{name} has {n} samples, not a multiple of ratio F={ratio}; "
            f"trim it to {n - n % ratio} samples explicitly"
        )
    return n // ratio


def _as_2d(x: ArrayLike, name: str) -> AnyArray:
    a = np.asarray(x)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DimensionError(f"{name} must have shape (n_samples, n_channels), got {a.shape}")
    return a


def time_lift(x: ArrayLike, ratio: int) -> AnyArray:
    """Stack F consecutive samples: (N, c) -> (N/F, F*c) (a view when ``x`` is contiguous).

    Column ``i*c + ch`` of row m holds sample ``mF + i`` of channel ``ch`` [1]_.

    Parameters
    ----------
    x : array_like, shape (N,) or (N, c)
        A signal at the high rate; N a multiple of F.
    ratio : int
        F, the samples per low-rate period.

    Returns
    -------
    ndarray, shape (N/F, F*c)

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1.
    DimensionError
        If N is not a multiple of ``ratio`` (never cut silently), or ``x`` is not 1-D or 2-D.

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import time_lift, time_unlift
    >>> time_lift(np.arange(6.0), 3)
    array([[0., 1., 2.],
           [3., 4., 5.]])
    >>> time_unlift(time_lift(np.arange(6.0), 3), 3).ravel()
    array([0., 1., 2., 3., 4., 5.])
    """
    F = check_ratio(ratio)
    a = _as_2d(x, "x")
    M = check_multiple(a.shape[0], F, "x")
    return a.reshape(M, F * a.shape[1])


def time_unlift(x_bar: ArrayLike, ratio: int) -> AnyArray:
    """Inverse of :func:`time_lift`: (M, F*c) -> (M*F, c).

    Parameters
    ----------
    x_bar : array_like, shape (M,) or (M, F*c)
    ratio : int

    Returns
    -------
    ndarray, shape (M*F, c)

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1.
    DimensionError
        If the columns are not a multiple of F, or ``x_bar`` is not 1-D or 2-D.
    """
    F = check_ratio(ratio)
    a = _as_2d(x_bar, "x_bar")
    if a.shape[1] % F:
        raise DimensionError(f"x_bar has {a.shape[1]} columns, not a multiple of ratio F={F}")
    return a.reshape(a.shape[0] * F, a.shape[1] // F)


def freq_lift(X: ArrayLike, ratio: int) -> AnyArray:
    """Stack the F aliases of a DFT spectrum: (N, c) -> (N/F, F*c).

    ``X_tilde[k, l*c + ch] = X[k + l*M, ch]`` with M = N/F: the bins one low-rate bin k
    folds together, alias-major [1]_.

    Parameters
    ----------
    X : array_like, shape (N,) or (N, c)
        A spectrum on all N bins (:func:`dft`); N a multiple of F.
    ratio : int

    Returns
    -------
    ndarray, shape (N/F, F*c)

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1.
    DimensionError
        If N is not a multiple of F, or ``X`` is not 1-D or 2-D.

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import freq_lift, freq_unlift
    >>> freq_lift(np.arange(6.0), 3)  # bin k beside its aliases k + 2 and k + 4
    array([[0., 2., 4.],
           [1., 3., 5.]])
    >>> freq_unlift(freq_lift(np.arange(6.0), 3), 3).ravel()
    array([0., 1., 2., 3., 4., 5.])
    """
    F = check_ratio(ratio)
    a = _as_2d(X, "X")
    M = check_multiple(a.shape[0], F, "X")
    c = a.shape[1]
    return a.reshape(F, M, c).transpose(1, 0, 2).reshape(M, F * c)


def freq_lift_half(
    half: list[ComplexArray], bins: range | IntArray, ratio: int, n_samples: int
) -> ComplexArray:
    """Frequency-lifted spectrum ``X_tilde(k)`` of a real signal on consecutive low-rate bins.

    Parameters
    ----------
    half : list of ndarray, each (N//2+1,)
        :func:`half_spectrum` of the signal (c columns).
    bins : range or ndarray of int
        Low-rate bins k, usually consecutive (may reach below 0 or beyond M: the spectrum
        is periodic, so windows around every bin are gathered the same way).
    ratio, n_samples : int
        F and N.

    Returns
    -------
    ndarray, shape (len(bins), F*c)
        Alias-major, as :func:`freq_lift` (``freq_lift(dft(x))[bins]`` without the full DFT).
    """
    F = check_ratio(ratio)
    M = check_multiple(n_samples, F, "n_samples")
    idx = (np.asarray(bins, dtype=np.int64)[:, None] + M * np.arange(F)[None, :]) % n_samples
    return spectrum_bins(half, idx, n_samples).reshape(idx.shape[0], -1)


def freq_unlift(X_tilde: ArrayLike, ratio: int) -> AnyArray:
    """Inverse of :func:`freq_lift`: (M, F*c) -> (M*F, c).

    Parameters
    ----------
    X_tilde : array_like, shape (M,) or (M, F*c)
    ratio : int

    Returns
    -------
    ndarray, shape (M*F, c)

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1.
    DimensionError
        If the columns are not a multiple of F, or ``X_tilde`` is not 1-D or 2-D.
    """
    F = check_ratio(ratio)
    a = _as_2d(X_tilde, "X_tilde")
    if a.shape[1] % F:
        raise DimensionError(f"X_tilde has {a.shape[1]} columns, not a multiple of ratio F={F}")
    M, c = a.shape[0], a.shape[1] // F
    return a.reshape(M, F, c).transpose(1, 0, 2).reshape(F * M, c)


def lifting_transform(
    bins: ArrayLike, ratio: int, n_samples: int, n_channels: int = 1
) -> ComplexArray:
    """The unitary ``T(k) = W D(k)`` mapping time-lifted to frequency-lifted spectra.

    Parameters
    ----------
    bins : array_like of int, shape (K,)
        Low-rate bins k.
    ratio, n_samples : int
        F and N.
    n_channels : int
        Channels c per sample; T acts as ``T(k) kron I_c``.

    Returns
    -------
    ndarray, shape (K, F*c, F*c)
    """
    F = check_ratio(ratio)
    k = np.asarray(bins, dtype=float)
    i = np.arange(F)
    W = np.exp(-2j * np.pi * np.outer(i, i) / F) / np.sqrt(F)  # (l, i)
    D = np.exp(-2j * np.pi * k[:, None] * i[None, :] / n_samples)  # (K, i)
    T: ComplexArray = W[None, :, :] * D[:, None, :]
    if n_channels > 1:
        T = np.asarray(np.kron(T, np.eye(n_channels)[None]), dtype=np.complex128)
    return T


def lift_frf(
    G: ArrayLike, ratio: int, *, domain: Domain = "frequency", bins: ArrayLike | None = None
) -> ComplexArray:
    """Lift an LTI FRF given on all N DFT bins.

    Parameters
    ----------
    G : array_like, shape (N, n_out, n_in)
        ``G[k]`` at frequency ``k/N`` cycles per sample, k = 0..N-1.
    ratio : int
    domain : {"frequency", "time"}
    bins : array_like of int, shape (K,), optional
        Low-rate bins to lift at (default all, 0..M-1); any integers (periodic in M).

    Returns
    -------
    ndarray, shape (K, F*n_out, F*n_in)
        Frequency-lifted: block diagonal ``diag(G(k + l M))``.
        Time-lifted: ``T(k)^H G_tilde(k) T(k)`` (the M-point FRF of the lifted system).

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1 or ``domain`` not "frequency" or "time".
    DimensionError
        If ``G`` is not 3-D or N not a multiple of F.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import lift_frf, unlift_frf
    >>> G = np.arange(1.0, 5.0).reshape(4, 1, 1)  # on N = 4 bins
    >>> lift_frf(G, 2)[1].real  # low-rate bin 1: bins 1 and 3
    array([[2., 0.],
           [0., 4.]])
    >>> unlift_frf(lift_frf(G, 2), 2).transpose(1, 0, 2, 3).ravel().real
    array([1., 2., 3., 4.])
    """
    F = check_ratio(ratio)
    Ga = np.asarray(G, dtype=complex)
    if Ga.ndim != 3:
        raise DimensionError(f"G must have shape (N, n_out, n_in), got {Ga.shape}")
    if domain not in ("frequency", "time"):
        raise ConfigError(f'domain must be "frequency" or "time", got {domain!r}')
    N, ny, nu = Ga.shape
    M = check_multiple(N, F, "G")
    k = np.arange(M) if bins is None else np.asarray(bins, dtype=np.int64)
    Gt = np.zeros((k.size, F * ny, F * nu), dtype=complex)
    for l in range(F):
        Gt[:, l * ny : (l + 1) * ny, l * nu : (l + 1) * nu] = Ga[(k + l * M) % N]
    if domain == "frequency":
        return Gt
    To = lifting_transform(k, F, N, ny)
    Ti = lifting_transform(k, F, N, nu)
    out: ComplexArray = np.conj(np.swapaxes(To, 1, 2)) @ Gt @ Ti
    return out


def unlift_bins(bins: ArrayLike, ratio: int, n_samples: int) -> IntArray:
    """High-rate bins ``k + l*M`` of low-rate bins k, shape (K, F)."""
    F = check_ratio(ratio)
    M = check_multiple(n_samples, F, "n_samples")
    out: IntArray = np.asarray(bins, dtype=np.int64)[:, None] + M * np.arange(F)[None, :]
    return out


def _unlift_phase(bins: ArrayLike | None, K: int, F: int, n_samples: int | None) -> ComplexArray:
    """``exp(-2j pi kappa i / N)`` for kappa = bins + l M: shape (K, F (l), F (i))."""
    k = np.arange(K) if bins is None else np.asarray(bins, dtype=np.int64)
    N = K * F if n_samples is None else int(n_samples)
    kappa = unlift_bins(k, F, N)
    out: ComplexArray = np.exp(-2j * np.pi * kappa[:, :, None] * np.arange(F)[None, None, :] / N)
    return out


def unlift_frf(
    G_lifted: ArrayLike,
    ratio: int,
    *,
    domain: Domain = "frequency",
    bins: ArrayLike | None = None,
    n_samples: int | None = None,
) -> ComplexArray:
    """Recover the high-rate LTI FRF from a lifted one.

    Frequency-lifted: the diagonal blocks, ``G(k + l M) = G_tilde(k)[l, l]``.
    Time-lifted: the first block column (polyphase components),
    ``G(kappa) = sum_i exp(-2j pi i kappa / N) G_bar(k)[i, 0]``.

    Parameters
    ----------
    G_lifted : array_like, shape (K, F*n_out, F*n_in)
    ratio : int
    domain : {"frequency", "time"}
    bins : array_like of int, shape (K,), optional
        Low-rate bins of ``G_lifted``; default ``0..K-1`` (then N = K*F).
    n_samples : int, optional
        N; default ``K * F``.

    Returns
    -------
    ndarray, shape (K, F, n_out, n_in)
        Entry ``[j, l]`` is the FRF at high-rate bin ``bins[j] + l*M``
        (:func:`unlift_bins`); for ``bins = 0..M-1`` reshape with
        ``out.transpose(1, 0, 2, 3).reshape(N, n_out, n_in)``.

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1 or ``domain`` not "frequency" or "time".
    DimensionError
        If ``G_lifted`` is not (K, F*n_out, F*n_in), or N not a multiple of F (time).
    """
    F = check_ratio(ratio)
    Gl = np.asarray(G_lifted, dtype=complex)
    if Gl.ndim != 3 or Gl.shape[1] % F or Gl.shape[2] % F:
        raise DimensionError(
            f"G_lifted must have shape (K, F*n_out, F*n_in) with F={F}, got {Gl.shape}"
        )
    K = Gl.shape[0]
    ny, nu = Gl.shape[1] // F, Gl.shape[2] // F
    blocks = Gl.reshape(K, F, ny, F, nu)
    if domain == "frequency":
        idx = np.arange(F)
        diag: ComplexArray = blocks[:, idx, :, idx, :].transpose(1, 0, 2, 3)
        return diag
    if domain == "time":
        phase = _unlift_phase(bins, K, F, n_samples)
        out: ComplexArray = np.einsum("kli,kiyu->klyu", phase, blocks[:, :, :, 0, :])
        return out
    raise ConfigError(f'domain must be "frequency" or "time", got {domain!r}')


def unlift_variance(
    row_cov: ArrayLike,
    col_cov: ArrayLike,
    ratio: int,
    *,
    domain: Domain = "frequency",
    bins: ArrayLike | None = None,
    n_samples: int | None = None,
) -> FloatArray:
    """Variance ``E|dG|^2`` of every entry of :func:`unlift_frf`.

    For a lifted estimate whose covariance is the Kronecker product ``row_cov (x) col_cov``
    (the LPM's form).

    Parameters
    ----------
    row_cov : array_like, shape (K, F*n_out, F*n_out), or its diagonal (K, F*n_out)
        The diagonal suffices in the frequency domain; the time domain needs the matrix.
    col_cov : array_like, shape (K, F*n_in, F*n_in), or its diagonal (K, F*n_in)
    ratio, domain, bins, n_samples
        As :func:`unlift_frf`.

    Returns
    -------
    ndarray, shape (K, F, n_out, n_in), float64
    """
    F = check_ratio(ratio)
    R = np.asarray(row_cov)
    C = np.asarray(col_cov)
    cdiag = np.real(C if C.ndim == 2 else np.diagonal(C, axis1=1, axis2=2))
    K, nu = cdiag.shape[0], cdiag.shape[1] // F
    if domain == "frequency":
        rdiag = np.real(R if R.ndim == 2 else np.diagonal(R, axis1=1, axis2=2))
        ny = rdiag.shape[1] // F
        var: FloatArray = (
            rdiag.reshape(K, F, ny)[:, :, :, None] * cdiag.reshape(K, F, nu)[:, :, None, :]
        )
        return var
    if domain == "time":
        if R.ndim != 3:
            raise DimensionError(
                f"the time domain needs the full row_cov (K, F*n_out, F*n_out), got {R.shape}"
            )
        ny = R.shape[1] // F
        phase = _unlift_phase(bins, K, F, n_samples)  # (K, l, i)
        rdiag = np.diagonal(R.reshape(K, F, ny, F, ny), axis1=2, axis2=4)  # (K, i, j, y)
        quad = np.real(np.einsum("kli,kijy,klj->kly", phase, rdiag, np.conj(phase)))
        c0 = cdiag.reshape(K, F, nu)[:, 0, :]  # (K, u): block column 0
        tvar: FloatArray = quad[:, :, :, None] * c0[:, None, None, :]
        return tvar
    raise ConfigError(f'domain must be "frequency" or "time", got {domain!r}')
