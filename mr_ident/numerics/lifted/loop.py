# SPDX-License-Identifier: Apache-2.0
"""The multirate loop in the frequency-lifted domain.

Loop (DEVELOPERS.md): ``u_h = r_h - H_u K_l S_d y_h``, ``y_h = P_h u_h``.
``S_d`` samples ``y_h`` at the high-rate phase ``phase`` of every low-rate
period (``y_l[m] = y_h[mF + phase]``); ``H_u`` holds ``u_l[m]`` over the F
samples starting at ``mF + hold``, where ``hold = phase + delay`` (``delay`` is
a computation delay in high-rate samples, 0 by default).

For a record of N = M F samples and low-rate bin k, the frequency-lifted
controller is the rank-n_u matrix ``C = A K_l B^T``::

    C[(l,u), (l2,y)] = a_l(k) K_l(k)[u,y] b_l2(k),
    a_l = (1/F) exp(-2j pi kl hold/N) H0(kl),   b_l = exp(+2j pi kl phase/N)

with ``kl = k + l M`` and ``H0(kl) = sum_{i<F} exp(-2j pi i kl / N)``
(:func:`controller_factors`); then ``S = (I + C P)^-1`` (r -> u) and ``J = P S``
(r -> y), with ``P = diag(P_h(k + l M))``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray
from ..lifting import check_multiple, check_ratio, lift_frf


def check_timing(phase: int, delay: int, ratio: int) -> None:
    """Sampling phase in 0..F-1 and computation delay >= 0 (high-rate samples)."""
    if not 0 <= phase < ratio:
        raise ConfigError(f"phase must be in 0..{ratio - 1}, got {phase}")
    if delay < 0:
        raise ConfigError(f"delay must be >= 0 high-rate samples, got {delay}")


def controller_factors(
    kappa: ArrayLike, ratio: int, n_samples: int, *, phase: int = 0, delay: int = 0
) -> tuple[ComplexArray, ComplexArray | None]:
    """The factors ``a_l, b_l`` of the lifted controller ``C = A K B^T`` (module docstring).

    At the aliases ``kappa + l M`` of high-rate bins ``kappa``.

    Returns
    -------
    a, b : ndarray, shape (F, K)
        ``b`` is None when ``phase`` is 0 (all ones).
    """
    F, N = check_ratio(ratio), int(n_samples)
    k = np.asarray(kappa, dtype=float)
    l = np.arange(F)
    s = phase + delay
    # exp(-2j pi kl x / N) = exp(-2j pi kappa x / N) * exp(-2j pi l x / F): one exp per bin.
    z = np.exp(-2j * np.pi * l / F)[:, None] * np.exp(-2j * np.pi * k / N)[None, :]  # (F, K)
    a: ComplexArray = np.full_like(z, 1.0 / F)
    for _ in range(F - 1):  # Horner: (1 + z + ... + z^(F-1)) / F
        a = 1.0 / F + z * a
    if s:
        a *= np.exp(-2j * np.pi * l * s / F)[:, None] * np.exp(-2j * np.pi * k * s / N)[None, :]
    if not phase:
        return a, None
    b: ComplexArray = (
        np.exp(2j * np.pi * l * phase / F)[:, None] * np.exp(2j * np.pi * k * phase / N)[None, :]
    )
    return a, b


def lifted_controller(
    K_low: ArrayLike,
    bins: ArrayLike,
    ratio: int,
    n_samples: int,
    *,
    phase: int = 0,
    delay: int = 0,
) -> ComplexArray:
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
    F = check_ratio(ratio)
    check_multiple(n_samples, F, "n_samples")
    check_timing(phase, delay, F)
    Kl = np.asarray(K_low, dtype=complex)
    k = np.asarray(bins, dtype=np.int64)
    if Kl.ndim != 3 or Kl.shape[0] != k.size:
        raise DimensionError(
            f"K_low must have shape (len(bins)={k.size}, n_u, n_y), got {Kl.shape}"
        )
    a, b = controller_factors(k, F, n_samples, phase=phase, delay=delay)
    right = np.ones_like(a) if b is None else b
    nu, ny = Kl.shape[1:]
    with np.errstate(invalid="ignore"):  # an integrating K_l is inf at DC: nan there
        C = a.T[:, :, None, None, None] * Kl[:, None, :, None, :] * right.T[:, None, None, :, None]
    out: ComplexArray = C.reshape(k.size, F * nu, F * ny)
    return out


def closed_loop_maps(
    P_full: ArrayLike,
    K_low: ArrayLike,
    bins: ArrayLike,
    ratio: int,
    *,
    phase: int = 0,
    delay: int = 0,
) -> tuple[ComplexArray, ComplexArray]:
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
    F = check_ratio(ratio)
    N = np.shape(P_full)[0]
    Pt = lift_frf(P_full, F, bins=bins)
    C = lifted_controller(K_low, bins, F, N, phase=phase, delay=delay)
    eye = np.eye(C.shape[1])[None]
    with np.errstate(invalid="ignore"):  # nan at DC with an integrating K_l (see above)
        S: ComplexArray = np.asarray(np.linalg.inv(eye + C @ Pt), dtype=np.complex128)
    J: ComplexArray = Pt @ S
    return J, S
