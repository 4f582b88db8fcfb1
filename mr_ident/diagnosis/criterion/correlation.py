# SPDX-License-Identifier: Apache-2.0
"""Nonlinear distortion under any excitation: the residual's higher-order correlations.

Periodic records show distortion on their unexcited lines and across realizations
(:mod:`.distortion`, :mod:`.realizations`); a record of random r has neither. What it
has is the validated model's output error ``e = y - P u - O x̂₀`` (the logged u through
the model's plant, its free responses from the least-squares initial state projected
out: :func:`~.matched.output_error`) and the model's own noise-free signals ``û``,
``ŷ`` (linear in r). If the loop is linear and the model describes it, e is the output
noise itself (not the noise as the loop shapes it, whose slow closed-loop modes no short
filter whitens), independent of r and so of every function of r. A static nonlinearity
``f`` at the plant's input (saturation, dead zone) makes ``e = P (f(u) - u) + v``; one at
its output (a sensor that clips) ``e = f(y) - y + v``: each correlates with higher
powers of the signal it acts on (Billings and Voon 1986 test the residual's correlations
with ``u²``; here with Hermite polynomials, as below).

**Regressors.** With ``z = û / std(û)`` (input side) or ``z = ŷ / std(ŷ)`` (output side),
``He₂(z) = z² - 1`` (even) and ``He₃(z) = z³ - 3z`` (odd), the input side's through the
model's plant P. With several inputs and outputs, per output channel o: He₂ and He₃ of
every input's z through ``P[o, i]``, and of its own ``ŷ_o``. For Gaussian r, z is
Gaussian and ``E{He_n(z) w} = 0`` for every w
linear in r and n >= 2 (Isserlis): a *linear* model error leaves the coefficients at 0
in expectation; only a nonlinear one moves them. The test asks r to be Gaussian-like
(white or filtered noise, a random-phase multisine of many lines); it is run on records
that are not periodic (periodic ones have the tests above).

**The test.** From the validation start on: ``e = X β + L γ + c + w``, four columns X,
and as nuisances L the model's ŷ at lags 0..:data:`LAGS`-1 (a linear error of the
model), P's free responses and a constant. The noise's own colour is taken out by an
autoregressive filter ``A(q)`` of order :data:`ORDER` fitted to e by least squares and
applied to e, X and L alike (prewhitening); the nuisances projected out of both
(Frisch-Waugh); least squares, and the coefficients' covariance by the
heteroscedasticity-robust sandwich with each sample's residual over one less its
leverage (HC3: He₃'s heavy tail puts weight on few samples) and the Newey-West sum over
:func:`hac_lags` lags (what the filter left, a multirate loop's periodic statistics).
Under the null the Wald statistic ``β^T V⁻¹ β`` is χ²(k), k = 2 n_u + 2 columns (4 for a
SISO loop); nonlinear distortion is found at ``p <`` :data:`HOS_ALPHA`. With n_y outputs
each is tested alone and the smallest p counts n_y times (Bonferroni: the level holds over
the outputs together). The kind is named by the sub-tests of the odd and even columns and
of the input and output columns (each at the same level, a χ² of their count within the
joint fit, Bonferroni over the outputs alike); where both or neither pass, that part of
the kind is not named. Its level: the fitted part's power over the rest,
``10 log10(1 + ‖Xβ‖² / ‖e - Xβ‖²)`` dB, on the output where it is largest;
each output's rest variance bounds that output's noise from above (:mod:`.unexplained`
takes it where it is below the LPM's level, which under random r holds the distortion).

**Missing samples** (NaN in u or y). The output error takes u's missing samples as
identification estimates them and is NaN where y is missing (:func:`~.matched.
output_error`); the regressors come from r alone and are complete. A filtered sample whose
filter window reaches a missing e is left out (the filter is exact elsewhere), and so is
every row of the autoregression that does; the Newey-West sum runs over the time axis
with the left-out samples' scores at zero, so no lag is shortened by a hole.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np
import scipy.stats

from ...numerics.arrays import FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import LoopStream
from .matched import free_response, output_error
from .prediction import Prediction

#: Fewer samples than this many times 16 past the settling: no test.
SMOOTH = 33
#: The test's level: a nonlinearity named on a linear loop with this probability at most
#: (:func:`correlation`; calibrated in docs/diagnose.md).
HOS_ALPHA = 1e-3
#: Lags of the model's own ŷ projected out with the free responses (a linear error of the
#: model, which the He-orthogonality leaves at 0 in expectation only).
LAGS = 8
#: Order of the autoregressive filter that whitens the residual (and the regressors alike).
ORDER = 30
#: The regressors of a SISO loop, in the order of the columns: (side, kind).
COLUMNS: tuple[tuple[str, str], ...] = (
    ("input", "even"),
    ("input", "odd"),
    ("output", "even"),
    ("output", "odd"),
)
KINDS = ("even", "odd")


@dataclass(frozen=True)
class Correlation:
    """The residual's higher-order correlations with the model's signals.

    Attributes
    ----------
    statistic : float
        Wald statistic of the output with the smallest p, χ²(2 n_u + 2) under the null.
    p : float
        That output's p times the number of outputs (at most 1).
    alpha : float
        The level.
    z : tuple of float
        Each coefficient over its std, named by :attr:`names`.
    odd_p, even_p, input_p, output_p : float
        The sub-tests of the odd, even, input and output columns (Bonferroni over outputs).
    level_db : float
        The fitted part's power over the rest, dB above it, on the output where it is largest.
    samples : int
        Samples tested (per output; the ones left out for missing samples not counted).
    rest_vars : tuple of float
        Per output, (n_y,): the output error's variance per sample with the fitted part
        taken out, an upper bound of that output's noise where the distortion is found
        (the LPM's noise level holds a random excitation's distortion, so
        :mod:`.unexplained` takes the smaller, shaped by the loop as the noise in y is:
        :func:`~.unexplained.loop_shaped`).
    fitted_vars : tuple of float
        Per output, (n_y,): the fitted part's variance per sample, a lower bound of the
        distortion's (what the regressors do not span of it stays in the rest).
    """

    statistic: float
    p: float
    alpha: float
    z: tuple[float, ...]
    odd_p: float
    even_p: float
    input_p: float
    output_p: float
    level_db: float
    samples: int
    rest_vars: tuple[float, ...] = ()
    fitted_vars: tuple[float, ...] = ()
    names: tuple[str, ...] = tuple(f"{side}_{kind}" for side, kind in COLUMNS)

    @property
    def detected(self) -> bool:
        """Nonlinear distortion at level :attr:`alpha`."""
        return self.p < self.alpha

    @property
    def kind(self) -> str:
        """The parity: odd, even, odd and even, or empty (the data do not tell)."""
        hit = [k for k, p in (("odd", self.odd_p), ("even", self.even_p)) if p < self.alpha]
        return " and ".join(hit)

    @property
    def side(self) -> str:
        """The side, input or output, where one pair passes and the other not; else empty."""
        hit = [
            k for k, p in (("input", self.input_p), ("output", self.output_p)) if p < self.alpha
        ]
        return hit[0] if len(hit) == 1 else ""

    def text(self) -> str:
        """The finding in words, or "" where there is none."""
        if not self.detected:
            return ""
        kind = ", ".join(x for x in (self.kind, f"{self.side} side" if self.side else "") if x)
        return (
            f"nonlinear distortion{' (' + kind + ')' if kind else ''} in the residual's "
            f"higher-order correlations with the input: {self.level_db:.1f} dB above the "
            f"noise (Wald {self.statistic:.1f}, p = {self.p:.2g} < {self.alpha:g}; the "
            "residual correlates with the square or cube of the model's own signals, which "
            "no linear model makes)"
        )

    def summary(self) -> dict[str, object]:
        """The JSON report's figures."""
        return {
            "detected": self.detected,
            "statistic": self.statistic,
            "p": self.p,
            "alpha": self.alpha,
            "z": dict(zip(self.names, self.z, strict=True)),
            "odd_p": self.odd_p,
            "even_p": self.even_p,
            "input_p": self.input_p,
            "output_p": self.output_p,
            "level_db": self.level_db,
            "kind": self.kind,
            "side": self.side,
            "samples": self.samples,
        }


