# SPDX-License-Identifier: Apache-2.0
"""Missing samples of u and y as unknowns of the lifted local fit (not interpolated).

Ugryumova, Pintelon, Vandersteen, "Frequency response function estimation in the presence
of missing output data", IEEE Trans. Instrum. Meas. 64(2), 2015, extended to missing
inputs of a closed loop and to the frequency-lifted fit (the method page, "Missing
samples", derives it). Zero-fill the holes; the DFT of the record is then
``X(κ) = X0(κ) + Σ_m θ_m e^{-j2πκm/N}/√N`` over the missing samples m of the signal
(θ_m real, unknown). Every column of [y; u] is an output of the lifted r -> [y; u] fit (r,
the excitation, is known: never missing), whose window w has the regressor K_w (the
lifted R times ``(r/n)^s`` and the transient ``(r/n)^s``, s = 0..R). Eliminating the local
model of every window by its projection ``P_w = I - Q_w Q_wᴴ`` (Q_w an orthonormal basis
of K_w) leaves the global least-squares problem

    min_θ  Σ_w ‖P_w (Y0_w + D_w θ)‖²,

D_w the window's lifted bins of the spread-and-transformed θ. The same θ enters every
alias of the window (one unknown per missing high-rate sample). Its normal equations
``Aᵀ A θ = -Aᵀ a0`` (real) are solved by conjugate gradients on the operator
θ -> spread -> DFT -> gather the lifted windows -> project -> scatter back -> adjoint DFT
-> take at the holes: about ``N log N`` per step, never a matrix of the unknowns. The
columns of [y; u] are decoupled (P_w acts per column), so one run solves them all.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from ...errors import DataError
from ..arrays import BoolArray, ComplexArray, FloatArray, IntArray
from ..lifting import freq_lift_half, half_spectrum
from ..threads import one_blas_thread

#: Windows per chunk of the projection (complex (chunk, 2n+1, Q) bases).
CHUNK_WINDOWS = 4096
#: The bases of every window are kept between iterations up to this many bytes.
CACHE_BYTES = 256 * 2**20
#: Conjugate gradients stop at this residual, relative to the right-hand side.
RTOL = 1e-10
#: The first of two solves (``reweight``) only sets the weights: this residual is enough
#: (1e-6 left the weights of a noise-free record visibly short: 1.4e-8 instead of 6.8e-9).
FIRST_RTOL = 1e-8
#: ``ω_w = 1/(s_w + WEIGHT_FLOOR median(s))``: the windows of large residual power s_w lose
#: weight, none gains more than 1/median (a floor of 0.01 took 37 steps instead of 14 for
#: no gain noise-free).
WEIGHT_FLOOR = 1.0
#: The ridge λ of the solve, relative to the median diagonal of Aᵀ A (see ``_solve``): 0,
#: the plain least squares (1e-12 and 1e-10 made the noise-free plant 1.2x and 8x worse:
#: the fit's transient takes the ends' holes as they come, not as interpolated).
RIDGE = 0.0
#: ... or when a step lowers the criterion by less than this share of it (``ftol``).
FTOL = 1e-6
#: ... or after this many iterations (a warning then).
MAX_ITER = 400


@dataclass(frozen=True)
class MissingFill:
    """The missing samples estimated: the filled signals and how the solve went.

    Attributes
    ----------
    u, y : ndarray, shapes (N, n_u), (N, n_y)
        The signals with every missing sample replaced by its estimate θ̂. Holes within
        about N/(2n+1) samples of the record's ends are loosely determined (the windows'
        transient takes them; the fit's does the same, so the plant does not suffer).
    holes : tuple of ndarray of int
        The missing sample indices of every column of [y; u] (n_y + n_u arrays).
    theta : tuple of ndarray of float
        θ̂ of every column, in the order of ``holes``.
    iterations : int
        Conjugate-gradient steps taken.
    """

    u: FloatArray
    y: FloatArray
    holes: tuple[IntArray, ...]
    theta: tuple[FloatArray, ...]
    iterations: int


@dataclass(frozen=True)
class SolveOptions:
    """How the conjugate gradients solve for θ̂ (the keywords of :func:`estimate_missing`)."""

    rtol: float = RTOL
    reweight: bool = True
    ridge: float = RIDGE
    ftol: float = FTOL


@dataclass(frozen=True)
class _Holes:
    """[y; u] with holes: zero-filled, where, interpolated (mask order), Aᵀ A's diagonal."""

    x0: FloatArray
    mask: BoolArray
    prior: FloatArray
    diag: FloatArray


