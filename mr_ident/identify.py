"""Identification of the high-rate plant of a multirate loop from r_h, u_h, y_h.

Methods (all return an :class:`~mr_ident.results.FRF` on (0, fs_high/2]):

``freq-lifted`` (default)
    Frequency-lift R, U, Y (stack the F aliases), LPM on r -> [y; u] giving the
    lifted J and S, indirect step ``P = J S^-1``, P_h from the diagonal blocks.
``time-lifted``
    Time-lift r, u, y (stack F samples), LPM on their M-point DFTs, indirect step,
    P_h from the first block column (polyphase components).
``lpm``
    LTI LPM on the high-rate spectra r -> [y; u], indirect step. Blind to the
    periodic time variation: the aliases act as noise.
``etfe``
    ``Y / U`` per bin, no window, no noise model (std NaN). SISO only.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from .errors import ConfigError, DataError, DimensionError
from . import _batched
from ._parallel import resolve_workers, thread_map
from .lifting import _check_ratio
from .lpm import _lpm_core, _warn_bad, check_lpm_options
from .pfg import pfg_from_plant
from .results import FRF, PFG, Identification, LiftedFRF

Method = Literal["freq-lifted", "time-lifted", "lpm", "etfe"]
METHODS: tuple[str, ...] = ("freq-lifted", "time-lifted", "lpm", "etfe")


def _check_signals(r: ArrayLike, u: ArrayLike, y: ArrayLike, ratio: int
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    arrays = []
    for name, x in (("r", r), ("u", u), ("y", y)):
        a = np.asarray(x, dtype=float)
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2:
            raise DimensionError(f"{name} must have shape (n_samples,) or (n_samples, n_channels), got {a.shape}")
        if not np.all(np.isfinite(a)):
            bad = np.argwhere(~np.isfinite(a))[0]
            raise DataError(f"{name} contains NaN or inf (first at sample {bad[0]}, channel {bad[1]})")
        arrays.append(a)
    ra, ua, ya = arrays
    if not ra.shape[0] == ua.shape[0] == ya.shape[0]:
        raise DimensionError(f"r, u, y must have equal lengths, got {ra.shape[0]}, {ua.shape[0]}, {ya.shape[0]}")
    if ra.shape[1] != ua.shape[1]:
        raise DimensionError(
            f"r and u must have the same number of channels (r excites u), got {ra.shape[1]} and {ua.shape[1]}")
    if ra.shape[0] % ratio:
        raise DimensionError(
            f"the record has {ra.shape[0]} samples, not a multiple of ratio F={ratio}; "
            f"trim it to {ra.shape[0] - ra.shape[0] % ratio} samples")
    return ra, ua, ya


def _half_spectra(*signals: NDArray[np.float64], workers: int = 1) -> list[list[NDArray[np.complex128]]]:
    """DFTs of real (N, c_i) signals on bins 0..N//2: per signal, one (N//2+1,) array per column.

    One real transform per column, the columns on ``workers`` threads (scipy's own
    ``workers`` does not split a few long columns). The upper half is never formed:
    :func:`_bins` reads any bin through conjugate symmetry.
    """
    columns = [x[:, i] for x in signals for i in range(x.shape[1])]
    half = thread_map(lambda c: scipy.fft.rfft(c, norm="ortho"), columns, workers)
    ends = np.cumsum([x.shape[1] for x in signals])
    return [half[e - x.shape[1]:e] for x, e in zip(signals, ends)]


def _bins(columns: list[NDArray[np.complex128]], idx: NDArray[np.intp], n_samples: int) -> NDArray[np.complex128]:
    """``X[idx]`` (shape ``idx.shape + (c,)``) of the full N-bin DFT of each column, from
    its bins 0..N//2 (``X(N-k) = conj X(k)`` for a real signal); ``idx`` in 0..N-1."""
    upper = idx > n_samples // 2
    src = np.where(upper, n_samples - idx, idx)
    out = np.stack([c[src] for c in columns], axis=-1)
    np.conjugate(out, out=out, where=upper[..., None])
    return out


def _solve_right(J: NDArray, S: NDArray) -> NDArray:
    """``J S^-1`` for stacks (K, a, b) and (K, b, b)."""
    return np.swapaxes(np.linalg.solve(np.swapaxes(S, 1, 2), np.swapaxes(J, 1, 2)), 1, 2)


