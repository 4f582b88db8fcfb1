"""Lifting of signals, spectra and FRFs, and their inverses.

Conventions (see DEVELOPERS.md):

* DFT ``X(k) = N**-0.5 * sum_n x[n] exp(-2j pi n k / N)``, see :func:`dft`.
* Time lifting of ``x`` (N, c) with factor F: ``x_bar[m] = [x[mF], x[mF+1], ..., x[mF+F-1]]``,
  shape (M, F*c) with M = N/F; column ``i*c + ch`` holds sample ``mF+i`` of channel ``ch``.
* Frequency lifting of a spectrum ``X`` (N, c): ``X_tilde(k) = [X(k), X(k+M), ..., X(k+(F-1)M)]``,
  shape (M, F*c); column ``l*c + ch`` holds alias ``l`` of channel ``ch``.
* The two are related by the unitary ``T(k) = W D(k)``:
  ``X_tilde(k) = T(k) X_bar(k)`` with ``W[l, i] = F**-0.5 exp(-2j pi i l / F)`` and
  ``D(k) = diag(exp(-2j pi i k / N))``, where ``X_bar`` is the M-point DFT of ``x_bar``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from .errors import ConfigError, DimensionError

Domain = Literal["frequency", "time"]


def _check_ratio(ratio: int) -> int:
    if isinstance(ratio, bool) or not isinstance(ratio, (int, np.integer)) or ratio < 1:
        raise ConfigError(f"ratio must be an integer >= 1, got {ratio!r}")
    return int(ratio)


def _as_2d(x: ArrayLike, name: str) -> NDArray:
    a = np.asarray(x)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DimensionError(f"{name} must have shape (n_samples, n_channels), got {a.shape}")
    return a


def _check_multiple(n: int, ratio: int, name: str) -> int:
    if n % ratio:
        raise DimensionError(
            f"{name} has {n} samples, not a multiple of ratio F={ratio}; "
            f"trim it to {n - n % ratio} samples explicitly")
    return n // ratio


def dft(x: ArrayLike, *, workers: int | None = None) -> NDArray[np.complex128]:
    """Unitary DFT along axis 0: ``X(k) = N**-0.5 sum_n x[n] exp(-2j pi n k/N)``.

    Parameters
    ----------
    x : array_like, shape (N, ...)

    Returns
    -------
    ndarray, shape (N, ...), complex128
    """
    return scipy.fft.fft(np.asarray(x), axis=0, norm="ortho", workers=workers)


def idft(X: ArrayLike, *, workers: int | None = None) -> NDArray[np.complex128]:
    """Inverse of :func:`dft` (complex result; take ``.real`` for real signals)."""
    return scipy.fft.ifft(np.asarray(X), axis=0, norm="ortho", workers=workers)


def time_lift(x: ArrayLike, ratio: int) -> NDArray:
    """Stack F consecutive samples: (N, c) -> (N/F, F*c).

    Raises
    ------
    DimensionError
        If N is not a multiple of ``ratio`` (never cut silently).
    """
    F = _check_ratio(ratio)
    a = _as_2d(x, "x")
    M = _check_multiple(a.shape[0], F, "x")
    return a.reshape(M, F * a.shape[1])


def time_unlift(x_bar: ArrayLike, ratio: int) -> NDArray:
    """Inverse of :func:`time_lift`: (M, F*c) -> (M*F, c)."""
    F = _check_ratio(ratio)
    a = _as_2d(x_bar, "x_bar")
    if a.shape[1] % F:
        raise DimensionError(f"x_bar has {a.shape[1]} columns, not a multiple of ratio F={F}")
    return a.reshape(a.shape[0] * F, a.shape[1] // F)


def freq_lift(X: ArrayLike, ratio: int) -> NDArray:
    """Stack the F aliases of a DFT spectrum: (N, c) -> (N/F, F*c).

    ``X_tilde[k, l*c + ch] = X[k + l*M, ch]`` with M = N/F.
    """
    F = _check_ratio(ratio)
    a = _as_2d(X, "X")
    M = _check_multiple(a.shape[0], F, "X")
    c = a.shape[1]
    return a.reshape(F, M, c).transpose(1, 0, 2).reshape(M, F * c)


def freq_unlift(X_tilde: ArrayLike, ratio: int) -> NDArray:
    """Inverse of :func:`freq_lift`: (M, F*c) -> (M*F, c)."""
    F = _check_ratio(ratio)
    a = _as_2d(X_tilde, "X_tilde")
    if a.shape[1] % F:
        raise DimensionError(f"X_tilde has {a.shape[1]} columns, not a multiple of ratio F={F}")
    M, c = a.shape[0], a.shape[1] // F
    return a.reshape(M, F, c).transpose(1, 0, 2).reshape(F * M, c)


def lifting_transform(bins: ArrayLike, ratio: int, n_samples: int,
                      n_channels: int = 1) -> NDArray[np.complex128]:
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
    F = _check_ratio(ratio)
    k = np.asarray(bins, dtype=float)
    i = np.arange(F)
    W = np.exp(-2j * np.pi * np.outer(i, i) / F) / np.sqrt(F)          # (l, i)
    D = np.exp(-2j * np.pi * k[:, None] * i[None, :] / n_samples)      # (K, i)
    T = W[None, :, :] * D[:, None, :]
    if n_channels > 1:
        T = np.kron(T, np.eye(n_channels)[None])
    return T


def lift_frf(G: ArrayLike, ratio: int, *, domain: Domain = "frequency") -> NDArray[np.complex128]:
    """Lift an LTI FRF given on all N DFT bins.

    Parameters
    ----------
    G : array_like, shape (N, n_out, n_in)
        ``G[k]`` at frequency ``k/N`` cycles per sample, k = 0..N-1.
    ratio : int
    domain : {"frequency", "time"}

    Returns
    -------
    ndarray, shape (N/F, F*n_out, F*n_in)
        Frequency-lifted: block diagonal ``diag(G(k + l M))``.
        Time-lifted: ``T(k)^H G_tilde(k) T(k)`` (the M-point FRF of the lifted system).
    """
    F = _check_ratio(ratio)
    Ga = np.asarray(G, dtype=complex)
    if Ga.ndim != 3:
        raise DimensionError(f"G must have shape (N, n_out, n_in), got {Ga.shape}")
    N, ny, nu = Ga.shape
    M = _check_multiple(N, F, "G")
    Gt = np.zeros((M, F * ny, F * nu), dtype=complex)
    blocks = Ga.reshape(F, M, ny, nu)
    for l in range(F):
        Gt[:, l * ny:(l + 1) * ny, l * nu:(l + 1) * nu] = blocks[l]
    if domain == "frequency":
        return Gt
    if domain == "time":
        k = np.arange(M)
        To = lifting_transform(k, F, N, ny)
        Ti = lifting_transform(k, F, N, nu)
        return np.conj(np.swapaxes(To, 1, 2)) @ Gt @ Ti
    raise ConfigError(f'domain must be "frequency" or "time", got {domain!r}')


def unlift_bins(bins: ArrayLike, ratio: int, n_samples: int) -> NDArray[np.int64]:
    """High-rate bins ``k + l*M`` of low-rate bins k, shape (K, F)."""
    F = _check_ratio(ratio)
    M = _check_multiple(n_samples, F, "n_samples")
    return np.asarray(bins, dtype=np.int64)[:, None] + M * np.arange(F)[None, :]


def unlift_frf(G_lifted: ArrayLike, ratio: int, *, domain: Domain = "frequency",
               bins: ArrayLike | None = None, n_samples: int | None = None) -> NDArray[np.complex128]:
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
    """
    F = _check_ratio(ratio)
    Gl = np.asarray(G_lifted, dtype=complex)
    if Gl.ndim != 3 or Gl.shape[1] % F or Gl.shape[2] % F:
        raise DimensionError(
            f"G_lifted must have shape (K, F*n_out, F*n_in) with F={F}, got {Gl.shape}")
    K = Gl.shape[0]
    ny, nu = Gl.shape[1] // F, Gl.shape[2] // F
    k = np.arange(K) if bins is None else np.asarray(bins, dtype=np.int64)
    N = K * F if n_samples is None else int(n_samples)
    blocks = Gl.reshape(K, F, ny, F, nu)
    if domain == "frequency":
        idx = np.arange(F)
        return blocks[:, idx, :, idx, :].transpose(1, 0, 2, 3)
    if domain == "time":
        kappa = unlift_bins(k, F, N)                                       # (K, l)
        phase = np.exp(-2j * np.pi * kappa[:, :, None] * np.arange(F)[None, None, :] / N)
        return np.einsum("kli,kiyu->klyu", phase, blocks[:, :, :, 0, :])
    raise ConfigError(f'domain must be "frequency" or "time", got {domain!r}')
