# SPDX-License-Identifier: Apache-2.0
"""Validation decides: an extension is applied only where the validation data confirm it.

The causes are found and fitted on the estimation data (:mod:`.forward`); there every
extra value lowers the residual, and an effect that belongs to *that* record only (the
nonlinear distortion of one excitation realization, which a periodic disturbance or an
extra mode can imitate on its lines) is accepted like a real one. So the extension is
held, with its values fixed, against data it was not fitted on (``--validate`` or the
held-out part), on the same criterion: the whitened residual spectrum ``e(k)`` of y - ŷ
(:class:`~mr_ident.diagnosis.criterion.objective.Objective` built on the validation data,
its noise from those data alone), ``C = sum_k |e(k)|²``, ``-2 log L = 2 C``.

**The test.** Two fixed models A (without) and B (with the extension): residuals
``e_A = w + δ_A``, ``e_B = w + δ_B`` with w the part no model explains. Their difference
``d = e_A - e_B`` holds no noise (both are simulated on the same measured r), so

    G = C_A - C_B = |δ_A|² - |δ_B|² + 2 Re sum_k conj(w_k) d_k,

and under the null "B predicts these data no better than A" (``|δ_A|² <= |δ_B|²``) the
noise enters G only along d, with variance ``2 sum_k |d_k|² s_k`` (``s_k = E|w_k|²``,
1 where the noise spectrum is right). ``s`` is taken as the level of B's residual where
the two differ, ``ŝ = sum_k |d_k|² |e_B(k)|² / sum_k |d_k|²``, at least 1: what the
noise spectrum misses (distortion on lines a design excites all of) then counts as
noise, and a B fitted to the estimation record's distortion meets its own misfit there.
The statistic ``z = G / sqrt(2 ŝ sum_k |d_k|²)`` is N(0, 1) at the null's boundary
(Gaussian w; many bins or a Gaussian sum); the gain is **significant** when
``z > z_{1-alpha}`` (alpha the diagnosis's level, 0.01 by default: an extension that
explains nothing new passes with probability at most 1 %). A gain concentrated on one
line (a disturbance) is judged as surely as one spread over the band, since ``d`` is
known, not estimated.

**The decision.** Backward from the candidates (the causes the estimation data chose,
jointly fitted): each cause is tested by the set without it against the set with it; a
cause fails where its gain is not significant or the set with it fits y worse on the
validation data (fit %) than the set without it; the failing one of least z is rejected
and the rest re-tested, until no remaining cause fails. The remaining set is then tested
against the nominal model the same way (significant, and not lowering the fit of y);
otherwise no extension is validated and the nominal model stands. The values are not
re-fitted.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.stats

from ...numerics.systems.model import Model
from ..causes.cause import CauseFit
from ..causes.registry import build
from ..criterion.objective import Objective
from ..criterion.prediction import TimeFit

#: The test in words (the JSON report's ``validation.statistic``).
STATISTIC = (
    "z = (C_without - C_with) / sqrt(2 s sum_k |e_without(k) - e_with(k)|^2), C = sum_k "
    "|e(k)|^2 of the whitened residual spectrum of y on the validation data, s the level of "
    "the residual with the extension where the two differ (at least 1); significant when "
    "z > z_(1 - alpha)"
)


@dataclass(frozen=True)
class Gain:
    """One model against another on the validation data.

    Attributes
    ----------
    z : float
        The statistic of the module docstring (inf where the two models do not differ on
        these data but one cannot be simulated; 0 where they are the same).
    likelihood : float
        ``-2 log L`` of the model without, less that of the model with: ``2 G``.
    level : float
        ``ŝ``, the residual's level where the two differ, relative to the noise's.
    """

    z: float
    likelihood: float
    level: float


def _bins(res: np.ndarray) -> np.ndarray:
    """Complex residual per bin (and channel) from the criterion's real vector."""
    half = res.size // 2
    return res[:half] + 1j * res[half:]


def gain(obj: Objective, without: Model, with_: Model) -> Gain:
    """How much better ``with_`` predicts ``obj``'s record than ``without`` (docstring)."""
    ea, eb = _bins(obj.residuals(without)), _bins(obj.residuals(with_))
    d2 = np.abs(ea - eb) ** 2
    G = float(np.sum(np.abs(ea) ** 2) - np.sum(np.abs(eb) ** 2))
    total = float(np.sum(d2))
    if not total > 0.0:
        return Gain(0.0, 0.0, 1.0)
    level = max(1.0, float(np.sum(d2 * np.abs(eb) ** 2)) / total)
    return Gain(G / math.sqrt(2.0 * level * total), 2.0 * G, level)


def later(model: Model, start: int) -> Model:
    """``model`` with its time axis starting at sample ``start`` (its disturbances' phases)."""
    if not start or not model.disturbances:
        return model
    w = 2.0 * math.pi * start / model.fs_high
    return replace(
        model, disturbances=tuple((f, a, ph + w * f, o) for f, a, ph, o in model.disturbances)
    )


def critical(alpha: float) -> float:
    """``z_{1-alpha}``: the one-sided standard normal quantile."""
    return float(scipy.stats.norm.isf(alpha))