def _indirect(G: NDArray, Cv: NDArray, Ainv: NDArray, n_y: int
              ) -> tuple[NDArray, NDArray, NDArray]:
    """Indirect step on a joint LPM fit of [J; S] (bins-first arrays).

    Returns P (K, n_y, n_u), and the Kronecker covariance factors of P:
    ``row = E C_v E^H`` with ``E = [I, -P]`` and ``col = S^-T A^-1 conj(S^-1)``.
    """
    J, S = G[:, :n_y], G[:, n_y:]
    Sinv = np.linalg.inv(S)
    P = J @ Sinv
    E = np.concatenate([np.broadcast_to(np.eye(n_y), P.shape[:1] + (n_y, n_y)), -P], axis=2)
    row = E @ Cv @ np.conj(np.swapaxes(E, 1, 2))
    col = np.swapaxes(Sinv, 1, 2) @ Ainv @ np.conj(Sinv)
    return P, row, col


#: Low-rate bins per block of the freq-lifted path: bounds the memory in flight; the
#: blocks run on the worker threads.
BLOCK_BINS = 8192


def _indirect_diag(G: NDArray, Cv: NDArray, Ainv: NDArray, n_y: int) -> tuple[NDArray, NDArray, NDArray]:
    """Indirect step on a joint LPM fit of [J; S], bins-last, keeping only the
    diagonals of the covariance factors.

    G (n_y + n_u, n_u, K), Cv (n_y + n_u, n_y + n_u, K), Ainv (n_u, n_u, K) as
    :func:`~mr_ident.lpm._lpm_core` returns them. Returns P (n_y, n_u, K),
    ``diag(E C_v E^H)`` (n_y, K) with ``E = [I, -P]`` and ``diag(S^-T A^-1 conj(S^-1))``
    (n_u, K): enough for the standard deviation of every entry of P.
    """
    J, S = G[:n_y], G[n_y:]
    Sinv = _batched.inv(S)
    P = _batched.matmul(J, Sinv)
    # diag(E Cv E^H)_a = Cv_yy[a,a] - 2 Re(Cv_yu[a,:] P[a,:]^H) + P[a,:] Cv_uu P[a,:]^H
    d = np.arange(n_y)
    row = (Cv[d, d].real - 2.0 * _batched.real_dot(Cv[:n_y, n_y:], P, axis=1)
           + _batched.real_dot(_batched.matmul(P, Cv[n_y:, n_y:]), P, axis=1))
    # diag(S^-T A^-1 conj(S^-1))_b = Re sum_j (S^-T A^-1)[b, j] conj(S^-1[j, b])
    col = _batched.real_dot(_batched.matmul(Sinv.transpose(1, 0, 2), Ainv), Sinv.transpose(1, 0, 2), axis=1)
    return P, np.maximum(row, 0.0), np.maximum(col, 0.0)


def _fit(Uin: NDArray, Yout: NDArray, n: int, degree: int, q: int, workers: int = 1
         ) -> tuple[NDArray, NDArray, NDArray, int]:
    """LPM (options already checked, q the dof) in bins-first layout, plus the singular-bin count."""
    G, Cv, Ainv, n_bad = _lpm_core(Uin, Yout, n, degree, q, workers)
    return G.transpose(2, 0, 1), Cv.transpose(2, 0, 1), Ainv.transpose(2, 0, 1), n_bad


