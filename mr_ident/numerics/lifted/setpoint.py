# SPDX-License-Identifier: Apache-2.0
"""A loop excited at its setpoint: the sampled setpoint, the hold's zeros.

The loop as a ros2_control stack runs it: the controller samples the setpoint r with y,
``u_h = H_u K_l S_d (r_h - y_h)``, ``y_h = P_h u_h + v_h``. Only the samples of r that the
controller takes act, ``r_l[m] = r_h[m F + q]`` (q the sampling phase); write ``r_↑`` for
them upsampled to the high rate (zeros between). With ``T_l = (I + K_l S_d P_h H_u)^{-1}
K_l`` the low-rate loop from the setpoint to the controller's output,

    U_h(ω) = H(ω) T_l(e^{jωF}) R_↑(ω) + noise,    Y_h(ω) = P_h(ω) U_h(ω) + noise,

with ``R_↑(ω) = R_l(e^{jωF})`` (the DFT of ``r_↑`` is that of ``r_l``, repeated F times
over the high-rate band) and ``H(ω) = Σ_{i<F} e^{-jω(i + q + d)}`` the hold (d the control
delay). So ``r_↑ -> [y_h; u_h]`` is LTI at the high rate, ``G_u = H T_l``, ``G_y = P_h G_u``,
and the indirect step ``P_h = G_y G_u^{-1}`` holds on every high-rate bin where ``G_u`` is
invertible: no lifting is needed, and the plain high-rate local fit (the ``lpm`` engine) on
``r_↑`` is the estimator. In the lifted form it is ``P̃ 1_F = J̃ S̃^{-1}`` with one-column J̃
and S̃: the frequency-lifted fit with one lifted input has, row by row, the same windows.

Noise: v_h reaches u_h through the sampler, aliased, ``-H(ω) T_l(e^{jωF}) Σ_l V_h(ω + 2πl/F)
/ F``: u's noise at a bin is correlated with y's at that bin (the local fit estimates the
2 x 2 covariance per window) and with the noise at the bin's F - 1 aliases, which lie
outside every window narrower than N/F bins: the fit's covariance is that of the LTI local
model, and P_h's std is the indirect step's. The estimates at a bin and its aliases are
correlated through that noise (the PFG from P_h treats them as independent).

The hold's zeros: ``H(2π j/F) = 0`` for j = 1..F-1 (multiples of ``f_l = fs_high/F``);
there ``G_u = G_y = 0`` and P_h is not determined. Near them ``|H|`` grows linearly, P_h's
std as its inverse; the local polynomial's bias relative to ``G_u`` grows alike.
:func:`hold_zone` flags the bins whose window reaches a zero.
"""

from __future__ import annotations

import numpy as np

from ...errors import ConfigError, DimensionError
from ..arrays import BoolArray, FloatArray, IntArray
from ..lifting import check_sample_of_period
from ..structure import hold_of

#: The methods a setpoint-excited loop takes (one estimator there: the high-rate local fit).
SETPOINT_METHODS = ("freq-lifted", "lpm")