def _hermite(x: FloatArray, s: int) -> tuple[FloatArray, FloatArray]:
    """He₂ and He₃ of ``x`` standardised by its mean and std from sample ``s`` on."""
    z = (x - x[s:].mean()) / max(float(x[s:].std()), 1e-300)
    return z * z - 1.0, z * (z * z - 3.0)


def hac_lags(ratio: int) -> int:
    """Lags of the Newey-West sum: four low-rate periods and ten samples."""
    return 4 * ratio + 10


def _ar(e: FloatArray, order: int) -> FloatArray:
    """The AR polynomial ``[1, -a_1, ..., -a_p]`` that whitens ``e``, by least squares.

    Rows that reach a missing (NaN) sample are left out.
    """
    n = e.size
    lagged = np.column_stack([e[order - i - 1 : n - i - 1] for i in range(order)])
    ok = np.isfinite(e[order:]) & np.all(np.isfinite(lagged), axis=1)
    a = np.linalg.lstsq(lagged[ok], e[order:][ok], rcond=None)[0]
    return np.concatenate([[1.0], -a])


def _filtered(a: FloatArray, x: FloatArray) -> FloatArray:
    """``A(q) x`` per column, the first ``len(a) - 1`` samples dropped."""
    p = a.size - 1
    out = x[p:].copy()
    for i in range(1, p + 1):
        out += a[i] * x[p - i : x.shape[0] - i]
    return out


