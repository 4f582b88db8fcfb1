"""The criterion every cause is fitted and ranked by: whitened residuals and the BIC."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np
import scipy.optimize

from ..errors import DataError
from ..numerics.arrays import ComplexArray, FloatArray
from ..numerics.model import Model
from ..numerics.signals import LoopData
from .prediction import centred, predict


class Objective:
    """Whitened residuals of a model family on the estimation record.

    The spectrum ``E(k)`` of y - ŷ (``rfft``, orthonormal) is divided by the noise std
    of :func:`~mr_ident.diagnosis.noise.noise_spectrum`, so that the bins are independent
    with unit variance when
    the model is right: least squares is then efficient and
    ``-2 log L = 2 sum |E|^2 / S`` enters the BIC with the number of bins as the sample
    size. Only y - ŷ enters: in closed loop u - û is the same noise filtered by the loop
    (one noise source), so counting it too would double the evidence, noise included.
    """

    def __init__(
        self,
        rec: LoopData,
        base: Model,
        noise: FloatArray,
        plant: tuple[FloatArray, ComplexArray] | None = None,
    ):
        self.rec = rec
        self.base = base
        self.plant = plant  # (frequency, P̂) of the record, for starting guesses
        _, u, y = centred(rec, base)
        self.u, self.y = u, y
        self.skip = rec.period or 0
        self.closed = base.controller is not None
        if self._raw(base) is None:
            raise DataError("the model cannot be simulated on this data (the loop is not stable)")
        self.weight = 1.0 / np.sqrt(noise)
        self.n_bins = int(self.weight.size)

    def _raw(self, model: Model) -> list[FloatArray] | None:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # unstable or defective candidates are rejected
            try:
                pred = predict(model, self.rec)
            except (ArithmeticError, ValueError, Warning, np.linalg.LinAlgError):
                return None  # any warning, a library's own (scipy's BadCoefficients) included
        s = self.skip
        parts = [self.y[s:] - pred.y[s:], self.u[s:] - pred.u[s:]]
        if not all(np.all(np.isfinite(p_)) for p_ in parts):
            return None
        return parts

    def residuals(self, model: Model) -> FloatArray:
        """The whitened residual spectrum (real and imaginary parts) of ``model``."""
        return self._whiten(self._raw(model))

    def cost(self, model: Model) -> float:
        """Sum of squares of :meth:`residuals`."""
        with np.errstate(over="ignore"):
            return float(np.sum(self.residuals(model) ** 2))

    def _whiten(self, raw: list[FloatArray] | None) -> FloatArray:
        if raw is None:
            return np.full(2 * self.n_bins, 1e3)
        with np.errstate(all="ignore"):
            E = np.fft.rfft(raw[0], axis=0, norm="ortho") * self.weight
        res = np.concatenate([E.real.ravel(), E.imag.ravel()])
        ok = np.all(np.isfinite(res)) and float(np.max(np.abs(res), initial=0.0)) < 1e100
        return res if ok else np.full(2 * self.n_bins, 1e3)

    def evaluate(self, model: Model, p: int) -> tuple[float, dict[str, float]]:
        """BIC and residual sums of squares of ``model``, from one simulation.

        BIC ``2 sum |E|^2 / S + p ln(n_bins)``; the sums of squares of y (and u in closed loop).
        """
        raw = self._raw(model)
        bic = 2.0 * float(np.sum(self._whiten(raw) ** 2)) + p * math.log(self.n_bins)
        if raw is None:
            return bic, {"y": math.inf} | ({"u": math.inf} if self.closed else {})
        rss = {"y": float(np.sum(raw[0] ** 2))}
        if self.closed:
            rss["u"] = float(np.sum(raw[1] ** 2))
        return bic, rss


def least_squares(
    obj: Objective,
    build: Callable[[FloatArray], Model],
    starts: list[list[float]],
    lower: list[float],
    upper: list[float],
    scale: list[float],
) -> tuple[FloatArray, Model]:
    """Bounded least squares from several starts; the best end point and its model."""
    best: tuple[float, FloatArray, Model] | None = None
    for start in starts:
        x0 = np.clip(np.asarray(start, float), lower, upper)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                res = scipy.optimize.least_squares(
                    lambda x: obj.residuals(build(x)),
                    x0,
                    bounds=(lower, upper),
                    x_scale=np.asarray(scale, float),
                    max_nfev=100,
                    ftol=1e-10,
                    xtol=1e-10,
                    diff_step=1e-5,
                )
            except (ValueError, np.linalg.LinAlgError):  # a start where the loop is unstable
                continue
        cost = float(res.cost)
        if best is None or cost < best[0]:
            best = (cost, res.x, build(res.x))
    if best is None:
        first: FloatArray = np.clip(np.asarray(starts[0], float), lower, upper)
        return first, build(first)
    return best[1], best[2]


def best_starts(
    obj: Objective, build: Callable[[FloatArray], Model], starts: list[list[float]], keep: int
) -> list[list[float]]:
    """The ``keep`` starts with the smallest residual (a cheap grid before least squares)."""
    costs = [(obj.cost(build(np.asarray(x, float))), x) for x in starts]
    return [x for _, x in sorted(costs, key=lambda t: t[0])[:keep]] or starts[:1]