def check_setpoint_shapes(r: FloatArray, u: FloatArray, y: FloatArray, ratio: int) -> None:
    """A setpoint's record: r at N or N/F samples, y at N, as many setpoints as y and u.

    DimensionError naming the lengths or channels otherwise (the indirect step inverts
    r -> u: a square loop).
    """
    N = u.shape[0]
    if r.shape[0] not in (N, N // ratio) or N % ratio:
        raise DimensionError(
            f"the setpoint r must have N = {N} samples (as u) or N/F, got {r.shape[0]}"
        )
    if y.shape[0] != N:
        raise DimensionError(
            f"a setpoint-excited loop needs y at the high rate (N = {N} samples), got {y.shape[0]}"
        )
    if not r.shape[1] == y.shape[1] == u.shape[1]:
        raise DimensionError(
            "a setpoint-excited loop needs as many setpoints, outputs and inputs (the "
            f"indirect step inverts r -> u), got r {r.shape[1]}, y {y.shape[1]}, u "
            f"{u.shape[1]} channel(s)"
        )


def setpoint_regressor(
    r: FloatArray, ratio: int, phase: object, method: str, n_samples: int
) -> FloatArray:
    """The regressor of a setpoint's fit, ``r_↑`` (:func:`sampled_setpoint`), its options checked.

    ConfigError for a ``method`` other than :data:`SETPOINT_METHODS` or a ``phase`` outside
    0..F-1.
    """
    if method not in SETPOINT_METHODS:
        raise ConfigError(
            "a setpoint-excited loop is identified by the high-rate local fit of the sampled "
            f"setpoint (method {' or '.join(SETPOINT_METHODS)}: one estimator there), got "
            f"method {method!r}"
        )
    q = check_sample_of_period("phase", phase, ratio)
    return sampled_setpoint(r, ratio, q, n_samples)


def held_over_blocks(r: FloatArray, ratio: int, method: str) -> bool:
    """Whether r at the plant input is held over blocks of F: the setpoint's estimator then.

    A held r is ``r = H r_l↑`` (H the hold), so the loop from ``r_l↑`` is LTI at the high
    rate as a setpoint's is, and ``Y/R = G_y/H`` on every bin but the hold's zeros: the
    high-rate local fit on r itself is the estimator. The lifted regressor has rank one per
    block (no lifted method can fit it). ConfigError for a ``method`` other than
    :data:`SETPOINT_METHODS`.
    """
    hold = hold_of(r) if ratio > 1 and r.shape[0] > ratio else None
    if hold is None or hold[0] % ratio:
        return False
    if method not in SETPOINT_METHODS:
        raise ConfigError(
            f"r is held over blocks of {hold[0]} samples: its lifted regressor has rank one "
            "per block, so the loop is identified by the high-rate local fit on r (method "
            f"{' or '.join(SETPOINT_METHODS)}), got method {method!r}"
        )
    return True


def sampled_setpoint(r: FloatArray, ratio: int, phase: int, n_samples: int) -> FloatArray:
    """``r_↑``: the setpoint's samples the controller takes, zeros between, shape (N, n_r).

    ``r`` (N, n_r) at the high rate (sample ``m F + phase`` is taken) or (N/F, n_r) at the
    controller's rate (sample m is taken at ``m F + phase``).
    """
    F, N = int(ratio), int(n_samples)
    out = np.zeros((N, r.shape[1]))
    if r.shape[0] == N:
        out[phase::F] = r[phase::F]
    elif r.shape[0] * F == N:
        out[phase::F] = r
    else:
        raise DimensionError(
            f"the setpoint r has {r.shape[0]} samples: neither N = {N} (the high rate) nor "
            f"N/F = {N // F} (the controller's rate)"
        )
    return out


def hold_zero_bins(n_samples: int, ratio: int) -> IntArray:
    """The bins of 1..N//2 at the hold's zeros: multiples of M = N/F (``f_l`` and up)."""
    M = n_samples // ratio
    return np.arange(M, n_samples // 2 + 1, M, dtype=np.int64)


def hold_zone(n_samples: int, ratio: int, n_used: IntArray) -> BoolArray:
    """Bins 1..N//2 whose local window reaches a hold's zero, shape (N//2,).

    ``n_used`` (N//2,): each bin's window half-width. A bin k is flagged when a zero z has
    ``|k - z| <= n_used[k]`` (its window holds the zero; the bin itself when n_used is 0).
    """
    k = np.arange(1, n_samples // 2 + 1)
    zeros = hold_zero_bins(n_samples, ratio)
    if zeros.size == 0:
        return np.zeros(k.shape, dtype=bool)
    M = n_samples // ratio
    nearest = np.rint(k / M).astype(np.int64) * M
    dist = np.abs(k - nearest)
    flagged: BoolArray = (nearest > 0) & (dist <= np.asarray(n_used))
    return flagged
