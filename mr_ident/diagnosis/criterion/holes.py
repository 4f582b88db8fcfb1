# SPDX-License-Identifier: Apache-2.0
"""Missing samples of y in the criterion: unknowns eliminated, not guesses.

The criterion (:class:`~mr_ident.diagnosis.criterion.objective.Objective`) is the
whitened spectrum ``W(k) E(k)`` of the residual ``e = y - ŷ`` on the rfft bins of its
window. Where a sample of y is missing, e is unknown there. Its exact treatment is the
same as that of the loop's unknown initial state: the missing residual samples are
unknowns of the least-squares problem, eliminated by projection. Writing the residual
with zeros at the holes, ``e = e₀ + Σ_m c_m δ_m``, each hole adds the column
``a_m = W(k) DFT(δ_m)(k) = W(k) e^{-j2πkm/N}/√N`` (real and imaginary parts) and the
criterion is ``min_c |W E₀ + A c|²``. Under a Gaussian noise model whose covariance is
what ``W`` whitens, this minimum is ``-2 log`` of the *marginal* likelihood of the samples
that are present (the Schur complement: minimising a quadratic form over some of its
variables leaves the quadratic form of the marginal), so nothing about the holes is
assumed and every present sample counts with its full weight.

The columns do not depend on the model: their Gram matrix
``G[a, b] = Σ_k W²(k) cos(2πk(m_a - m_b)/N) / N`` is one inverse FFT of ``W²``, and
``Aᵀ v`` and ``A c`` are one FFT each, so a projection costs two FFTs and one product
with the precomputed pseudo-inverse of G per channel (no matrix of N rows and one
column per hole is formed). The projection of a hole's column out of the free
responses' columns (:meth:`Holes.project`, applied to both) and then of those out of the
residual is the projection onto the complement of both spans together (exact).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg

from ...numerics.arrays import BoolArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model

#: Eigenvalues of a hole Gram matrix below this fraction of its largest are dropped (holes
#: whose columns the weight makes nearly alike: their combination is unknown either way).
GRAM_RCOND = 1e-12


def _gram_solver(G: FloatArray) -> Callable[[FloatArray], FloatArray]:
    """``b -> G⁺ b`` for a Gram matrix G: by Cholesky where it is well conditioned.

    Else (holes whose columns the weight makes nearly alike) by its eigenvalues, those
    below :data:`GRAM_RCOND` of the largest dropped. Cholesky is a third of the work.
    """
    if not G.size:
        return lambda b: np.zeros_like(b)
    try:
        factor = scipy.linalg.cho_factor(G, lower=True, check_finite=False)
        d = np.diag(factor[0]) ** 2
        if float(d.min()) > GRAM_RCOND * 1e2 * float(np.max(np.diag(G))):
            return lambda b: np.asarray(scipy.linalg.cho_solve(factor, b, check_finite=False))
    except np.linalg.LinAlgError:
        pass
    w, Q = np.linalg.eigh(G)
    keep = w > GRAM_RCOND * max(float(w[-1]), 0.0)
    inv = np.zeros_like(w)
    inv[keep] = 1.0 / w[keep]
    pinv = (Q * inv) @ Q.T
    return lambda b: np.asarray(np.tensordot(pinv, b, axes=(1, 0)))


class Holes:
    """The missing samples of y in a criterion's window, per output channel.

    Parameters
    ----------
    missing : ndarray of bool, shape (N, n_y)
        True where y's sample is missing (the window's samples, N of them).
    weight : ndarray, shape (N//2 + 1, n_y)
        The criterion's weight per rfft bin of the window.
    """

    def __init__(self, missing: BoolArray, weight: FloatArray):
        self.n = int(missing.shape[0])
        self.n_y = int(missing.shape[1])
        if weight.shape != (self.n // 2 + 1, self.n_y):
            raise ValueError(
                f"weight must be (N//2 + 1, n_y) = ({self.n // 2 + 1}, {self.n_y}), "
                f"got {weight.shape}"
            )
        self.weight = weight
        self.positions = [np.flatnonzero(missing[:, j]) for j in range(self.n_y)]
        self.count = int(sum(p.size for p in self.positions))
        half = np.full(weight.shape[0], 0.5)
        half[0] = 1.0
        if self.n % 2 == 0:
            half[-1] = 1.0
        self._half = half  # the rfft's interior bins stand for two of the full DFT
        self._solve: list[Callable[[FloatArray], FloatArray]] = []
        for j, pos in enumerate(self.positions):
            g = np.fft.irfft(weight[:, j] ** 2 * half, n=self.n)
            self._solve.append(_gram_solver(g[(pos[:, None] - pos[None, :]) % self.n]))

    def project(self, v: FloatArray) -> FloatArray:
        """``v`` less its least-squares fit by the holes' columns.

        ``v``: stacked like the criterion's residual, ``[Re V.ravel(); Im V.ravel()]`` for
        ``V`` of shape (N//2 + 1, n_y), with any trailing axes (columns) after the first.
        """
        if not self.count:
            return v
        nb = self.weight.shape[0]
        tail = v.shape[1:]
        V = (v[: nb * self.n_y] + 1j * v[nb * self.n_y :]).reshape(nb, self.n_y, *tail)
        out = V.copy()
        scale = np.sqrt(self.n)
        for j, pos in enumerate(self.positions):
            if not pos.size:
                continue
            wj = self.weight[:, j].reshape(nb, *(1,) * len(tail))
            hj = self._half.reshape(nb, *(1,) * len(tail))
            at = np.fft.irfft(wj * V[:, j] * hj, n=self.n, axis=0)[pos] * scale  # Aᵀ v
            c = self._solve[j](at)
            z = np.zeros((self.n, *tail))
            z[pos] = c
            out[:, j] -= wj * np.fft.rfft(z, axis=0, norm="ortho")  # A c
        out = out.reshape(nb * self.n_y, *tail)
        return np.concatenate([out.real, out.imag])


def longest_run(missing: BoolArray) -> int:
    """The longest run of consecutive True in a 1-D mask (0 if none)."""
    if not missing.any():
        return 0
    edges = np.diff(np.concatenate([[0], missing.astype(np.int8), [0]]))
    return int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))


def beyond_limits(rec: LoopData, n: int, degree: int = 2, ratio: int | None = None) -> str:
    """Why ``rec``'s missing samples are more than diagnose carries, or "" when they are not.

    The limits are identification's (:func:`~mr_ident.numerics.lifted.options.missing_limits`
    of ``freq-lifted`` with the window ``n`` and ``degree`` diagnose uses, over this record):
    per channel of u and y the share of missing samples and the longest hole. ``ratio``:
    F where ``rec`` does not say.
    """
    from ...errors import MrIdentError
    from ...numerics.lifted.options import missing_limits

    lost = np.concatenate([np.isnan(rec.y), np.isnan(rec.u)], axis=1)
    if not lost.any():
        return ""
    F = rec.ratio or ratio or 1
    n_out = max(rec.u.shape[1], rec.y.shape[1])
    try:
        lim = missing_limits(
            "freq-lifted", n, degree, F, rec.r.shape[1], n_out, n_samples=rec.n_samples
        )
    except MrIdentError as err:
        return f"the fit carries no missing sample with these options ({err})"
    share = float(lost.mean(axis=0).max())
    run = max(longest_run(lost[:, j]) for j in range(lost.shape[1]))
    if share > lim.share or run > lim.gap:
        return (
            f"{100 * share:.2g} % of a channel's samples missing, the longest hole {run} "
            f"samples; the fits carry at most {100 * lim.share:.2g} % and holes up to "
            f"{lim.gap} samples"
        )
    return ""


def check_missing(rec: LoopData, n: int, what: str) -> None:
    """Missing samples of u and y diagnose carries: none in periodic data, within the limits.

    r's are recovered before (:func:`~mr_ident.diagnosis.criterion.records.with_r`).

    Raises
    ------
    DataError
        Holes beyond the limits; a :class:`~mr_ident.errors.DataFieldError` naming
        ``{period}`` for periodic data with holes.
    """
    from ...errors import DataError, DataFieldError

    lost = np.isnan(rec.u).any(axis=1) | np.isnan(rec.y).any(axis=1)
    if not lost.any():
        return
    if rec.period is not None:
        raise DataFieldError(
            f"{what}: u or y miss {int(lost.sum())} samples; periodic data ({{period}}) are "
            "averaged over periods, which needs every sample (cut the record at the holes)",
            "period",
        )
    why = beyond_limits(rec, n)
    if why:
        raise DataError(
            f"{what}: too many missing samples for diagnose ({why}); diagnose the longest "
            "stretch without a hole (mr-ident diagnose does so by itself)"
        )


def complete_stretch(rec: LoopData, ratio: int | None = None) -> LoopData:
    """The longest part of ``rec`` without a missing sample, on the F grid (itself if none).

    Whole low-rate periods at both ends, on the absolute sample grid (``rec.first``);
    ``ratio``: F where ``rec`` does not say.
    """
    lost = np.isnan(rec.u).any(axis=1) | np.isnan(rec.y).any(axis=1)
    F = rec.ratio or ratio
    if not lost.any() or F is None:
        return rec
    edges = np.concatenate([[-1], np.flatnonzero(lost), [lost.size]])
    k = int(np.argmax(np.diff(edges)))
    lo, hi = int(edges[k]) + 1, int(edges[k + 1])
    lo += -(rec.first + lo) % F  # whole periods at both ends, on the absolute grid
    hi -= (rec.first + hi) % F
    return rec.part(lo, max(lo, hi))


def diagnosable(
    rec: LoopData, model: Model, n: int | str | None = None, degree: int = 2
) -> tuple[LoopData, str]:
    """The record diagnose takes of ``rec``, and a note when it is not all of it.

    All of it, its missing samples (NaN in u or y) unknowns of every fit, where they stay
    within the limits identification derives for diagnose's window (:func:`beyond_limits`;
    ``n`` as :func:`~mr_ident.diagnosis.diagnose` takes it); beyond them, and in periodic
    data, the longest stretch without a missing sample (:func:`complete_stretch`), the note
    saying which and why.
    """
    lost = np.isnan(rec.u).any(axis=1) | np.isnan(rec.y).any(axis=1)
    if not lost.any():
        return rec, ""
    if n is None or isinstance(n, str):
        from ...numerics.identify import default_n

        n = default_n("freq-lifted", degree, model.ratio, model.n_u, max(model.n_u, model.n_y))
    why = (
        "periodic data are averaged over whole periods"
        if rec.period is not None
        else beyond_limits(rec, n, degree, model.ratio)
    )
    if not why:
        return rec, ""
    part = complete_stretch(rec, model.ratio)
    return part, (
        f"u or y miss {int(lost.sum())} of {rec.n_samples} samples and {why}: diagnosed on "
        f"the longest stretch without a missing sample, samples {part.first - rec.first}.."
        f"{part.first - rec.first + part.n_samples - 1} ({part.n_samples} samples)"
    )
