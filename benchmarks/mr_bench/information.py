# SPDX-License-Identifier: Apache-2.0
"""What a record can determine of the hidden causes, before any diagnosis answers.

:func:`truth_std` is the Cramér-Rao bound of the hidden values at the truth on a
diagnosis's criterion; :func:`determinable` says whether that bound is within the
benchmark's tolerances (:data:`~mr_bench.verdict.TOLERANCES`) at all. A miss
on a case the record does not determine is the record's, whoever the estimator; the
success rate among the determinable cases is what a diagnosis can be asked for.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from mr_ident.diagnosis.causes.registry import CAUSES
from mr_ident.diagnosis.controller.relation import EXACT, Equation, value_std
from mr_ident.diagnosis.criterion.objective import Objective
from mr_ident.numerics.arrays import FloatArray
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.model import Model

from .scenarios import HiddenCause, apply
from .verdict import TOLERANCES

#: A record determines a parameter when its tolerance is at least this many Cramér-Rao
#: standard deviations at the truth (:func:`determinable`).
DETERMINED = 3.0


def truth_std(
    nominal: Model,
    hidden: Sequence[HiddenCause],
    criterion: Objective,
    record: LoopData | None = None,
) -> list[dict[str, float]]:
    """Cramér-Rao standard deviation of every hidden continuous parameter, at the truth.

    The truth is ``nominal`` with ``hidden`` (a scenario's causes) applied.
    On ``criterion`` (a diagnosis's :class:`~mr_ident.diagnosis.criterion.objective.Objective`:
    whitened residual components of variance 1/2 under the true model), the Fisher
    information of the hidden values jointly is ``2 JᵀJ``, J the residual's Jacobian by
    forward differences at the truth (:meth:`~mr_ident.diagnosis.criterion.objective.Objective.
    gauss_newton`, step 1e-4 of the value).
    What any unbiased estimator's spread is at least on this record, known before the
    diagnosis answers. Per hidden cause, by parameter name (discrete ones absent); inf
    where the record holds no information on a value.

    With the ``record`` (closed loop, y at the high rate) the controller's own equation
    counts too (:mod:`~mr_ident.diagnosis.controller.relation`): where the truth satisfies
    it to :data:`~mr_ident.diagnosis.controller.relation.EXACT`, the controller-side
    values are fixed by it (their std is its Gauss-Newton std, at rounding level) and the
    others' bound is taken with those known.
    """
    hidden = list(hidden)
    out: list[dict[str, float]] = [{} for _ in hidden]
    settled: set[int] = set()
    if record is not None and nominal.controller is not None and record.y_step == 1:
        true = apply(nominal, hidden)
        eq = Equation(record, nominal)
        if eq.error(true) <= EXACT:
            for j, h in enumerate(hidden):
                if CAUSES[h.cause].controller_side:
                    settled.add(j)
                    out[j] = _equation_std(eq, nominal, hidden, j)
    names = [
        (j, k) for j, h in enumerate(hidden) if j not in settled for k in _continuous(h.cause)
    ]
    if not names:
        return out

    def model_at(j: int, key: str, value: float) -> Model:
        moved = list(hidden)
        moved[j] = hidden[j].with_values({key: value})
        return apply(nominal, moved)

    steps = [1e-4 * (abs(hidden[j].parameters[key]) or 1.0) for j, key in names]
    cov, weak = criterion.gauss_newton(
        apply(nominal, hidden),
        (
            (model_at(j, key, hidden[j].parameters[key] + h), h)
            for (j, key), h in zip(names, steps, strict=True)
        ),
    )
    for i, (j, key) in enumerate(names):
        var = float(cov[i, i])
        out[j][key] = math.inf if weak[i] or not var >= 0 else math.sqrt(var)
    return out


def _equation_std(
    eq: Equation, nominal: Model, hidden: list[HiddenCause], j: int
) -> dict[str, float]:
    """The std of hidden cause ``j``'s continuous values on the controller's equation."""
    keys = _continuous(hidden[j].cause)
    if not keys:
        return {}

    def model_at(v: FloatArray) -> Model:
        moved = list(hidden)
        moved[j] = hidden[j].with_values(dict(zip(keys, map(float, v), strict=True)))
        return apply(nominal, moved)

    sd = value_std(eq, model_at, [hidden[j].parameters[k] for k in keys])
    return {k: float(v) for k, v in zip(keys, sd, strict=True)}


def determinable(
    hidden: Sequence[HiddenCause], stds: Sequence[Mapping[str, float]], fs_high: float
) -> bool:
    """Whether the record determines every hidden continuous parameter to its tolerance.

    Each tolerance at least :data:`DETERMINED` of the parameter's :func:`truth_std`: an
    efficient estimator then lands within it in 99.7 % of records. A case that is not
    determinable asks for more than the record holds, whoever the estimator.
    """
    for h, sd in zip(hidden, stds, strict=True):
        for key, s in sd.items():
            zeta = float(h.parameters.get("damping", 0.0))
            tol = TOLERANCES[h.cause][key].bound(h.parameters[key], fs_high, zeta)
            if not DETERMINED * s <= tol:
                return False
    return True


def _continuous(cause: str) -> list[str]:
    """The hidden cause's parameters with a tolerance that is not exact."""
    return [k for k, t in TOLERANCES.get(cause, {}).items() if t.kind != "exact"]