@dataclass(frozen=True)
class CauseCheck:
    """One candidate cause held against the validation data.

    Attributes
    ----------
    cause, description : str
        As found on the estimation data.
    parameters : dict
    gain : Gain
        The set (of the causes still in when it was tested) without it, against the set
        with it.
    fit_with, fit_without : float
        Fit % of y on the validation data of those two models.
    validated : bool
    """

    cause: str
    description: str
    parameters: dict[str, float]
    gain: Gain
    fit_with: float
    fit_without: float
    validated: bool


@dataclass(frozen=True)
class Validation:
    """What the validation data decided (module docstring).

    Attributes
    ----------
    alpha, z_critical : float
        Level of the test and its critical value.
    candidates : list of CauseFit
        The causes the estimation data chose, jointly fitted, in the order found.
    checks : list of CauseCheck
        One per candidate, in the same order.
    gain : Gain
        The validated set (or, when none is left, every candidate) against the nominal model.
    fit_candidates : TimeFit
        Fit % on the validation data of the nominal model with every candidate.
    validated : bool
        Some extension is validated (the applied causes are :attr:`applied`).
    """

    alpha: float
    z_critical: float
    candidates: list[CauseFit]
    checks: list[CauseCheck]
    gain: Gain
    fit_candidates: TimeFit
    validated: bool
    statistic: str = field(default=STATISTIC, repr=False)

    @property
    def applied(self) -> list[CauseFit]:
        """The candidates the validation data confirm (none unless :attr:`validated`)."""
        return [c for c, k in zip(self.candidates, self.checks, strict=True) if k.validated]

    @property
    def rejected(self) -> list[CauseCheck]:
        """The candidates the estimation data accepted and the validation data did not."""
        return [k for k in self.checks if not k.validated]

    def text(self, corrected: bool = False) -> str:
        """The decision in words.

        ``corrected``: a correction beyond the listed causes validated
        (:mod:`~mr_ident.diagnosis.selection.correction`), the only extension then.
        """
        if not self.candidates:
            return ""
        names = ", ".join(c.cause for c in self.candidates)
        if not self.validated:
            what, outcome = (
                ("no listed cause validated", "the correction is the only extension")
                if corrected
                else ("no extension validated", "the nominal model stands")
            )
            return (
                f"{what}: the candidates ({names}) fit the validation data "
                f"{self.fit_candidates.y:.1f} % (z = {self.gain.z:.2f}, needed > "
                f"{self.z_critical:.2f} at alpha = {self.alpha:g}); {outcome}"
            )
        if not self.rejected:
            return f"validated: {names} (z = {self.gain.z:.2f} > {self.z_critical:.2f})"
        out = ", ".join(k.cause for k in self.rejected)
        return (
            f"validated: {', '.join(c.cause for c in self.applied)} (z = {self.gain.z:.2f}); "
            f"rejected on the validation data: {out}"
        )


def decide(
    objective: Callable[[], Objective],
    nominal: Model,
    candidates: list[CauseFit],
    fit_of: Callable[[Model], TimeFit],
    *,
    alpha: float = 0.01,
    start: int = 0,
) -> Validation:
    """Which of ``candidates`` the validation record confirms (module docstring).

    ``objective``: builds the criterion on the validation record (called only when there
    are candidates); ``fit_of``: the fit % of a model on the validation data (the caller's
    :func:`~mr_ident.diagnosis.criterion.prediction.time_fit` with its start); ``start``:
    the sample of the models' time axis where ``obj``'s record begins (the held-out part
    of the estimation record: its cut), for the phase of a fitted disturbance.
    """
    z_crit = critical(alpha)
    if not candidates:
        return Validation(alpha, z_crit, [], [], Gain(0.0, 0.0, 1.0), fit_of(nominal), False)
    obj = objective()
    choices = [c.choice for c in candidates]
    if any(c is None for c in choices):
        raise ValueError("every candidate needs its choice (the fitted values)")

    @functools.cache
    def model(idx: tuple[int, ...]) -> Model:
        return build(nominal, [choices[i] for i in idx])  # type: ignore[misc]

    @functools.cache
    def fit(idx: tuple[int, ...]) -> TimeFit:
        return fit_of(model(idx))

    @functools.cache
    def seen(idx: tuple[int, ...]) -> Model:
        return later(model(idx), start)

    kept = tuple(range(len(candidates)))
    tested: dict[int, tuple[Gain, tuple[int, ...], tuple[int, ...]]] = {}
    while kept:
        trials = {}
        for j in kept:
            without = tuple(i for i in kept if i != j)
            trials[j] = (gain(obj, seen(without), seen(kept)), without, kept)
        tested.update(trials)  # each cause's test in the last set it was part of
        failing = [
            j for j in kept if not trials[j][0].z > z_crit or fit(kept).y < fit(trials[j][1]).y
        ]
        if not failing:
            break
        worst = min(failing, key=lambda j: trials[j][0].z)
        kept = tuple(i for i in kept if i != worst)
    every = tuple(range(len(candidates)))
    overall = gain(obj, seen(()), seen(kept or every))
    validated = bool(kept) and overall.z > z_crit and fit(kept).y >= fit(()).y
    checks = [
        CauseCheck(
            c.cause,
            c.description,
            dict(c.parameters),
            tested[j][0],
            fit(tested[j][2]).y,
            fit(tested[j][1]).y,
            j in kept and validated,
        )
        for j, c in enumerate(candidates)
    ]
    return Validation(alpha, z_crit, list(candidates), checks, overall, fit(every), validated)
