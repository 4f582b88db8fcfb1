"""Performance Frequency Gain (PFG) of a multirate loop r_h -> y_h.

Following Oomen et al. (2007), as used by van Haren et al. (2022): an input
at frequency ``w`` produces outputs at the F frequencies ``w + 2 pi l / F``;
the PFG is the 2-norm of that response, i.e. of the first block column of the
frequency-lifted closed-loop map ``J(w)`` (its largest singular value for
MIMO). For a high-rate bin ``kappa = k + l M`` this is block column ``l`` of
``J(k)`` (the lifted map is periodic in k up to a permutation of the aliases).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DimensionError
from .lifting import _check_multiple, _check_ratio
from .loop import closed_loop_maps, lifted_controller
from .results import PFG


def _column_gain(col: NDArray[np.complex128]) -> tuple[NDArray, NDArray, NDArray]:
    """Largest singular value of block columns (..., m, c) and its singular vectors."""
    if col.shape[-1] == 1:
        g = np.linalg.norm(col[..., 0], axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            u = col[..., 0] / g[..., None]
        v = np.ones(col.shape[:-2] + (1,), dtype=complex)
        return g, u, v
    U, s, Vh = np.linalg.svd(col, full_matrices=False)
    return s[..., 0], U[..., :, 0], np.conj(Vh[..., 0, :])


def half_to_full(X_half: NDArray, n_samples: int) -> NDArray:
    """Extend values on bins 0..N//2 to all N bins by conjugate symmetry."""
    k = np.arange(n_samples)
    idx = np.minimum(k, n_samples - k)
    out = X_half[idx]
    mirror = k > n_samples // 2
    if np.iscomplexobj(out):
        out[mirror] = np.conj(out[mirror])
    return out


def pfg_from_plant(P_half: ArrayLike, K_low: ArrayLike, ratio: int, n_samples: int, *,
                   P_std_half: ArrayLike | None = None, phase: int = 0, delay: int = 0
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """PFG on the high-rate bins 0..N//2 from a plant FRF and the controller.

    Parameters
    ----------
    P_half : array_like, shape (N//2 + 1, n_y, n_u)
        Plant on DFT bins 0..N//2 (DC included; the aliases need it).
    K_low : array_like, shape (M, n_u, n_y)
        Controller on all low-rate bins 0..M-1, M = N / F.
    ratio, n_samples : int
    P_std_half : array_like, shape like P_half, optional
        Standard deviation of the plant estimate (independent bins assumed);
        gives a first-order std of the PFG.
    phase, delay : int
        See :mod:`mr_ident.loop`.

    Returns
    -------
    gain, std : ndarray, shape (N//2 + 1,)
        std is NaN when ``P_std_half`` is None.
    """
    F = _check_ratio(ratio)
    N = int(n_samples)
    M = _check_multiple(N, F, "n_samples")
    Ph = np.asarray(P_half, dtype=complex)
    if Ph.ndim != 3 or Ph.shape[0] != N // 2 + 1:
        raise DimensionError(f"P_half must have shape (N//2+1={N // 2 + 1}, n_y, n_u), got {Ph.shape}")
    Kl = np.asarray(K_low, dtype=complex)
    if Kl.shape[0] != M:
        raise DimensionError(f"K_low must cover all M={M} low-rate bins, got {Kl.shape[0]}")
    ny, nu = Ph.shape[1:]
    P_full = half_to_full(Ph, N)
    kappa = np.arange(N // 2 + 1)
    k = kappa % M
    l = kappa // M
    ks = np.unique(k)
    J, S = closed_loop_maps(P_full, Kl[ks], ks, F, phase=phase, delay=delay)
    pos = np.searchsorted(ks, k)
    Jb = J.reshape(ks.size, F * ny, F, nu)
    col = Jb[pos, :, l, :]                                  # (kappa, F*ny, nu)
    gain, uvec, vvec = _column_gain(col)
    std = np.full(gain.shape, np.nan)
    if P_std_half is not None:
        sd_full = half_to_full(np.asarray(P_std_half, dtype=float), N)
        # dJ = S_o dP S with S_o = I - J C; the gain moves by Re(u^H dJ[:, col] v).
        C = lifted_controller(Kl[ks], ks, F, N, phase=phase, delay=delay)
        So = np.eye(F * ny)[None] - J @ C                   # (ks, F ny, F ny)
        a = np.einsum("kr,krs->ks", np.conj(uvec), So[pos])  # u^H S_o, (kappa, F ny)
        Sb = S.reshape(ks.size, F * nu, F, nu)[pos, :, l, :]  # S[:, col block], (kappa, F nu, nu)
        b = np.einsum("ksu,ku->ks", Sb, vvec)                 # (kappa, F nu)
        var = np.zeros(gain.shape)
        for ll in range(F):
            sd = sd_full[(k + ll * M) % N]                     # (kappa, ny, nu)
            coef = a[:, ll * ny:(ll + 1) * ny, None] * b[:, None, ll * nu:(ll + 1) * nu]
            var += 0.5 * np.sum(np.abs(coef) ** 2 * sd ** 2, axis=(1, 2))
        std = np.sqrt(var)
    return gain, std


def pfg_from_lifted(J: ArrayLike, bins: ArrayLike, ratio: int, n_samples: int, *,
                    row_cov: ArrayLike | None = None, col_cov: ArrayLike | None = None
                    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """PFG directly from an identified frequency-lifted closed-loop map ``J``.

    Parameters
    ----------
    J : array_like, shape (K, F*n_y, F*n_r)
        At low-rate bins ``bins`` (for a real loop, 0..M//2 suffice).
    bins : array_like of int, shape (K,)
    row_cov, col_cov : array_like, optional
        Kronecker covariance factors of J (see :class:`~mr_ident.results.LiftedFRF`).

    Returns
    -------
    kappa : ndarray of int, shape (K*F,)
        High-rate bins ``bins + l M`` folded into 0..N//2.
    gain, std : ndarray, shape (K*F,)
    """
    F = _check_ratio(ratio)
    N = int(n_samples)
    M = _check_multiple(N, F, "n_samples")
    Ja = np.asarray(J, dtype=complex)
    k = np.asarray(bins, dtype=np.int64)
    K, fy, fr = Ja.shape
    ny, nr = fy // F, fr // F
    cols = Ja.reshape(K, fy, F, nr).transpose(0, 2, 1, 3)       # (K, l, F ny, nr)
    gain, uvec, vvec = _column_gain(cols)
    std = np.full(gain.shape, np.nan)
    if row_cov is not None and col_cov is not None:
        Rc = np.asarray(row_cov)
        Cc = np.asarray(col_cov).reshape(K, F, nr, F, nr)
        Cd = Cc[:, np.arange(F), :, np.arange(F), :].transpose(1, 0, 2, 3)   # (K, l, nr, nr)
        qr = np.real(np.einsum("klr,krs,kls->kl", np.conj(uvec), Rc, uvec))
        qc = np.real(np.einsum("klu,kluv,klv->kl", vvec, Cd, np.conj(vvec)))
        std = np.sqrt(np.maximum(0.5 * qr * qc, 0.0))
    kappa = k[:, None] + M * np.arange(F)[None, :]
    kappa = np.where(kappa > N // 2, N - kappa, kappa)
    return kappa.ravel(), gain.ravel(), std.ravel()


def pfg_result(frequency: ArrayLike, gain: ArrayLike, std: ArrayLike, source: str) -> PFG:
    return PFG(np.asarray(frequency, float), np.asarray(gain, float), np.asarray(std, float), source)
