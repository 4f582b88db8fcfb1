# SPDX-License-Identifier: Apache-2.0
"""Performance Frequency Gain (PFG) of a multirate loop r_h -> y_h.

Following Oomen et al. (2007), as used by van Haren et al. (2022): an input
at frequency ``w`` produces outputs at the F frequencies ``w + 2 pi l / F``;
the PFG is the 2-norm of that response, i.e. of the first block column of the
frequency-lifted closed-loop map ``J(w)`` (its largest singular value for
MIMO). For a high-rate bin ``kappa = k + l M`` this is block column ``l`` of
``J(k)`` (the lifted map is periodic in k up to a permutation of the aliases).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ...errors import DimensionError
from ..arrays import AnyArray, ComplexArray, FloatArray
from ..lifting import check_multiple, check_ratio, fold_half
from ..results import PFG
from ..threads import resolve_workers, thread_map
from .loop import controller_factors

if TYPE_CHECKING:
    from ..local.lrm import DenominatorTerm
    from ..systems.model import Model


def _column_gain(col: ComplexArray) -> tuple[AnyArray, AnyArray, AnyArray]:
    """Largest singular value of block columns (..., m, c) and its singular vectors."""
    if col.shape[-1] == 1:
        g = np.linalg.norm(col[..., 0], axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            u = col[..., 0] / g[..., None]
        v = np.ones(col.shape[:-2] + (1,), dtype=complex)
        return g, u, v
    U, s, Vh = np.linalg.svd(col, full_matrices=False)
    return s[..., 0], U[..., :, 0], np.conj(Vh[..., 0, :])


def pfg_from_plant(
    P_half: ArrayLike,
    K_low: ArrayLike,
    ratio: int,
    n_samples: int,
    *,
    P_std_half: ArrayLike | None = None,
    phase: int = 0,
    delay: int = 0,
    fs_high: float = 1.0,
    workers: int | None = None,
) -> PFG:
    """PFG on the high-rate bins 0..N//2 from a plant FRF and the controller.

    The lifted controller has rank n_u (``C = A K B^T``), so by the Woodbury identity
    the first block column of ``J = P (I + C P)^-1`` at input bin kappa is::

        col_l = delta_l0 P_0 - a_l P_l K (I + Z)^-1 b_0 P_0,   Z = sum_l a_l b_l P_l K

    with ``P_l = P_h(kappa + l M)``: an n_y x n_y inverse per bin, O(F) work.

    Parameters
    ----------
    P_half : array_like, shape (N//2 + 1, n_y, n_u)
        Plant on DFT bins 0..N//2 (DC included; the aliases need it).
    K_low : array_like, shape (M, n_u, n_y)
        Controller on all low-rate bins 0..M-1, M = N / F.
    ratio, n_samples : int
        F and N (a multiple of F).
    P_std_half : array_like, shape like P_half, optional
        Standard deviation of the plant estimate (independent bins assumed);
        gives a first-order std of the PFG.
    phase, delay : int
        See :mod:`mr_ident.numerics.lifted.loop`.
    fs_high : float, default 1.0
        High sample rate, for the frequencies ``k fs_high / N`` of the result (the
        default gives cycles per sample).
    workers : int, optional
        Threads over blocks of bins (default: every CPU available to the process).

    Returns
    -------
    PFG
        On the N//2 + 1 bins 0..N//2; its std is NaN when ``P_std_half`` is None.

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1, or ``workers`` not None or a positive
        integer.
    DimensionError
        If N is not a multiple of F, ``P_half`` is not (N//2 + 1, n_y, n_u), or
        ``K_low`` does not cover the M low-rate bins.

    References
    ----------
    .. [1] T. Oomen, M. van de Wal, O. Bosgra, "Design framework for high-performance
       optimal sampled-data control with application to a wafer stage", IJC 80(6), 2007.
    .. [2] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.

    Examples
    --------
    Open-loop plant 1 under a zero controller: the input's own frequency gets gain 1,
    its aliases nothing, so the PFG is 1 everywhere.

    >>> import numpy as np
    >>> from mr_ident import pfg_from_plant
    >>> N, F = 12, 3
    >>> P, K = np.ones((N // 2 + 1, 1, 1)), np.zeros((N // F, 1, 1))
    >>> pfg = pfg_from_plant(P, K, F, N, fs_high=120.0)
    >>> pfg.frequency[:3], pfg.gain[:3]
    (array([ 0., 10., 20.]), array([1., 1., 1.]))
    """
    F = check_ratio(ratio)
    N = int(n_samples)
    M = check_multiple(N, F, "n_samples")
    Ph = np.asarray(P_half, dtype=complex)
    if Ph.ndim != 3 or Ph.shape[0] != N // 2 + 1:
        raise DimensionError(
            f"P_half must have shape (N//2+1={N // 2 + 1}, n_y, n_u), got {Ph.shape}"
        )
    Kl = np.asarray(K_low, dtype=complex)
    if Kl.shape[0] != M:
        raise DimensionError(f"K_low must cover all M={M} low-rate bins, got {Kl.shape[0]}")
    sd_half = None if P_std_half is None else np.asarray(P_std_half, dtype=float)
    gain = np.empty(N // 2 + 1)
    std = np.empty(N // 2 + 1)

    def block(k0: int) -> None:  # blocks bound the memory and run on threads
        kappa = np.arange(k0, min(k0 + PFG_BLOCK, N // 2 + 1))
        gain[kappa[0] : kappa[-1] + 1], std[kappa[0] : kappa[-1] + 1] = _pfg_block(
            kappa, Ph, sd_half, Kl, F, N, phase=phase, delay=delay
        )

    thread_map(block, range(0, N // 2 + 1, PFG_BLOCK), resolve_workers(workers))
    return PFG(np.arange(N // 2 + 1, dtype=np.float64) * (fs_high / N), gain, std, "plant")


#: High-rate bins per block in :func:`pfg_from_plant`.
PFG_BLOCK = 16384


def _aliases(X_half: AnyArray, kappa: AnyArray, F: int, N: int, axis: int = 1) -> AnyArray:
    """``X[kappa + l M]`` (bins mod N) of a real signal's spectrum given on bins 0..N//2.

    Read through ``X(N - k) = conj X(k)`` (no whole spectrum is formed); L on ``axis``
    (shape (K, F, ...) by default).
    """
    M = N // F
    bins = (kappa[None, :] + M * np.arange(F)[:, None]) % N  # (F, K)
    # Gathered straight into the layout asked for (C order): a moved-axis view would change
    # the order of the sums over it (the std's last bits).
    src, upper = fold_half(np.moveaxis(bins, 0, axis), N)
    out = np.take(X_half, src, axis=0)
    if np.iscomplexobj(out):
        mask = upper.reshape(upper.shape + (1,) * (out.ndim - 2))
        np.conjugate(out, out=out, where=np.broadcast_to(mask, out.shape))
    return out


def _pfg_block(
    kappa: AnyArray,
    P_half: AnyArray,
    sd_half: AnyArray | None,
    Kl: AnyArray,
    F: int,
    N: int,
    *,
    phase: int,
    delay: int,
) -> tuple[FloatArray, FloatArray]:
    """PFG and its std on consecutive high-rate bins kappa, from the plant on bins 0..N//2."""
    ny, nu = P_half.shape[1:]
    Kk = np.take(Kl, kappa, axis=0, mode="wrap")  # (K, nu, ny)
    a, b = controller_factors(kappa, F, N, phase=phase, delay=delay)
    if ny == nu == 1:
        sd = None if sd_half is None else _aliases(sd_half[:, 0, 0], kappa, F, N, axis=0)
        return _pfg_siso(_aliases(P_half[:, 0, 0], kappa, F, N, axis=0), Kk[:, 0, 0], a, b, sd)
    Pl = _aliases(P_half, kappa, F, N)  # (K, F, ny, nu)
    a = a.T
    b = np.ones_like(a) if b is None else b.T
    PK = Pl @ Kk[:, None]  # (K, F, ny, ny)
    Z = np.einsum("kl,klij->kij", a * b, PK)
    Minv = np.linalg.inv(np.eye(ny)[None] + Z)  # (K, ny, ny)
    MbP0 = (Minv @ Pl[:, 0]) * b[:, 0, None, None]  # (K, ny, nu)
    col = -(a[:, :, None, None] * (PK @ MbP0[:, None]))  # (K, F, ny, nu)
    col[:, 0] += Pl[:, 0]
    gain, uvec, vvec = _column_gain(col.reshape(kappa.size, F * ny, nu))
    std = np.full(gain.shape, np.nan)
    if sd_half is not None:
        sd = _aliases(sd_half, kappa, F, N)  # (K, F, ny, nu)
        ul = uvec.reshape(kappa.size, F, ny)
        # u^H S_o, S_o = (I + P C)^-1 = I - P A K (I+Z)^-1 B^T: block l is
        # conj(u_l) - (sum_m conj(u_m) a_m P_m K) (I+Z)^-1 b_l.
        w = (np.einsum("kmi,km,kmij->kj", np.conj(ul), a, PK)[:, None, :] @ Minv)[:, 0]
        acoef = np.conj(ul) - w[:, None, :] * b[:, :, None]  # (K, F, ny)
        # S[:, col 0] v, block l: delta_l0 v - a_l K (I+Z)^-1 b_0 P_0 v.
        KMbP0v = np.einsum("kuy,kyv,kv->ku", Kk, MbP0, vvec)  # (K, nu)
        bcoef = -a[:, :, None] * KMbP0v[:, None, :]  # (K, F, nu)
        bcoef[:, 0] += vvec
        coef2 = np.abs(acoef)[:, :, :, None] ** 2 * np.abs(bcoef)[:, :, None, :] ** 2
        std = np.sqrt(0.5 * np.sum(coef2 * sd**2, axis=(1, 2, 3)))
    return gain, std


def _pfg_siso(
    Pl: AnyArray, Kk: AnyArray, a: AnyArray, b: AnyArray | None, sd: AnyArray | None
) -> tuple[FloatArray, FloatArray]:
    """Scalar form of :func:`pfg_from_plant` (n_y = n_u = 1): elementwise, no stacked matmuls.

    Pl, a, b, sd have shape (F, K) (aliases first, so sums over them are vector adds;
    ``b`` None means all ones), Kk (K,).
    """
    with np.errstate(invalid="ignore", divide="ignore"):  # an integrator's P(0) = inf: nan
        aPK = a * (Pl * Kk)  # a_l P_l K
        minv = 1.0 / (1.0 + np.sum(aPK if b is None else aPK * b, axis=0))
        mbp0 = minv * Pl[0] if b is None else minv * b[0] * Pl[0]
        col = aPK * -mbp0
        col[0] += Pl[0]
        gain = np.sqrt(np.sum(col.real**2 + col.imag**2, axis=0))
    if sd is None:
        return gain, np.full(gain.shape, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = col / gain
    w = np.sum(np.conj(u) * aPK, axis=0) * minv
    acoef = np.conj(u) - (w if b is None else w * b)
    bcoef = a * -(Kk * mbp0)
    bcoef[0] += 1.0
    ab = acoef * bcoef * sd
    var = 0.5 * np.sum(ab.real**2 + ab.imag**2, axis=0)
    return gain, np.sqrt(var)


def pfg_of_model(model: Model, n_samples: int) -> PFG:
    """Exact PFG of a model's loop on the bins (0, fs_high/2] of an N-sample record (std 0)."""
    N = int(n_samples)
    g = pfg_from_plant(
        model.plant_frf(N),
        model.controller_frf(N // model.ratio),
        model.ratio,
        N,
        phase=model.sample_phase,
        delay=model.control_delay,
        fs_high=model.fs_high,
    )
    return PFG(g.frequency[1:], g.gain[1:], np.zeros(N // 2), "model")


def pfg_from_lifted(
    J: ArrayLike,
    bins: ArrayLike,
    ratio: int,
    n_samples: int,
    *,
    row_cov: ArrayLike | None = None,
    col_cov: ArrayLike | None = None,
    fs_high: float = 1.0,
) -> PFG:
    """PFG directly from an identified frequency-lifted closed-loop map ``J``.

    Parameters
    ----------
    J : array_like, shape (K, F*n_y, F*n_r)
        At low-rate bins ``bins`` (for a real loop, 0..M//2 suffice).
    bins : array_like of int, shape (K,)
        The low-rate bins k of ``J``.
    ratio, n_samples : int
        F and N (a multiple of F).
    row_cov, col_cov : array_like, optional
        Kronecker covariance factors of J (see :class:`~mr_ident.numerics.results.LiftedFRF`).
    fs_high : float, default 1.0
        For the frequencies of the result (the default gives cycles per sample).

    Returns
    -------
    PFG
        At the high-rate bins ``bins + l M`` folded into 0..N//2 (K*F of them), in
        increasing order: ``frequency * N / fs_high`` are the bins. Its std is the first
        order one of the Kronecker covariance (NaN without ``row_cov`` and ``col_cov``).

    Raises
    ------
    ConfigError
        If ``ratio`` is not an integer >= 1.
    DimensionError
        If N is not a multiple of F.

    References
    ----------
    .. [1] T. Oomen, M. van de Wal, O. Bosgra, "Design framework for high-performance
       optimal sampled-data control with application to a wafer stage", IJC 80(6), 2007.
    .. [2] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.
    .. [3] E. van Haren, L. Blanken, T. Oomen, "Performance analysis of multirate
       systems: a direct frequency-domain identification approach", MSSP 235, 2025.

    Examples
    --------
    The frequency-lifted map of a unit gain at F = 2 (the identity): each input frequency
    reaches only itself, so the PFG is 1 at every high-rate bin.

    >>> import numpy as np
    >>> from mr_ident import pfg_from_lifted
    >>> J = np.broadcast_to(np.eye(2), (3, 2, 2))  # low-rate bins 0..2 of M = 4, N = 8
    >>> pfg = pfg_from_lifted(J, np.arange(3), 2, 8)
    >>> pfg.frequency * 8, pfg.gain
    (array([0., 1., 2., 2., 3., 4.]), array([1., 1., 1., 1., 1., 1.]))
    """
    F = check_ratio(ratio)
    N = int(n_samples)
    M = check_multiple(N, F, "n_samples")
    k = np.asarray(bins, dtype=np.int64)
    gain, std = lifted_gains(J, F, row_cov=row_cov, col_cov=col_cov)
    kappa = (k[:, None] + M * np.arange(F)[None, :]).ravel()
    kappa = np.where(kappa > N // 2, N - kappa, kappa)
    order = np.argsort(kappa, kind="stable")
    return PFG(kappa[order] * (fs_high / N), gain.ravel()[order], std.ravel()[order], "lifted J")


def lifted_gains(
    J: ArrayLike,
    ratio: int,
    *,
    row_cov: ArrayLike | None = None,
    col_cov: ArrayLike | None = None,
    den: DenominatorTerm | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The PFG of every block column of a frequency-lifted closed-loop map, with its std.

    Block column l of ``J(k)`` is the response at the F aliases to an input at high-rate
    bin ``k + l M``; its 2-norm (largest singular value for MIMO) is the PFG there. The
    first-order std: ``dg = Re(u^H dJ_l v)`` with u, v the singular vectors, so
    ``E dg^2 = (u^H R u)(v^T C_ll conj(v)) / 2`` for the Kronecker covariance
    ``R (x) C`` of the LPM (circular errors).

    Parameters
    ----------
    J : array_like, shape (K, F*n_y, F*n_r)
    ratio : int
    row_cov : array_like, shape (K, F*n_y, F*n_y), optional
    col_cov : array_like, shape (K, F*n_r, F*n_r), optional
        Kronecker covariance factors of J (:class:`~mr_ident.numerics.results.LiftedFRF`).
    den : DenominatorTerm, optional
        A local rational fit's denominator share of the covariance, bins last (gain
        (F*n_y, F*n_r, R_d, K)): adds ``E dg^2 = h S_d h^H / 2`` with
        ``h_t = u^H C0_t[:, block l] v`` (:mod:`mr_ident.numerics.local.lrm`).

    Returns
    -------
    gain, std : ndarray, shape (K, F)
        Entry ``[j, l]`` at high-rate bin ``k_j + l M``; std NaN without the covariance.
    """
    F = check_ratio(ratio)
    Ja = np.asarray(J, dtype=complex)
    K, fy, fr = Ja.shape
    nr = fr // F
    cols = Ja.reshape(K, fy, F, nr).transpose(0, 2, 1, 3)  # (K, l, F ny, nr)
    gain, uvec, vvec = _column_gain(cols)
    std = np.full(gain.shape, np.nan)
    if row_cov is not None and col_cov is not None:
        Rc = np.asarray(row_cov)
        Cc = np.asarray(col_cov).reshape(K, F, nr, F, nr)
        Cd = Cc[:, np.arange(F), :, np.arange(F), :].transpose(1, 0, 2, 3)  # (K, l, nr, nr)
        qr = np.real(np.einsum("klr,krs,kls->kl", np.conj(uvec), Rc, uvec))
        qc = np.real(np.einsum("klu,kluv,klv->kl", vvec, Cd, np.conj(vvec)))
        var = 0.5 * qr * qc
        if den is not None:
            C0 = den.gain.reshape(fy, F, nr, *den.gain.shape[2:])  # (F ny, l, nr, R_d, K)
            h = np.einsum("klr,rlstk,kls->klt", np.conj(uvec), C0, vvec)
            var = var + 0.5 * np.einsum("klt,tsk,kls->kl", h, den.cov, np.conj(h)).real
        std = np.sqrt(np.maximum(var, 0.0))
    return gain, std
