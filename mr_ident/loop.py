"""The multirate loop in the frequency-lifted domain.

Loop (DEVELOPERS.md): ``u_h = r_h - H_u K_l S_d y_h``, ``y_h = P_h u_h``.
``S_d`` samples ``y_h`` at the high-rate phase ``phase`` of every low-rate
period (``y_l[m] = y_h[mF + phase]``); ``H_u`` holds ``u_l[m]`` over the F
samples starting at ``mF + hold``, where ``hold = phase + delay`` (``delay`` is
a computation delay in high-rate samples, 0 by default).

For a record of N = M F samples and low-rate bin k, the frequency-lifted
controller is the rank-n_u matrix::

    C[(l,u), (l2,y)] = (1/F) exp(-2j pi kl hold/N) H0(kl) K_l(k)[u,y] exp(+2j pi kl2 phase/N)

with ``kl = k + l M`` and ``H0(kl) = sum_{i<F} exp(-2j pi i kl / N)``; then
``S = (I + C P)^-1`` (r -> u) and ``J = P S`` (r -> y), with
``P = diag(P_h(k + l M))``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ConfigError, DimensionError
from .lifting import _check_multiple, _check_ratio


def lifted_controller(K_low: ArrayLike, bins: ArrayLike, ratio: int, n_samples: int, *,
                      phase: int = 0, delay: int = 0) -> NDArray[np.complex128]:
    """Frequency-lifted controller ``C(k)``.

    Parameters
    ----------
    K_low : array_like, shape (K, n_u, n_y)
        Controller frequency response at the low-rate bins ``bins``
        (``z = exp(2j pi k / M)``).
    bins : array_like of int, shape (K,)
    ratio, n_samples : int
        F and N.
    phase : int
        High-rate sample (0..F-1) at which the controller samples y.
    delay : int
        Extra high-rate samples before the held output is applied (>= 0).

    Returns
    -------
    ndarray, shape (K, F*n_u, F*n_y)
    """
    F = _check_ratio(ratio)
    M = _check_multiple(n_samples, F, "n_samples")
    if not 0 <= phase < F:
        raise ConfigError(f"phase must be in 0..{F - 1}, got {phase}")
    if delay < 0:
        raise ConfigError(f"delay must be >= 0 high-rate samples, got {delay}")
    Kl = np.asarray(K_low, dtype=complex)
    k = np.asarray(bins, dtype=float)
    if Kl.ndim != 3 or Kl.shape[0] != k.size:
        raise DimensionError(f"K_low must have shape (len(bins)={k.size}, n_u, n_y), got {Kl.shape}")
    kl = k[:, None] + M * np.arange(F)[None, :]                          # (K, F)
    h0 = np.exp(-2j * np.pi * np.arange(F)[None, None, :] * kl[:, :, None] / n_samples).sum(-1)
    left = h0 * np.exp(-2j * np.pi * kl * (phase + delay) / n_samples) / F   # (K, F)
    right = np.exp(2j * np.pi * kl * phase / n_samples)                      # (K, F)
    nu, ny = Kl.shape[1:]
    C = left[:, :, None, None, None] * Kl[:, None, :, None, :] * right[:, None, None, :, None]
    return C.reshape(k.size, F * nu, F * ny)


def plant_lifted(P_full: ArrayLike, bins: ArrayLike, ratio: int) -> NDArray[np.complex128]:
    """Block-diagonal ``diag(P_h(k + l M))``, shape (K, F*n_y, F*n_u).

    ``P_full`` has shape (N, n_y, n_u): the plant on every DFT bin 0..N-1.
    """
    F = _check_ratio(ratio)
    P = np.asarray(P_full, dtype=complex)
    N, ny, nu = P.shape
    M = _check_multiple(N, F, "P_full")
    k = np.asarray(bins, dtype=np.int64)
    out = np.zeros((k.size, F * ny, F * nu), dtype=complex)
    for l in range(F):
        out[:, l * ny:(l + 1) * ny, l * nu:(l + 1) * nu] = P[(k + l * M) % N]
    return out


def closed_loop_maps(P_full: ArrayLike, K_low: ArrayLike, bins: ArrayLike, ratio: int, *,
                     phase: int = 0, delay: int = 0
                     ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Frequency-lifted closed-loop maps ``J`` (r -> y) and ``S`` (r -> u).

    Parameters
    ----------
    P_full : array_like, shape (N, n_y, n_u)
        High-rate plant on every DFT bin.
    K_low : array_like, shape (K, n_u, n_y)
        Controller at the low-rate bins ``bins``.
    bins : array_like of int, shape (K,)

    Returns
    -------
    J : ndarray, shape (K, F*n_y, F*n_u)
    S : ndarray, shape (K, F*n_u, F*n_u)
    """
    F = _check_ratio(ratio)
    N = np.shape(P_full)[0]
    Pt = plant_lifted(P_full, bins, F)
    C = lifted_controller(K_low, bins, F, N, phase=phase, delay=delay)
    I = np.eye(C.shape[1])[None]
    S = np.linalg.inv(I + C @ Pt)
    return Pt @ S, S