def identify(r: ArrayLike, u: ArrayLike, y: ArrayLike, *, fs_high: float, ratio: int,
             method: str = "freq-lifted", n: int = 8, degree: int = 2,
             controller_low: ArrayLike | None = None, phase: int = 0, delay: int = 0,
             keep_lifted: bool = True, workers: int | None = None) -> Identification:
    """Identify the high-rate plant P_h (and the PFG) from closed-loop data.

    Parameters
    ----------
    r, u, y : array_like, shape (N,) or (N, channels)
        Reference, plant input and plant output at the high rate; N a multiple of F.
    fs_high : float
        High sample rate in Hz.
    ratio : int
        F = h_l / h_h.
    method : {"freq-lifted", "time-lifted", "lpm", "etfe"}
    n, degree : int
        LPM window half-width and polynomial degree R (defaults 8 and 2).
    controller_low : array_like, shape (M, n_u, n_y), optional
        Controller frequency response on all low-rate bins ``z = exp(2j pi k/M)``,
        k = 0..M-1; when given, the PFG is computed from P_h and it.
    phase, delay : int
        Controller sampling phase and computation delay in high-rate samples.
    keep_lifted : bool, default True
        Keep the lifted J and S with their covariance in the result (lifted methods);
        False saves memory (about 0.6 kB per low-rate bin for SISO, F = 3).
    workers : int, optional
        Threads over blocks of bins (default: every CPU available to the process;
        1 runs serially). The result does not depend on it; while they run,
        OpenBLAS is limited to one thread per caller.

    Returns
    -------
    Identification

    Raises
    ------
    DimensionError, DataError, ConfigError
        Bad shapes, NaN/inf, N not a multiple of F, too little data, bad options.
    """
    F = _check_ratio(ratio)
    if not (isinstance(fs_high, (int, float, np.floating)) and np.isfinite(fs_high) and fs_high > 0):
        raise ConfigError(f"fs_high must be a positive number of Hz, got {fs_high!r}")
    if method not in METHODS:
        raise ConfigError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    n_workers = resolve_workers(workers)
    ra, ua, ya = _check_signals(r, u, y, F)
    N, nr = ra.shape
    ny, nu = ya.shape[1], ua.shape[1]
    M = N // F
    half = N // 2
    period = N if method in ("lpm", "etfe") else M   # bins per period of the fitted spectrum
    if method != "etfe":
        lift = 1 if method == "lpm" else F
        q = check_lpm_options(n, degree, nr * lift, max(ny, nu) * lift)
        need = 2 * (2 * n + 1)
        if period < need:
            raise DataError(
                f"too few samples for the LPM window: {method} needs {need} independent bins "
                f"(2 x (2n+1), n={n}) per period, i.e. N >= {need * (N // period)} samples; got N = {N}")
    P_half = np.full((half + 1, ny, nu), np.nan + 0j)
    var_half = np.full((half + 1, ny, nu), np.nan)
    lifted_J = lifted_S = None

    if method == "freq-lifted":
        Rh, Uh, Yh = _half_spectra(ra, ua, ya, workers=n_workers)
        Kc = M // 2
        bins = np.arange(Kc + 1)
        aliases = M * np.arange(F)

        def block(b0: int) -> tuple[int, tuple | None]:
            """Lift, fit, indirect step and keep the diagonal for one block of bins.

            Blocks bound the memory and run on threads; each writes its own bins."""
            kb = bins[b0:b0 + BLOCK_BINS]
            idx = (np.arange(kb[0] - n, kb[-1] + n + 1)[:, None] + aliases[None, :]) % N
            lifted = lambda X: _bins(X, idx, N).reshape(idx.shape[0], -1)   # noqa: E731  (alias-major)
            G, Cv, Ainv, nb = _lpm_core(lifted(Rh), np.concatenate([lifted(Yh), lifted(Uh)], axis=1),
                                        n, degree, q)                     # bins-last
            P, rdiag, cdiag = _indirect_diag(G, Cv, Ainv, F * ny)
            Pb = P.reshape(F, ny, F, nu, kb.size)
            rd = rdiag.reshape(F, ny, kb.size)
            cd = cdiag.reshape(F, nu, kb.size)
            for l in range(F):
                kappa = kb + l * M
                Pl = Pb[l, :, l].transpose(2, 0, 1)
                vl = (rd[l][:, None] * cd[l][None]).transpose(2, 0, 1)
                direct = kappa <= half
                P_half[kappa[direct]] = Pl[direct]
                var_half[kappa[direct]] = vl[direct]
                mirror = ~direct & (N - kappa <= half)
                P_half[N - kappa[mirror]] = np.conj(Pl[mirror])
                var_half[N - kappa[mirror]] = vl[mirror]
            return nb, (tuple(a.transpose(2, 0, 1) for a in (G, Cv, Ainv)) if keep_lifted else None)

        done = thread_map(block, range(0, Kc + 1, BLOCK_BINS), n_workers)
        _warn_bad(sum(d[0] for d in done), Kc + 1)
        if keep_lifted:
            G, Cv, Ainv = (np.concatenate([d[1][i] for d in done]) for i in range(3))  # type: ignore[index]
            lifted_J = LiftedFRF(bins, G[:, :F * ny], Cv[:, :F * ny, :F * ny], Ainv, "frequency", F, N, q)
            lifted_S = LiftedFRF(bins, G[:, F * ny:], Cv[:, F * ny:, F * ny:], Ainv, "frequency", F, N, q)
    elif method == "time-lifted":
        Rt = scipy.fft.fft(ra.reshape(M, F * nr), axis=0, norm="ortho", workers=-1)
        Ut = scipy.fft.fft(ua.reshape(M, F * nu), axis=0, norm="ortho", workers=-1)
        Yt = scipy.fft.fft(ya.reshape(M, F * ny), axis=0, norm="ortho", workers=-1)
        Kc = M // 2
        idx = np.arange(-n, Kc + n + 1) % M
        G, Cv, Ainv, n_bad = _fit(Rt[idx], np.concatenate([Yt[idx], Ut[idx]], axis=1), n, degree, q,
                                  n_workers)
        _warn_bad(n_bad, Kc + 1)
        P, row, col = _indirect(G, Cv, Ainv, F * ny)
        bins = np.arange(Kc + 1)
        lifted_J = LiftedFRF(bins, G[:, :F * ny], Cv[:, :F * ny, :F * ny], Ainv, "time", F, N, q)
        lifted_S = LiftedFRF(bins, G[:, F * ny:], Cv[:, F * ny:, F * ny:], Ainv, "time", F, N, q)
        kappa = np.arange(half + 1)
        k = kappa % M
        flip = k > Kc
        kk = np.where(flip, M - k, k)
        # First block column: P_bar[(i, y), (0, u)], i = 0..F-1.
        first = P.reshape(Kc + 1, F, ny, F, nu)[kk, :, :, 0, :]          # (kappa, F, ny, nu)
        rowb = row.reshape(Kc + 1, F, ny, F, ny)[kk]                      # (kappa, F, ny, F, ny)
        c0 = np.real(np.diagonal(col.reshape(Kc + 1, F, nu, F, nu)[kk, 0, :, 0, :], axis1=1, axis2=2))
        first = np.where(flip[:, None, None, None], np.conj(first), first)
        rowb = np.where(flip[:, None, None, None, None], np.conj(rowb), rowb)
        ph = np.exp(-2j * np.pi * np.outer(kappa, np.arange(F)) / N)      # (kappa, F)
        P_half = np.einsum("ki,kiyu->kyu", ph, first)
        rdiag = np.diagonal(rowb, axis1=2, axis2=4)                        # (kappa, F, F, ny)
        quad = np.real(np.einsum("ki,kijy,kj->ky", ph, rdiag, np.conj(ph)))
        var_half = quad[:, :, None] * c0[:, None, :]
    elif method == "lpm":
        Rh, Uh, Yh = _half_spectra(ra, ua, ya, workers=n_workers)
        idx = np.arange(-n, half + n + 1) % N
        G, Cv, Ainv, n_bad = _lpm_core(_bins(Rh, idx, N), _bins(Yh + Uh, idx, N), n, degree, q,   # y, then u
                                       n_workers)                         # bins-last
        _warn_bad(n_bad, half + 1)
        P, rdiag, cdiag = _indirect_diag(G, Cv, Ainv, ny)
        P_half = P.transpose(2, 0, 1)
        var_half = (rdiag[:, None] * cdiag[None]).transpose(2, 0, 1)
    else:  # etfe
        if ny != 1 or nu != 1:
            raise DimensionError(
                f"etfe needs a SISO loop (one experiment cannot separate {nu} inputs); got n_y={ny}, n_u={nu}")
        Uf = scipy.fft.rfft(ua, axis=0, norm="ortho", workers=-1)
        Yf = scipy.fft.rfft(ya, axis=0, norm="ortho", workers=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            P_half = (Yf / Uf)[:, :, None]

    std_half = np.sqrt(np.maximum(var_half, 0.0))
    freq = np.arange(1, half + 1) * fs_high / N
    plant = FRF(freq, P_half[1:], std_half[1:], method)
    pfg: PFG | None = None
    if controller_low is not None:
        Kl = np.asarray(controller_low, dtype=complex)
        if Kl.shape != (M, nu, ny):
            raise DimensionError(f"controller_low must have shape (M={M}, n_u={nu}, n_y={ny}), got {Kl.shape}")
        gain, gstd = pfg_from_plant(P_half, Kl, F, N, P_std_half=None if method == "etfe" else std_half,
                                    phase=phase, delay=delay, workers=n_workers)
        pfg = PFG(freq, gain[1:], gstd[1:], f"plant:{method}")
    return Identification(plant=plant, pfg=pfg, lifted_J=lifted_J, lifted_S=lifted_S,
                          fs_high=float(fs_high), ratio=F)