def holes_of(x: FloatArray) -> tuple[IntArray, ...]:
    """The indices of the NaN samples of every column of x (N, c)."""
    return tuple(np.flatnonzero(np.isnan(x[:, j])) for j in range(x.shape[1]))


def longest_burst(idx: IntArray) -> int:
    """The longest run of consecutive indices in the sorted ``idx`` (0 when empty)."""
    if idx.size == 0:
        return 0
    breaks = np.flatnonzero(np.diff(idx) != 1)
    edges = np.concatenate([[-1], breaks, [idx.size - 1]])
    return int(np.diff(edges).max())


class _Criterion:
    """``Σ_w ‖P_w (Y0_w + D_w θ)‖²`` of the lifted fit r -> [y; u], window half-width n.

    The windows are centred on every ``stride``-th low-rate bin of 0..M//2 (and on M//2):
    with ``stride <= 2n+1`` every bin lies in a window.
    """

    def __init__(self, r: FloatArray, ratio: int, n: int, degree: int, stride: int) -> None:
        N = r.shape[0]
        F, M = ratio, N // ratio
        self.N, self.n, self.F = N, n, F
        self.centres = np.unique(np.append(np.arange(0, M // 2 + 1, stride), M // 2))
        self.n_win = self.centres.size
        self.n_bins = M // 2 + 1 + 2 * n  # lifted bins -n..M//2+n
        bins = np.arange(-n, M // 2 + 1 + n)
        # full-spectrum index of every lifted bin (unique: M >= 2 (2n + 1))
        idx = (bins[:, None] + M * np.arange(F)[None, :]) % N
        self.upper = idx > N // 2
        self.fold = np.where(self.upper, N - idx, idx)  # the rfft bin of every lifted bin
        self.half_weight = np.full(N // 2 + 1, 0.5)  # irfft counts bins 1..(N-1)//2 twice
        self.half_weight[0] = 1.0
        if N % 2 == 0:
            self.half_weight[-1] = 1.0
        self.R = freq_lift_half(half_spectrum(r), bins, F, N)  # (n_bins, F n_r)
        x = np.arange(-n, n + 1) / n
        self.powers = x[None, :] ** np.arange(degree + 1)[:, None]  # (R+1, 2n+1)
        q = (degree + 1) * (self.R.shape[1] + 1)
        size = self.n_win * (2 * n + 1) * q * 16
        cache: list[tuple[ComplexArray, ComplexArray]] | None = (
            [] if 2 * size <= CACHE_BYTES else None
        )
        self._cache = cache
        self.weights: FloatArray | None = None  # (n_win, C): ω of every window and column
        self._scatters: dict[tuple[int, int], IntArray] = {}
        self.value = 0.0  # the criterion of the last :meth:`project`
        self._sign = np.where(self.upper, -1.0, 1.0)[:, :, None]  # conjugate above N/2
        self._gathers: dict[int, IntArray] = {}

    def _rows(self, a: int) -> IntArray:
        """The lifted-bin rows (B, 2n+1) of the windows a..a+CHUNK_WINDOWS-1."""
        c = self.centres[a : a + CHUNK_WINDOWS]
        rows: IntArray = c[:, None] + np.arange(2 * self.n + 1)[None, :]
        return rows

    def _bases(self, i: int, a: int) -> tuple[ComplexArray, ComplexArray]:
        """Q_w (B, 2n+1, Q), orthonormal bases of chunk i (windows a..), and their Q_wᴴ.

        Cached while they fit :data:`CACHE_BYTES`.
        """
        if self._cache is not None and i < len(self._cache):
            return self._cache[i]
        Rw = self.R[self._rows(a)]  # (B, L, F n_r)
        B, L = Rw.shape[:2]
        p = self.powers.T  # (L, R+1)
        Kg = (p[None, :, :, None] * Rw[:, :, None, :]).reshape(B, L, -1)
        Kt = np.broadcast_to(p[None].astype(complex), (B, L, p.shape[1]))
        Q: ComplexArray = np.linalg.qr(np.concatenate([Kt, Kg], axis=2))[0]
        QH = np.conj(Q.transpose(0, 2, 1)).copy()
        if self._cache is not None:
            self._cache.append((Q, QH))
        return Q, QH

    def window_power(self, Z: ComplexArray) -> FloatArray:
        """``‖P_w Z_w‖²`` of every window and column of lifted bins Z (n_bins, F, C)."""
        C = Z.shape[2]
        Zf = Z.reshape(Z.shape[0], -1)
        out = np.empty((self.n_win, C))
        for i, a in enumerate(range(0, self.n_win, CHUNK_WINDOWS)):
            Q, QH = self._bases(i, a)
            W = Zf[self._rows(a)]
            E = W - Q @ (QH @ W)
            e2 = (E.real**2 + E.imag**2).reshape(E.shape[0], -1, self.F, C)
            out[a : a + E.shape[0]] = e2.sum(axis=(1, 2))
        return out

    def project(self, Z: ComplexArray) -> ComplexArray:
        """``Σ_w ω_w S_wᵀ P_w S_w Z`` on lifted bins Z (n_bins, F, C).

        Sets :attr:`value`, the criterion ``Σ_w ω_w ‖P_w S_w Z‖²`` of Z.
        """
        L, C = 2 * self.n + 1, Z.shape[2]
        Zf = Z.reshape(Z.shape[0], -1)
        out = np.zeros_like(Zf)
        value = 0.0
        for i, a in enumerate(range(0, self.n_win, CHUNK_WINDOWS)):
            Q, QH = self._bases(i, a)
            rows = self._rows(a)
            W = Zf[rows]  # (B, L, F C)
            E = W - Q @ (QH @ W)
            if self.weights is not None:
                w = self.weights[a : a + E.shape[0]]
                Ew = (E.reshape(E.shape[0], L, self.F, C) * w[:, None, None, :]).reshape(E.shape)
                value += float(np.vdot(E, Ew).real)
                E = Ew
            else:
                value += float(np.vdot(E, E).real)
            k = self._scatter(i, a, Zf.shape[1])  # every column's bins at once
            size = self.n_bins * Zf.shape[1]
            Er = E.reshape(-1)
            part = out[: self.n_bins].reshape(-1)
            part += np.bincount(k, Er.real, size)
            part += 1j * np.bincount(k, Er.imag, size)
            out[: self.n_bins] = part.reshape(self.n_bins, -1)
        self.value = value
        return out.reshape(Z.shape[0], self.F, C)

    def _scatter(self, i: int, a: int, cols: int) -> IntArray:
        """``bin · cols + column`` of every entry of chunk i's windows (B, L, cols), raveled."""
        key = (i, cols)
        if key not in self._scatters:
            rows = self._rows(a)
            self._scatters[key] = (rows[:, :, None] * cols + np.arange(cols)).ravel()
        return self._scatters[key]

    def diagonal(self, holes: IntArray, cols: IntArray, n_cols: int) -> FloatArray:
        """``(Aᵀ A)[m, m]`` of the samples ``holes``, exactly and without the operator.

        Column (l, c) of window w holds ``e^{-j2π(k_w + r + l M) m/N}/√N``, r = -n..n: a
        unit phase times ``a_m(r) = e^{-j2πrm/N}/√N``, so
        ``(Aᵀ A)[m, m] = F Σ_w ‖P_w a_m‖² = F (n_win (2n+1) - a_mᴴ Π a_m)/N`` (a_m without
        its 1/√N) with ``Π = Σ_w Q_w Q_wᴴ`` ((2n+1) x (2n+1)), the same for every column.
        """
        L = 2 * self.n + 1
        w = np.ones((self.n_win, n_cols)) if self.weights is None else self.weights
        Pi = np.zeros((n_cols, L, L), dtype=np.complex128)
        for i, a in enumerate(range(0, self.n_win, CHUNK_WINDOWS)):
            Q = self._bases(i, a)[0]
            for c in range(n_cols if self.weights is not None else 1):
                Qw = (Q * np.sqrt(w[a : a + Q.shape[0], c])[:, None, None]).transpose(1, 0, 2)
                Qw = Qw.reshape(L, -1)
                Pi[c] += Qw @ np.conj(Qw.T)
        if self.weights is None:  # the same for every column
            Pi[1:] = Pi[0]
        a_m = np.exp(-2j * np.pi * np.outer(holes, np.arange(-self.n, self.n + 1)) / self.N)
        quad = np.empty(holes.size)
        for c in range(n_cols):
            at = cols == c
            quad[at] = ((np.conj(a_m[at]) @ Pi[c]) * a_m[at]).sum(axis=1).real
        d: FloatArray = self.F * (w.sum(axis=0)[cols] * L - quad) / self.N
        return d

    def forward(self, x: FloatArray) -> ComplexArray:
        """The lifted bins (n_bins, F, C) of the unitary DFT of the signals x (N, C)."""
        Xh = np.fft.rfft(x.T, axis=1).T / np.sqrt(self.N)
        X: ComplexArray = Xh[self.fold]
        X.imag *= self._sign
        return X

    def adjoint(self, Z: ComplexArray) -> FloatArray:
        """The real adjoint of :meth:`forward`: x (N, C).

        ``x[t] = Re Σ_κ Z_κ e^{j2πκt/N}/√N`` over the gathered bins κ; a bin above N/2
        enters as the conjugate at N - κ, so the sum is an inverse real FFT.
        """
        C = Z.shape[2]
        if C not in self._gathers:  # ``rfft bin · C + column`` of every entry, raveled
            self._gathers[C] = (self.fold[:, :, None] * C + np.arange(C)).ravel()
        k = self._gathers[C]
        size = (self.N // 2 + 1) * C
        H = np.empty((self.N // 2 + 1, C), dtype=np.complex128)
        H.real = np.bincount(k, Z.real.ravel(), size).reshape(-1, C)
        H.imag = np.bincount(k, (Z.imag * self._sign).ravel(), size).reshape(-1, C)
        H *= self.half_weight[:, None]
        x: FloatArray = np.fft.irfft(H.T, n=self.N, axis=1).T * (self.N / np.sqrt(self.N))
        return x

    def normal(self, x: FloatArray) -> FloatArray:
        """``Aᵀ A`` applied to the signals x (N, C) (every sample; the caller takes holes)."""
        return self.adjoint(self.project(self.forward(x)))


def estimate_missing(
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    ratio: int,
    n: int,
    degree: int,
    *,
    rtol: float = RTOL,
    stride: int | None = None,
    reweight: bool = True,
    ridge: float = RIDGE,
    ftol: float = FTOL,
) -> MissingFill:
    """Estimate the NaN samples of u and y: the least-squares θ̂ of the lifted local fit.

    Parameters
    ----------
    r : ndarray, shape (N, n_r)
        The excitation, complete (no NaN; checked by the caller).
    u, y : ndarray, shapes (N, n_u), (N, n_y)
        NaN where a sample is missing. N a multiple of F, and ``N >= 2 (2n+1) F``.
    ratio, n, degree : int
        F and the lifted local polynomial's window half-width and degree R (the options of
        ``freq-lifted``: ``2n+1 - (R+1)(F n_r + 1) > F max(n_y, n_u)``, checked by the
        caller).
    rtol : float
        Conjugate gradients stop at ``‖Aᵀ(a0 + A θ)‖ <= rtol ‖Aᵀ a0‖``.
    stride : int, optional
        The windows of the criterion are centred on every stride-th low-rate bin (default
        n: every bin in two or three windows; 1: every window of the fit). Noise-free, every
        stride up to 2n+1 gives the exact samples; n costs 1/n of every window.
    reweight : bool, default True
        Solve twice: the second time with every window (and column) weighted by
        ``1/(s_w + median s)``, s_w its residual power after the first (averaged over 5
        windows). With white noise s_w is about the same everywhere (the weights nearly
        equal); noise-free it is the local model's error, which an unweighted solve
        spreads from the worst windows (resonances) over every bin (paper's loop, 600 s,
        1 % missing: 1.8e-8 unweighted, 2.5e-9 weighted, median relative error of P_h).
    ftol : float
        Conjugate gradients stop as well when a step lowers the criterion by less than
        ftol of its value: with noise the criterion's floor is the noise's residual and
        the estimates are then within about 0.01 of the noise's std of the solution; noise-free
        the floor is the local model's error and the rule asks for more steps. 0: rtol alone.
    ridge : float
        λ relative to the median diagonal of Aᵀ A: the solve pulls every θ towards the
        linear interpolation of its neighbours (where the iteration starts) with that
        weight; 0 (default): the plain least squares.

    Returns
    -------
    MissingFill

    Warns
    -----
    RuntimeWarning
        When the conjugate gradients stop at :data:`MAX_ITER` steps before ``rtol``.
    """
    options = SolveOptions(rtol=rtol, reweight=reweight, ridge=ridge, ftol=ftol)
    with one_blas_thread():  # its threads slow the thin products down (docs/benchmarks.md)
        crit = _Criterion(r, ratio, n, degree, n if stride is None else stride)
        return _estimate(crit, u, y, options)


def _estimate(
    crit: _Criterion, u: FloatArray, y: FloatArray, options: SolveOptions
) -> MissingFill:
    """:func:`estimate_missing` on its criterion (OpenBLAS on one thread)."""
    yu = np.concatenate([y, u], axis=1)
    holes = holes_of(yu)
    mask = np.isnan(yu)
    x0 = np.where(mask, 0.0, yu)
    rtol = options.rtol
    first = max(rtol, FIRST_RTOL) if options.reweight else rtol
    # the unweighted diagonal preconditions both solves (weights of mean 1, about equal with
    # noise: the weighted one took as many steps), the record's window power serves both
    rows, cols = np.nonzero(mask)
    record = _Holes(x0, mask, _interpolated(x0, mask), crit.diagonal(rows, cols, mask.shape[1]))
    theta, it, bb = _solve(crit, record, record.prior.copy(), replace(options, rtol=first))
    if options.reweight:
        filled = x0.copy()
        filled[mask] = theta
        power = crit.window_power(crit.forward(filled))  # (n_win, C)
        k = 2  # smoothed over ±k windows: about 5 x 2 q F residual degrees of freedom
        kern = np.ones(2 * k + 1) / (2 * k + 1)
        padded = np.pad(power, ((k, k), (0, 0)), mode="edge")
        smooth = np.stack(
            [np.convolve(padded[:, c], kern, mode="valid") for c in range(power.shape[1])], 1
        )
        floor = WEIGHT_FLOOR * np.median(smooth, axis=0, keepdims=True) + np.finfo(float).tiny
        crit.weights = 1.0 / (smooth + floor)
        crit.weights /= crit.weights.mean(axis=0, keepdims=True)
        theta, it2, _ = _solve(crit, record, theta, options, bb)
        it += it2
    filled = x0.copy()
    filled[mask] = theta
    thetas = tuple(filled[h, j] for j, h in enumerate(holes))
    ny = y.shape[1]
    u_filled, y_filled = filled[:, ny:], filled[:, :ny]
    return MissingFill(u=u_filled, y=y_filled, holes=holes, theta=thetas, iterations=it)


def _interpolated(x0: FloatArray, mask: BoolArray) -> FloatArray:
    """The holes of every column linearly interpolated between its kept samples (mask order)."""
    t = np.arange(x0.shape[0])
    out = np.empty(x0.shape)
    for c in range(x0.shape[1]):
        keep = ~mask[:, c]
        out[:, c] = np.interp(t, t[keep], x0[keep, c]) if keep.any() else 0.0
    values: FloatArray = out[mask]
    return values


def _solve(
    crit: _Criterion,
    record: _Holes,
    theta0: FloatArray,
    options: SolveOptions,
    bb: float | None = None,
) -> tuple[FloatArray, int, float]:
    """Preconditioned conjugate gradients from θ0; θ, the steps and ``‖b‖²``.

    On ``(Aᵀ A + λ I) θ = -Aᵀ a0 + λ θ_prior``, λ = ``ridge`` times the median of the
    diagonal of Aᵀ A. A hole at the record's very ends has a diagonal near 0 (its phase
    ramp is smooth across every window: the transient takes it); the preconditioner
    keeps its exact diagonal (bounded below by 1e-14 of the median against rounding), so
    the steps stay few, and its value is loose (the fit's transient takes it too).
    ``record.diag``: the diagonal of the unweighted Aᵀ A (the preconditioner; a weighted
    solve's weights have mean 1); ``bb``: ``‖b‖²``, the scale of ``rtol``, where known (a weighted
    solve takes the unweighted one's: weights of mean 1).
    """
    x0, mask, prior, d = record.x0, record.mask, record.prior, record.diag
    rtol, ftol = options.rtol, options.ftol
    lam = options.ridge * float(np.median(d))
    inv_diag = 1.0 / (np.maximum(d, 1e-14 * float(np.median(d))) + lam)

    def apply(v: FloatArray) -> FloatArray:
        spread = np.zeros_like(x0)
        spread[mask] = v
        Hv: FloatArray = crit.normal(spread)[mask] + lam * v
        return Hv

    if bb is None:
        b = -crit.normal(x0)[mask] + lam * prior  # -Aᵀ a0 at the holes (row-major order)
        bb = float(b @ b)
    stop = rtol**2 * bb
    theta = theta0.copy()
    filled = x0.copy()
    filled[mask] = theta
    # b - (AᵀA + λ) θ = -Aᵀ(a0 + A θ) + λ (prior - θ): one application
    res = -crit.normal(filled)[mask] + lam * (prior - theta)
    # the criterion f(θ) = ‖a0 + A θ‖² (+ λ‖θ - prior‖²), and each step lowers it by
    # α rᵀz: stop too when that is below FTOL of f (the noise's residual)
    f = crit.value + lam * float((theta - prior) @ (theta - prior))
    z = inv_diag * res
    direction = z.copy()
    rz = float(res @ z)
    it = 0
    while float(res @ res) > stop and it < MAX_ITER:
        Hd = apply(direction)
        alpha = rz / float(direction @ Hd)
        theta += alpha * direction
        res -= alpha * Hd
        z = inv_diag * res
        rz_new = float(res @ z)
        direction = z + (rz_new / rz) * direction
        f -= alpha * rz
        it += 1
        if alpha * rz <= ftol * f:
            return theta, it, bb
        rz = rz_new
    rr = float(res @ res)
    if rr > stop:
        warnings.warn(
            f"missing samples: conjugate gradients stopped after {MAX_ITER} steps at a "
            f"relative residual {np.sqrt(rr / bb):.1e} (asked {rtol:g})",
            RuntimeWarning,
            stacklevel=3,
        )
    return theta, it, bb


def max_share(n: int, dof: int, n_map: int) -> float:
    """The largest share of missing samples of a signal that a fit's windows can carry.

    A window keeps ``q' = q - (2n+1) p`` residual degrees of freedom per output
    (:func:`~mr_ident.numerics.local.fit.missing_factor`); the noise model needs
    ``q' > n_map`` (the outputs of one map, as the options' rule): ``p < (q - n_map)/(2n+1)``.
    """
    return (dof - n_map) / (2 * n + 1)


def check_share(
    counts: IntArray, n_samples: int, names: list[str], rules: list[tuple[str, int, int, int]]
) -> None:
    """DataError when a channel misses more samples than a fit of ``rules`` can carry.

    ``counts``: missing samples per channel named ``names``; ``rules``: (fit, n, q, n_map).
    """
    for what, n, q, n_map in rules:
        limit = max_share(n, q, n_map)
        for count, name in zip(counts, names, strict=True):
            if count / n_samples >= limit:
                raise DataError(
                    f"{name} misses {count} of {n_samples} samples "
                    f"({100 * count / n_samples:.1f} %); the {what} fit (n = {n}, q = {q} "
                    f"residual degrees of freedom per window of 2n+1 = {2 * n + 1} bins, "
                    f"{n_map} of them needed) carries less than (q - {n_map})/(2n+1) = "
                    f"{100 * limit:.1f} %: cut the record at its long gaps, or widen the "
                    "window (n)"
                )
