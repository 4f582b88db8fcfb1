# SPDX-License-Identifier: Apache-2.0
"""Equivalent explanations: other causes the data cannot tell apart from a chosen one.

Some effects look alike over the band a record excites: a pure input delay of 4.6 ms and
a first-order low-pass at 34.6 Hz bend the phase the same way below 20 Hz; a shallow wide
notch low in the loop and a control delay (on y alone: where the logged u is the
controller's output, its own equation tells them apart,
:mod:`~mr_ident.diagnosis.controller.relation`); an additive mode at a one-mode plant's own
mode and a gain change. The selection (:mod:`~mr_ident.diagnosis.selection.forward`) keeps
one of them (within its margin, the one with fewest values); a user should know that the
others explain the data as well, so that the next experiment (a wider band, a longer
record) can decide, and so that a named cause is not read as more certain than it is.

For each chosen cause, the other applicable causes are fitted in its place (on top of the
rest, then every continuous value re-fitted jointly:
:func:`~mr_ident.diagnosis.selection.forward.swap`). One whose BIC comes within
:data:`~mr_ident.diagnosis.selection.forward.ACCEPT_MARGIN` of the chosen set's is an
*equivalent*: the evidence between the two is less than the evidence the selection demands
for a cause at all. Its values are re-fitted on the whole estimation record and given their
standard deviations.

Fitting every cause in every place would double a diagnosis's time, so the candidates
are first screened by the ranking (each cause alone on the nominal model): a look-alike
of a chosen cause explains, alone, about what the chosen cause explains alone, so only
causes whose single BIC is within :data:`SCREEN_SLACK` of the chosen cause's are tried.
"""

from __future__ import annotations

import math
from dataclasses import replace

from ...numerics.systems.model import Model
from ..causes.cause import CauseFit, Equivalent, PlantData
from ..causes.registry import CAUSES
from ..criterion.objective import Objective
from .fitting import joint_refit, parameter_std
from .forward import ACCEPT_MARGIN, swap

#: Candidates tried in a chosen cause's place: single BIC (the ranking) within this of its.
SCREEN_SLACK = 3 * ACCEPT_MARGIN


def with_equivalents(
    obj: Objective,
    screen: Objective,
    nominal: Model,
    plant: PlantData | None,
    chosen: list[CauseFit],
    ranking: list[CauseFit],
) -> list[CauseFit]:
    """``chosen`` (from :func:`~mr_ident.diagnosis.selection.forward.select`) with equivalents.

    Each one's :attr:`~mr_ident.diagnosis.causes.cause.CauseFit.equivalents` is filled in.

    ``obj``: the whole estimation record (the BIC); ``screen``: its screening part (the
    fits); ``ranking``: every cause alone on the nominal (the screen of candidates). The
    chosen set's BIC is the last fit's score.
    """
    if not chosen or any(c.choice is None for c in chosen):
        return chosen
    choices = [c.choice for c in chosen if c.choice is not None]
    bic = chosen[-1].score
    alone = {c.cause: c.score for c in ranking if c.applicable}
    out = []
    for j, fit in enumerate(chosen):
        others = {c.cause for i, c in enumerate(choices) if i != j}
        found: list[Equivalent] = []
        near = alone.get(fit.cause, math.inf) + SCREEN_SLACK
        for name, score in alone.items():
            k = CAUSES.get(name)
            if k is None or name == fit.cause or name in others or not score < near:
                continue
            got = swap(obj, screen, nominal, plant, choices, j, cause=k)
            if got is None or not got[0] < bic + ACCEPT_MARGIN:
                continue
            trial, cost = got[1], got[2]
            if screen is not obj:  # its values from all of the estimation data
                trial, cost = joint_refit(obj, nominal, trial, max_nfev=15)
            params = k.named(trial[j], nominal)
            found.append(
                Equivalent(
                    k.name,
                    params,
                    parameter_std(obj, nominal, trial)[j],
                    k.describe(params),
                    obj.bic(cost, sum(CAUSES[c.cause].n_free for c in trial)) - bic,
                )
            )
        out.append(replace(fit, equivalents=tuple(sorted(found, key=lambda e: e.delta_bic))))
    return out