def _p(beta: FloatArray, V: FloatArray, idx: list[int]) -> float:
    """The χ² p of the coefficients ``idx`` within the joint fit (1 where V is singular)."""
    b, v = beta[idx], V[np.ix_(idx, idx)]
    try:
        w = float(b @ np.linalg.solve(v, b))
    except np.linalg.LinAlgError:
        return 1.0
    return float(scipy.stats.chi2.sf(w, len(idx)))


@dataclass(frozen=True)
class _Output:
    """One output's fit: coefficients, their covariance, the fitted part and the rest."""

    beta: FloatArray
    V: FloatArray
    fitted: float
    rest: float
    samples: int


def _fit(e: FloatArray, X: FloatArray, lin: FloatArray, F: int) -> _Output | None:
    """The prewhitened, robust fit of ``e`` (n,) on ``X`` (n, k), ``lin`` (n, m) out.

    NaN in ``e`` (missing y): the filtered samples that reach one are left out.
    """
    a = _ar(e - np.nanmean(e), ORDER)
    ew, Xw, Lw = (_filtered(a, v) for v in (e[:, None], X, lin))
    keep = np.isfinite(ew[:, 0])
    if keep.sum() < 16 * SMOOTH:
        return None
    # the nuisances projected out of both (Frisch-Waugh), their span by SVD (P's free
    # responses are near one another where it integrates)
    Lk = np.column_stack([Lw[keep], np.ones(int(keep.sum()))])
    U, sv, _ = np.linalg.svd(Lk, full_matrices=False)
    U = U[:, sv > 1e-9 * sv[0]]
    ek = ew[keep, 0] - U @ (U.T @ ew[keep, 0])
    Xk = Xw[keep] - U @ (U.T @ Xw[keep])
    Q, R = np.linalg.qr(Xk)
    if np.min(np.abs(np.diag(R))) < 1e-10 * np.max(np.abs(np.diag(R))):
        return None
    coef = np.linalg.solve(R, Q.T @ ek)
    res = ek - Xk @ coef
    Rinv = np.linalg.inv(R)
    lev = np.einsum("ij,ij->i", Q, Q) + np.einsum("ij,ij->i", U, U)  # He3's heavy tail
    G = np.zeros((keep.size, Q.shape[1]))  # HC3 scores on the time axis, 0 where left out
    G[keep] = Q * (res / np.maximum(1.0 - lev, 0.05))[:, None]
    meat = G.T @ G
    for lag in range(1, hac_lags(F) + 1):  # Newey-West: what whitening left, cyclic too
        c = G[lag:].T @ G[:-lag]
        meat += (1.0 - lag / (hac_lags(F) + 1)) * (c + c.T)
    cov = Rinv @ meat @ Rinv.T
    seen = np.isfinite(e)
    Xc = X[seen] - X[seen].mean(axis=0)
    fitted = Xc @ coef
    rest = float(np.sum((e[seen] - e[seen].mean() - fitted) ** 2))
    return _Output(coef, cov, float(np.sum(fitted**2)), rest, int(seen.sum()))


