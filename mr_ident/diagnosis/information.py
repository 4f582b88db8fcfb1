"""What a record can determine of the hidden causes, before any diagnosis answers.

:func:`truth_std` is the Cramér-Rao bound of the hidden values at the truth on a
diagnosis's criterion; :func:`determinable` says whether that bound is within the
benchmark's tolerances (:data:`~mr_ident.diagnosis.verdict.TOLERANCES`) at all. A miss
on a case the record does not determine is the record's, whoever the estimator; the
success rate among the determinable cases is what a diagnosis can be asked for.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from ..numerics.model import Model
from .objective import Objective
from .scenarios import HiddenCause, apply
from .verdict import TOLERANCES

#: A record determines a parameter when its tolerance is at least this many Cramér-Rao
#: standard deviations at the truth (:func:`determinable`).
DETERMINED = 3.0


def truth_std(
    nominal: Model, hidden: Sequence[HiddenCause], criterion: Objective
) -> list[dict[str, float]]:
    """Cramér-Rao standard deviation of every hidden continuous parameter, at the truth.

    The truth is ``nominal`` with ``hidden`` (a scenario's causes) applied.
    On ``criterion`` (a diagnosis's :class:`~mr_ident.diagnosis.objective.Objective`:
    whitened residual components of variance 1/2 under the true model), the Fisher
    information of the hidden values jointly is ``2 JᵀJ``, J the residual's Jacobian by
    forward differences at the truth (:meth:`~mr_ident.diagnosis.objective.Objective.
    gauss_newton`, step 1e-4 of the value).
    What any unbiased estimator's spread is at least on this record, known before the
    diagnosis answers. Per hidden cause, by parameter name (discrete ones absent); inf
    where the record holds no information on a value.
    """
    hidden = list(hidden)
    names = [(j, k) for j, h in enumerate(hidden) for k in _continuous(h.cause)]
    out: list[dict[str, float]] = [{} for _ in hidden]
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
            tol = TOLERANCES[h.cause][key].bound(h.parameters[key], fs_high)
            if not DETERMINED * s <= tol:
                return False
    return True


def _continuous(cause: str) -> list[str]:
    """The hidden cause's parameters with a tolerance that is not exact."""
    return [k for k, t in TOLERANCES.get(cause, {}).items() if t.kind != "exact"]
