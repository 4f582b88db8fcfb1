# SPDX-License-Identifier: Apache-2.0
"""The alias range: how far a lifted row's other responses exceed the one a bin's estimate needs.

One record of a white r excites all F aliases of every lifted bin k at once, so the
response to alias l (block column l of a lifted map G(k)) is told apart from the responses
to the other aliases only through the local model across the window of neighbouring bins.
Whatever the local model misses of the largest response in an output row (the local
polynomial's bias near a pole of the lifted loop: a relative error eps) the least-squares
fit spreads into that row's other entries, at about the same absolute size. The relative
error of column l is then about ``eps * rho`` with the alias range

    rho_l(k) = || (max_{|k' - k| <= n} max_j |G_ij(k')|)_i || / sigma_max(G(k)[:, block l]):

the 2-norm over the output rows of each row's largest entry in the window, over the gain
of column l. README, "The PFG from data", measures it: the PFG from data (G = J, the
lifted r -> y) and P_h from a low-rate y (G the lifted row ``[P_h(k + l M)]_l``) follow
``err ~ eps rho`` over seven decades of rho.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ...errors import DimensionError
from ..arrays import ComplexArray, FloatArray
from ..lifting import check_multiple, check_ratio, fold_half, half_to_full
from .loop import closed_loop_maps

if TYPE_CHECKING:
    from ..systems.model import Model


def alias_range(G: ArrayLike, ratio: int, halfwidth: int = 0) -> FloatArray:
    """The alias range of every block column of lifted maps G on consecutive bins.

    Parameters
    ----------
    G : array_like, shape (K + 2 halfwidth, n_out, F*n_in)
        Lifted maps at consecutive low-rate bins, block columns alias-major
        (``l*n_in + i``); n_out is F*n_y for the lifted J, n_y for the row of a low-rate
        output.
    ratio : int
        F.
    halfwidth : int
        n: the rows' largest entries are taken over the window ``k-n..k+n`` of each of
        the K centre bins (0: that bin alone).

    Returns
    -------
    ndarray, shape (K, F)
        rho (module docstring) of block column l at centre bin j (>= 1; inf where the
        column is zero or another entry infinite, NaN where the column is not finite).
    """
    F = check_ratio(ratio)
    Ga = np.asarray(G, dtype=complex)
    if Ga.ndim != 3 or Ga.shape[2] % F or Ga.shape[0] <= 2 * halfwidth:
        raise DimensionError(
            f"G must have shape (K + 2*halfwidth, n_out, F*n_in) with F={F}, "
            f"halfwidth={halfwidth}, K >= 1; got {np.shape(G)}"
        )
    n_out, n_in = Ga.shape[1], Ga.shape[2] // F
    big = np.abs(Ga).max(axis=2)  # (K + 2n, n_out)
    if halfwidth:
        big = np.lib.stride_tricks.sliding_window_view(big, 2 * halfwidth + 1, axis=0).max(-1)
    rows = np.linalg.norm(big, axis=1)  # (K,)
    centre = Ga[halfwidth : Ga.shape[0] - halfwidth]
    cols = centre.reshape(-1, n_out, F, n_in).transpose(0, 2, 1, 3)  # (K, l, n_out, n_in)
    finite = np.isfinite(cols).all(axis=(2, 3))
    gain = np.full(finite.shape, np.nan)
    gain[finite] = np.linalg.norm(cols[finite], ord=2, axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        out: FloatArray = rows[:, None] / gain
    return out


def _on_high_rate_bins(rho: FloatArray, ratio: int, n_samples: int) -> FloatArray:
    """(M//2+1, F) per low-rate bin and alias -> (N//2,) on the bins 1..N//2."""
    M = n_samples // ratio
    kappa = np.arange(M // 2 + 1)[:, None] + M * np.arange(ratio)[None, :]
    idx, _ = fold_half(kappa.ravel(), n_samples)
    out = np.full(n_samples // 2 + 1, np.nan)
    out[idx] = rho.ravel()
    return out[1:]


def pfg_alias_range(model: Model, n_samples: int, halfwidth: int = 0) -> FloatArray:
    """The alias range of a model's lifted r -> y on the bins (0, fs_high/2], (N//2,).

    The PFG from data (:mod:`mr_ident.numerics.lifted.pfg_data`) at a bin needs its local model
    good to ``tolerance / rho`` there; ``halfwidth`` is the window's n. NaN at the
    multiples of fs_low with an integrating controller (the model's lifted map is not
    finite there).
    """
    N, F = int(n_samples), model.ratio
    M = check_multiple(N, F, "n_samples")
    bins = np.arange(-halfwidth, M // 2 + 1 + halfwidth)
    J, _ = closed_loop_maps(  # bins below 0: the window's continuation, k + l M mod N
        half_to_full(model.plant_frf(N), N),
        model.controller_frf(M)[bins % M],
        bins,
        F,
        phase=model.sample_phase,
        delay=model.control_delay,
    )
    return _on_high_rate_bins(alias_range(J, F, halfwidth), F, N)


def row_alias_range(
    P_half: ArrayLike, ratio: int, n_samples: int, halfwidth: int = 0
) -> FloatArray:
    """The alias range of the lifted row of a low-rate output ``[P_h(k + l M)]_l``, (N//2,).

    Parameters
    ----------
    P_half : array_like, shape (N//2+1, n_y, n_u)
        The high-rate plant on bins 0..N//2.
    ratio, n_samples : int
    halfwidth : int
        The window's n (see :func:`alias_range`).

    Returns
    -------
    ndarray, shape (N//2,)
        On the bins 1..N//2; for SISO and n = 0 ``max_l |P_h(kappa_l)| / |P_h(kappa)|``
        (inf where another alias is a pole: DC of an integrating plant).
    """
    F, N = check_ratio(ratio), int(n_samples)
    M = check_multiple(N, F, "n_samples")
    P = np.asarray(P_half, dtype=complex)
    if P.ndim != 3 or P.shape[0] != N // 2 + 1:
        raise DimensionError(
            f"P_half must have shape (N//2+1={N // 2 + 1}, n_y, n_u), got {np.shape(P_half)}"
        )
    full: ComplexArray = half_to_full(P, N)
    k = np.arange(-halfwidth, M // 2 + 1 + halfwidth)
    kappa = k[:, None] + M * np.arange(F)[None, :]  # (K + 2n, F)
    row = full[kappa % N].transpose(0, 2, 1, 3).reshape(k.size, P.shape[1], -1)
    with np.errstate(invalid="ignore"):
        return _on_high_rate_bins(alias_range(row, F, halfwidth), F, N)