def correlation(
    model: Model, rec: LoopData, start: int, pred: Prediction, *, alpha: float
) -> Correlation | None:
    """The test of the module docstring on ``rec`` from sample ``start`` on.

    ``pred``: ``model``'s prediction on ``rec``. None for periodic records or too few
    samples left (:data:`SMOOTH`).
    """
    if rec.period is not None:
        return None
    N, F, n_u, n_y = rec.n_samples, model.ratio, model.n_u, model.n_y
    err = output_error(model, rec)  # y - P u - (P's free responses): the noise itself
    if err is None or err.y.shape[0] != N or N - start < 16 * SMOOTH:
        return None
    s = start
    plant = replace(model, controller=None, disturbances=())
    through_p = []  # per input and kind (input-major), (N, n_y): He(z_i) through P[:, i]
    for i in range(n_u):
        for g in _hermite(pred.u[:, i], s):
            drive = np.zeros((N, n_u))
            drive[:, i] = g
            with warnings.catch_warnings():  # an integrator's Jordan block: the recursion
                warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
                through_p.append(LoopStream(plant).next(drive)[1])
    free = free_response(model.plant_discrete(), N)
    names = [f"input{i if n_u > 1 else ''}_{k}" for i in range(n_u) for k in KINDS]
    names += [f"output_{k}" for k in KINDS]
    outs = []
    for o in range(n_y):
        X = np.column_stack([x[:, o] for x in through_p] + list(_hermite(pred.y[:, o], s)))
        lags = [np.roll(pred.y[:, o], j) for j in range(LAGS)]
        fit = _fit(err.y[s:, o], X[s:], np.column_stack([*lags, free[:, o, :]])[s:], F)
        if fit is None:
            return None
        outs.append(fit)
    k = 2 * n_u + 2
    odd, even = list(range(1, k, 2)), list(range(0, k, 2))
    groups = (odd, even, list(range(2 * n_u)), [k - 2, k - 1])

    def bonferroni(p: float) -> float:
        return min(1.0, n_y * p)

    ps = [_p(f.beta, f.V, list(range(k))) for f in outs]
    best = int(np.argmin(ps))
    b = outs[best]
    stat = float(b.beta @ np.linalg.solve(b.V, b.beta)) if ps[best] < 1.0 else 0.0
    sub = [bonferroni(min(_p(f.beta, f.V, g) for f in outs)) for g in groups]
    count = sum(f.samples for f in outs)
    sd = np.sqrt(np.maximum(np.diag(b.V), 1e-300))
    out_names = names if n_y == 1 else [f"{x}@y{best}" for x in names]
    return Correlation(
        statistic=stat,
        p=bonferroni(ps[best]),
        alpha=alpha,
        z=tuple(float(v) for v in b.beta / sd),
        odd_p=sub[0],
        even_p=sub[1],
        input_p=sub[2],
        output_p=sub[3],
        level_db=10.0 * math.log10(1.0 + max(f.fitted / max(f.rest, 1e-300) for f in outs)),
        samples=count // n_y,
        rest_vars=tuple(f.rest / max(f.samples, 1) for f in outs),
        fitted_vars=tuple(f.fitted / max(f.samples, 1) for f in outs),
        names=tuple(out_names),
    )
