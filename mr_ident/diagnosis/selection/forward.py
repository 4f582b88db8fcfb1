# SPDX-License-Identifier: Apache-2.0
"""Which causes, together: forward selection with joint re-fits and an information criterion.

The criterion is the BIC of the time-domain residual
(:class:`~mr_ident.diagnosis.criterion.objective.Objective`):
``BIC = 2 sum_k |E(k)|² / S(k) + p ln(n_bins)``, p the free parameters of every chosen
cause. Each step:

1. **Screen.** Every applicable cause is fitted on top of the causes chosen so far (their
   values fixed), on the screening part of the record (at most :data:`SCREEN_SAMPLES`
   samples, whole periods of a periodic record, at least 8): proposals from the
   identified plant or a grid, each scored, the best one refined by least squares;
   discrete causes (delays, offsets) are enumerated.
2. **Re-fit jointly.** The best :data:`JOINT_CANDIDATES` of the screen are each added to
   the chosen set and *all* continuous parameters re-fitted together (on the screening
   part), each trial then scored on the whole estimation record. At the second step the
   second cause is also sought on top of each of the first step's best
   :data:`PAIR_SINGLES` singles (a beam): two simple effects at once (a gain and a
   delay) can look like one flexible cause (a damped second-order lag), which the
   forward path alone would keep. Every discrete value in a trial is also tried at its
   neighbours.
3. **Stop or keep.** The best joint model is accepted when its BIC is lower than the
   current one's by more than :data:`ACCEPT_MARGIN` (among trials within that margin of
   the best, the one with the fewest parameters); otherwise the selection stops. After
   an acceptance every earlier cause is tried out of the set (the rest re-fitted): one
   whose removal does not raise the BIC by the margin explains nothing the others do not,
   and is dropped.

So two or three effects at once are found and applied together, and two causes that
explain the same thing are not both kept.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

from ...numerics.systems.model import Model
from ..causes.cause import Cause, CauseFit, Choice, Context, PlantData
from ..causes.registry import CAUSES, build
from ..criterion.objective import Objective
from .fitting import fit_single, joint_refit, parameter_std

#: Longest screening part of the record, in samples.
SCREEN_SAMPLES = 20_000
#: BIC decrease a further cause must bring: "very strong" evidence (Kass and Raftery, 1995).
#: The search tries many shapes, so a bare decrease would let noise through.
ACCEPT_MARGIN = 10.0
#: Screened causes re-fitted jointly on the whole estimation record at each step.
JOINT_CANDIDATES = 3
#: At the second step, the second cause is also sought on top of this many best singles.
PAIR_SINGLES = 3


@dataclass(frozen=True)
class Selection:
    """What the selection found.

    Attributes
    ----------
    chosen : list of CauseFit
        The causes kept, in the order found, with their jointly fitted values.
    ranking : list of CauseFit
        Every cause fitted alone on the nominal model, scored on the whole estimation
        record (lowest BIC first; inapplicable ones last).
    model : Model
        The nominal model with every kept cause.
    """

    chosen: list[CauseFit]
    ranking: list[CauseFit]
    model: Model


def _n_free(choices: list[Choice]) -> int:
    return sum(CAUSES[c.cause].n_free for c in choices)


def _fit(obj: Objective, nominal: Model, choices: list[Choice], score: float) -> CauseFit:
    """The CauseFit of the last of ``choices`` (with all of them in its model)."""
    c = choices[-1]
    cause = CAUSES[c.cause]
    params = cause.named(c, nominal)
    model = build(nominal, choices)
    _, rss = obj.evaluate(model, 0)
    return CauseFit(c.cause, params, score, rss, model, True, cause.describe(params), c)


def select(
    est_full: Objective,
    est_screen: Objective,
    nominal: Model,
    plant: PlantData | None,
    *,
    max_causes: int = 3,
    ruled_out: str | None = None,
) -> Selection:
    """Forward selection of causes (see the module docstring).

    ``ruled_out``: why the controller-side causes are not sought (the controller's own
    equation has settled them, :mod:`~mr_ident.diagnosis.controller.relation`); they are
    then listed in the ranking as not applicable, with this reason as their description.
    """
    excluded = (
        {c.name for c in CAUSES.values() if c.controller_side} if ruled_out is not None else set()
    )
    applicable = [c for c in CAUSES.values() if c.applies(nominal) and c.name not in excluded]

    def screen(chosen: list[Choice], among: list[str] | None = None) -> list[Choice]:
        ctx = Context(build(nominal, chosen), nominal, plant, est_screen)
        out: list[tuple[float, Choice]] = []
        for cause in applicable:
            if among is not None and cause.name not in among:
                continue
            if not cause.repeatable and any(ch.cause == cause.name for ch in chosen):
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got = fit_single(cause, ctx)
            if got is not None:
                out.append((est_screen.bic(got[1], cause.n_free), got[0]))
        return [ch for _, ch in sorted(out, key=lambda t: t[0])]

    def best_of(trials: list[list[Choice]]) -> tuple[float, list[Choice], float]:
        """The best trial; within ACCEPT_MARGIN of it, the one with fewest parameters."""
        fitted = []
        for trial0 in _with_neighbours(trials, nominal):
            trial, _ = joint_refit(est_screen, nominal, trial0)  # fitted on the screen part,
            cost = est_full.cost(build(nominal, trial))  # judged on the whole record
            fitted.append((est_full.bic(cost, _n_free(trial)), trial, cost))
        if not fitted:
            return math.inf, [], math.inf
        low = min(f[0] for f in fitted)
        near = [f for f in fitted if f[0] < low + ACCEPT_MARGIN]
        return min(near, key=lambda f: (_n_free(f[1]), f[0]))

    cur_cost = est_full.cost(nominal)
    cur_bic = est_full.bic(cur_cost, 0)
    accepted = 0  # steps taken
    chosen: list[Choice] = []
    singles = screen([])
    ranking = _ranking(est_full, nominal, singles)
    while len(chosen) < max_causes:
        if not chosen:
            trials = [[ch] for ch in singles[:JOINT_CANDIDATES]]
        elif accepted == 1:
            # two effects at once can look like one flexible cause (a gain and a delay like
            # a damped lag), which the forward path alone would keep: the second cause is
            # sought on top of each of the best singles (a beam)
            trials = [[chosen[0], b] for b in screen(chosen)[:JOINT_CANDIDATES]]
            trials += [
                [a, b]
                for a in singles[:PAIR_SINGLES]
                if a.cause != chosen[0].cause
                for b in screen([a])[:2]
            ]
        else:
            trials = [chosen + [ch] for ch in screen(chosen)[:JOINT_CANDIDATES]]
        bic, trial, cost = best_of(trials)
        if not bic < cur_bic - ACCEPT_MARGIN:
            break
        chosen, cur_cost, cur_bic = _prune(est_full, est_screen, nominal, trial, cost, bic)
        accepted += 1
    if chosen:
        chosen, cur_bic = _finished(
            est_full, est_screen, nominal, plant, applicable, chosen, cur_bic=cur_bic
        )
    stds = parameter_std(est_full, nominal, chosen)
    fits = [
        replace(_fit(est_full, nominal, chosen[: j + 1], cur_bic), std=stds[j])
        for j in range(len(chosen))
    ]
    inapplicable = _inapplicable(nominal, excluded, ruled_out)
    return Selection(fits, ranking + inapplicable, build(nominal, chosen))


def _finished(
    est_full: Objective,
    est_screen: Objective,
    nominal: Model,
    plant: PlantData | None,
    applicable: list[Cause],
    chosen: list[Choice],
    *,
    cur_bic: float,
) -> tuple[list[Choice], float]:
    """The selected causes simplified, pruned again, their values from the whole record.

    A cause replaced by a simpler one may leave the others' work to go
    (:func:`_prune` over every cause); with a screening part, the values are refitted on
    all of the estimation data. Returns the causes and their BIC.
    """
    simpler, cur_cost, cur_bic = _simplify(
        est_full, est_screen, nominal, plant, applicable, chosen, bic=cur_bic
    )
    if simpler != chosen:  # what a replaced cause had left to the others may go now
        simpler, cur_cost, cur_bic = _prune(
            est_full, est_screen, nominal, simpler, cur_cost, cur_bic, every=True
        )
    chosen = simpler
    if chosen and est_screen is not est_full:  # the values from all of the estimation data
        chosen, cur_cost = joint_refit(est_full, nominal, chosen)
        cur_bic = est_full.bic(cur_cost, _n_free(chosen))
    return chosen, cur_bic


def _inapplicable(nominal: Model, excluded: set[str], ruled_out: str | None) -> list[CauseFit]:
    """The causes not sought, for the ranking.

    Those that do not apply, and the excluded ones with ``ruled_out`` as their description.
    """
    return [
        CauseFit(
            c.name,
            {},
            math.inf,
            {},
            nominal,
            applicable=False,
            description=ruled_out if ruled_out and c.name in excluded else "",
        )
        for c in CAUSES.values()
        if not c.applies(nominal) or c.name in excluded
    ]


def _ranking(obj: Objective, nominal: Model, screened: list[Choice]) -> list[CauseFit]:
    """Each cause alone on the nominal, scored on the whole estimation record."""
    cost0 = obj.cost(nominal)
    out = [
        CauseFit(
            "none",
            {},
            obj.bic(cost0, 0),
            obj.evaluate(nominal, 0)[1],
            nominal,
            True,
            "the model explains the data within noise",
        )
    ]
    for ch in screened:
        cost = obj.cost(build(nominal, [ch]))
        out.append(_fit(obj, nominal, [ch], obj.bic(cost, CAUSES[ch.cause].n_free)))
    return sorted(out, key=lambda c: c.score)


def swap(
    obj: Objective,
    screen: Objective,
    nominal: Model,
    plant: PlantData | None,
    chosen: list[Choice],
    j: int,
    *,
    cause: Cause,
) -> tuple[float, list[Choice], float] | None:
    """``chosen`` with ``cause`` in place of its ``j``-th: (BIC, choices, cost), or None.

    ``cause`` is fitted on top of the others (on ``screen``), then every continuous value
    re-fitted jointly; the BIC and cost are of ``obj``. None: ``cause`` has no proposal.
    """
    rest = chosen[:j] + chosen[j + 1 :]
    ctx = Context(build(nominal, rest), nominal, plant, screen)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = fit_single(cause, ctx)
    if got is None:
        return None
    trial, _ = joint_refit(screen, nominal, rest[:j] + [got[0]] + rest[j:], max_nfev=15)
    cost = obj.cost(build(nominal, trial))
    return obj.bic(cost, _n_free(trial)), trial, cost


def _simplify(
    obj: Objective,
    screen: Objective,
    nominal: Model,
    plant: PlantData | None,
    applicable: list[Cause],
    chosen: list[Choice],
    *,
    bic: float,
) -> tuple[list[Choice], float, float]:
    """Each chosen cause replaced by a simpler one where that explains as much.

    Some effects have a simpler twin: on a one-mode plant an additive mode at the plant's
    own mode is a gain change, a wide notch of no depth acts like a control delay, a
    critically damped pair far up like a low-pass. Forward selection keeps whichever it
    met first; here every cause with fewer free values than a chosen one is fitted in its
    place (on top of the others) and, where the joint re-fit's BIC comes within
    :data:`ACCEPT_MARGIN` of the current one, the simpler set is kept (the rule of
    :func:`select`: within the margin, the fewest values).
    """
    j = 0
    while j < len(chosen):
        c = chosen[j]
        rest = chosen[:j] + chosen[j + 1 :]
        names = {ch.cause for ch in rest}
        simpler = [
            k
            for k in applicable
            if k.n_free < CAUSES[c.cause].n_free and k.name not in names and k.name != c.cause
        ]
        best: tuple[float, list[Choice], float] | None = None
        for k in simpler:
            got = swap(obj, screen, nominal, plant, chosen, j, cause=k)
            if (
                got is not None
                and got[0] < bic + ACCEPT_MARGIN
                and (best is None or got[0] < best[0])
            ):
                best = got
        if best is not None:
            bic, chosen = best[0], best[1]
            continue  # the same position again: the new cause may have a simpler twin too
        j += 1
    cost = obj.cost(build(nominal, chosen))
    return chosen, cost, obj.bic(cost, _n_free(chosen))


def _prune(
    obj: Objective,
    screen: Objective,
    nominal: Model,
    chosen: list[Choice],
    cost: float,
    bic: float,
    *,
    every: bool = False,
) -> tuple[list[Choice], float, float]:
    """Drop causes whose removal (the rest re-fitted) does not raise the BIC by the margin.

    Every earlier cause (the last was just accepted with its margin); ``every``: any.
    """
    j = 0
    while len(chosen) > 1 and j < len(chosen) - (0 if every else 1):
        rest = chosen[:j] + chosen[j + 1 :]
        trial, _ = joint_refit(screen, nominal, rest, max_nfev=15)
        c = obj.cost(build(nominal, trial))
        b = obj.bic(c, _n_free(trial))
        if b <= bic + ACCEPT_MARGIN:  # it did not bring its margin: dropped
            chosen, cost, bic = trial, c, b
            continue
        j += 1
    return chosen, cost, bic


def _with_neighbours(trials: list[list[Choice]], nominal: Model) -> list[list[Choice]]:
    """``trials`` and, for every discrete cause in one, its neighbouring values too.

    A discrete value is chosen with the other causes' values fixed: a continuous cause
    fitted first may have taken up part of its effect (a low-pass some of a control
    delay's lag), and a discrete one chosen first may be one off because of what was
    still missing (a control delay one short with a notch unmodelled); so the values
    within two of it are re-fitted jointly with the rest as well.
    """
    out, seen = [], set()
    for t in trials:
        variants = [t]
        for j, c in enumerate(t):
            cause = CAUSES[c.cause]
            if cause.discrete:
                variants += [
                    t[:j] + [replace(c, x=(v,))] + t[j + 1 :]
                    for v in cause.values(nominal)
                    if v != c.x[0] and abs(v - c.x[0]) <= 2
                ]
        for v in variants:
            key = tuple((c.cause, c.x) for c in v)
            if key not in seen:
                seen.add(key)
                out.append(v)
    return out
