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
model's plant P. For Gaussian r, z is Gaussian and ``E{He_n(z) w} = 0`` for every w
linear in r and n >= 2 (Isserlis): a *linear* model error leaves the coefficients at 0
in expectation; only a nonlinear one moves them. The test asks r to be Gaussian-like
(white or filtered noise, a random-phase multisine of many lines); it is run on records
that are not periodic (periodic ones have the tests above), SISO, complete.

**The test.** From the validation start on: ``e = X β + L γ + c + w``, four columns X,
and as nuisances L the model's ŷ at lags 0..:data:`LAGS`-1 (a linear error of the
model), P's free responses and a constant. The noise's own colour is taken out by an
autoregressive filter ``A(q)`` of order :data:`ORDER` fitted to e by least squares and
applied to e, X and L alike (prewhitening); the nuisances projected out of both
(Frisch-Waugh); least squares, and the coefficients' covariance by the
heteroscedasticity-robust sandwich with each sample's residual over one less its
leverage (HC3: He₃'s heavy tail puts weight on few samples) and the Newey-West sum over
:func:`hac_lags` lags (what the filter left, a multirate loop's periodic statistics).
Under the null the Wald statistic ``β^T V⁻¹ β`` is χ²(4); nonlinear distortion is found
at ``p <`` :data:`HOS_ALPHA`. The kind is named by the sub-tests of the odd and even
pairs and of the input and output pairs (each at the same level, the pair's χ²(2) within
the joint fit); where both or neither pass, that part of the kind is not named. Its
level: the fitted part's power over the rest, ``10 log10(1 + ‖Xβ‖² / ‖e - Xβ‖²)`` dB;
the rest's variance bounds the output noise's from above (:mod:`.unexplained` takes it
where it is below the LPM's level, which under random r holds the distortion).
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
from .prediction import Prediction, centred

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
#: The regressors, in the order of the columns: (side, kind).
COLUMNS: tuple[tuple[str, str], ...] = (
    ("input", "even"),
    ("input", "odd"),
    ("output", "even"),
    ("output", "odd"),
)


@dataclass(frozen=True)
class Correlation:
    """The residual's higher-order correlations with the model's signals.

    Attributes
    ----------
    statistic : float
        Wald statistic of the four coefficients, χ²(4) under the null.
    p : float
    alpha : float
        The level.
    z : tuple of float
        Each coefficient over its std (the order of :data:`COLUMNS`).
    odd_p, even_p, input_p, output_p : float
        The pairs' sub-tests (χ²(2)).
    level_db : float
        The fitted part's power over the rest, dB above it.
    samples : int
    rest_var : float
        The output error's variance per sample with the fitted part taken out: an upper
        bound of the output noise's where the distortion is found (the LPM's noise level
        holds a random excitation's distortion, so :mod:`.unexplained` takes the smaller,
        shaped by the loop as the noise in y is: :func:`~.unexplained.loop_shaped`).
    fitted_var : float
        The fitted part's variance per sample: a lower bound of the distortion's (what
        the regressors do not span of it stays in the rest).
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
    rest_var: float = math.nan
    fitted_var: float = math.nan

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
            "z": dict(zip([f"{s}_{k}" for s, k in COLUMNS], self.z, strict=True)),
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
    """The AR polynomial ``[1, -a_1, ..., -a_p]`` that whitens ``e``, by least squares."""
    n = e.size
    lagged = np.column_stack([e[order - i - 1 : n - i - 1] for i in range(order)])
    a = np.linalg.lstsq(lagged, e[order:], rcond=None)[0]
    return np.concatenate([[1.0], -a])


def _filtered(a: FloatArray, x: FloatArray) -> FloatArray:
    """``A(q) x`` per column, the first ``len(a) - 1`` samples dropped."""
    p = a.size - 1
    out = x[p:].copy()
    for i in range(1, p + 1):
        out += a[i] * x[p - i : x.shape[0] - i]
    return out


def _sub(beta: FloatArray, V: FloatArray, idx: list[int]) -> float:
    b, v = beta[idx], V[np.ix_(idx, idx)]
    try:
        w = float(b @ np.linalg.solve(v, b))
    except np.linalg.LinAlgError:
        return 1.0
    return float(scipy.stats.chi2.sf(w, len(idx)))


def correlation(
    model: Model, rec: LoopData, start: int, pred: Prediction, *, alpha: float
) -> Correlation | None:
    """The test of the module docstring on ``rec`` from sample ``start`` on.

    ``pred``: ``model``'s prediction on ``rec``. None for periodic or multichannel records,
    records with missing samples, or too few samples left.
    """
    if rec.period is not None or model.n_u != 1 or model.n_y != 1:
        return None
    _, _, y = centred(rec, model)
    if np.isnan(y).any() or np.isnan(rec.u).any():
        return None
    N, F = rec.n_samples, model.ratio
    err = output_error(model, rec)  # y - P u - (P's free responses): the noise itself
    if err is None or N - start < 16 * SMOOTH:
        return None
    s = start
    plant = replace(model, controller=None, disturbances=())
    cols = []
    for g in _hermite(pred.u[:, 0], s):  # at the plant's input: through P
        with warnings.catch_warnings():  # an integrator's Jordan block: the direct recursion
            warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
            _, x = LoopStream(plant).next(g[:, None])
        cols.append(x[:, 0])
    cols += list(_hermite(pred.y[:, 0], s))  # at its output: as they are
    free = free_response(model.plant_discrete(), N)[:, 0, :]
    X = np.column_stack(cols)[s:]
    e = err.y[s:, 0]
    lin = np.column_stack([np.roll(pred.y[:, 0], j) for j in range(LAGS)] + [free])[s:]
    a = _ar(e - e.mean(), ORDER)
    ew, Xw, Lw = (_filtered(a, v) for v in (e[:, None], X, lin))
    # the nuisances projected out of both (Frisch-Waugh), their span by SVD (P's free
    # responses are near one another where it integrates)
    U, sv, _ = np.linalg.svd(np.column_stack([Lw, np.ones(Lw.shape[0])]), full_matrices=False)
    U = U[:, sv > 1e-9 * sv[0]]
    ew = ew - U @ (U.T @ ew)
    Xw = Xw - U @ (U.T @ Xw)
    Q, R = np.linalg.qr(Xw)
    if np.min(np.abs(np.diag(R))) < 1e-10 * np.max(np.abs(np.diag(R))):
        return None
    coef = np.linalg.solve(R, Q.T @ ew[:, 0])
    res = ew[:, 0] - Xw @ coef
    Rinv = np.linalg.inv(R)
    lev = np.einsum("ij,ij->i", Q, Q) + np.einsum("ij,ij->i", U, U)  # He3's heavy tail
    G = Q * (res / np.maximum(1.0 - lev, 0.05))[:, None]  # HC3 scores
    meat = G.T @ G
    for lag in range(1, hac_lags(F) + 1):  # Newey-West: what whitening left, cyclic too
        c = G[lag:].T @ G[:-lag]
        meat += (1.0 - lag / (hac_lags(F) + 1)) * (c + c.T)
    cov = Rinv @ meat @ Rinv.T
    beta, V = coef[:4], cov[:4, :4]
    try:
        stat = float(beta @ np.linalg.solve(V, beta))
    except np.linalg.LinAlgError:
        return None
    X = X - X.mean(axis=0)
    e = e - e.mean()
    fitted = X @ beta
    rest = float(np.sum((e - fitted) ** 2))
    level = 10.0 * math.log10(1.0 + float(np.sum(fitted**2)) / max(rest, 1e-300))
    sd = np.sqrt(np.maximum(np.diag(V), 1e-300))
    return Correlation(
        stat,
        float(scipy.stats.chi2.sf(stat, 4)),
        alpha,
        tuple(float(v) for v in beta / sd),
        _sub(beta, V, [1, 3]),
        _sub(beta, V, [0, 2]),
        _sub(beta, V, [0, 1]),
        _sub(beta, V, [2, 3]),
        level,
        N - s,
        rest / e.size,
        float(np.sum(fitted**2)) / e.size,
    )
