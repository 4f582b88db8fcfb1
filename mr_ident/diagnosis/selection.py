"""Which causes, together: forward selection with joint re-fits and an information criterion.

The criterion is the BIC of the time-domain residual (:class:`~mr_ident.diagnosis.objective.
Objective`): ``BIC = 2 sum_k |E(k)|² / S(k) + p ln(n_bins)``, p the free parameters of every
chosen cause. Each step:

1. **Screen.** Every applicable cause is fitted on top of the causes chosen so far (their
   values fixed), on the screening part of the record (at most :data:`SCREEN_SAMPLES`
   samples): proposals from the identified plant or a grid, each scored, the best one
   refined by least squares; discrete causes (delays, offsets) are enumerated.
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

import numpy as np

from ..numerics.arrays import FloatArray
from ..numerics.model import Model
from .causes import Cause, CauseFit, Choice, Context, Params, PlantData, clip
from .objective import Objective, least_squares
from .registry import CAUSES, build

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


def fit_single(cause: Cause, ctx: Context) -> tuple[Choice, float] | None:
    """``cause`` fitted on top of ``ctx.current`` on ``ctx.objective``: choice and cost.

    Every proposal (at most 24) is scored; a discrete cause keeps the best, a continuous
    one refines the best by least squares.
    """
    obj = ctx.objective
    props = cause.proposals(ctx)[:24]
    if not props:
        return None
    if cause.linear:
        props = [solve_linear(obj, cause, ctx.current, p) for p in props]
    scored = sorted(
        ((obj.cost(cause.apply(ctx.current, p)), i, p) for i, p in enumerate(props)),
        key=lambda t: (t[0], t[1]),
    )
    cost0, _, p = scored[0]
    if cause.discrete:
        return p, cost0
    lo, hi, sc = cause.bounds(ctx.nominal, p)

    def make(x: FloatArray) -> Model:
        return cause.apply(ctx.current, replace(p, x=tuple(float(v) for v in x)))

    x, cost = least_squares(obj, make, clip(p.x, lo, hi), lo, hi, sc, max_nfev=20)
    if cost0 < cost:
        return p, cost0
    return replace(p, x=tuple(float(v) for v in x)), cost


def solve_linear(obj: Objective, cause: Cause, current: Model, choice: Choice) -> Choice:
    """``choice`` with its :attr:`Cause.linear` values solved by least squares.

    The whitened residual is affine in them (the initial-state projection is linear too):
    ``res(x) = res(0) + sum_i x_i d_i``, so one simulation per value gives the solution.
    Each value is probed at the size of its start, so that the numbers stay in range.
    """
    x = np.asarray(choice.x, float)
    idx = list(cause.linear)
    probe = np.where(np.abs(x[idx]) > 0, np.abs(x[idx]), 1.0)
    x0 = x.copy()
    x0[idx] = 0.0

    def res(v: FloatArray) -> FloatArray:
        return obj.residuals(cause.apply(current, replace(choice, x=tuple(float(t) for t in v))))

    r0 = res(x0)
    cols = []
    for i, s in zip(idx, probe, strict=True):
        xi = x0.copy()
        xi[i] = s
        cols.append((res(xi) - r0) / s)
    A = np.column_stack(cols)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(r0))):
        return choice
    x0[idx] = np.linalg.lstsq(A, -r0, rcond=None)[0]
    return replace(choice, x=tuple(float(t) for t in x0))


@dataclass(frozen=True)
class _Continuous:
    """The continuous values of a set of choices as one vector (discrete ones left fixed).

    ``cont``: indices of the continuous choices; ``sizes``: their values' counts; ``x``,
    ``lower``, ``upper``, ``scale``: concatenated values and bounds.
    """

    choices: list[Choice]
    cont: list[int]
    sizes: list[int]
    x: FloatArray
    lower: FloatArray
    upper: FloatArray
    scale: FloatArray

    @classmethod
    def of(cls, nominal: Model, choices: list[Choice]) -> _Continuous:
        cont = [j for j, c in enumerate(choices) if not CAUSES[c.cause].discrete]
        parts = [CAUSES[choices[j].cause].bounds(nominal, choices[j]) for j in cont]
        x = [np.asarray(choices[j].x, float) for j in cont]

        def cat(arrays: list[FloatArray]) -> FloatArray:
            return np.concatenate(arrays) if arrays else np.zeros(0)

        return cls(
            choices,
            cont,
            [len(choices[j].x) for j in cont],
            cat(x),
            cat([b[0] for b in parts]),
            cat([b[1] for b in parts]),
            cat([b[2] for b in parts]),
        )

    def unpack(self, x: FloatArray) -> list[Choice]:
        """The choices with the continuous values ``x``."""
        out, k = list(self.choices), 0
        for j, n in zip(self.cont, self.sizes, strict=True):
            out[j] = replace(self.choices[j], x=tuple(float(v) for v in x[k : k + n]))
            k += n
        return out


def joint_refit(
    obj: Objective, nominal: Model, choices: list[Choice], *, max_nfev: int = 30
) -> tuple[list[Choice], float]:
    """Every continuous parameter of ``choices`` re-fitted together (discrete ones fixed)."""
    v = _Continuous.of(nominal, choices)
    start = obj.cost(build(nominal, choices))
    if not v.cont:
        return choices, start
    x0 = clip(v.x, v.lower, v.upper)
    x, cost = least_squares(
        obj,
        lambda x: build(nominal, v.unpack(x)),
        x0,
        v.lower,
        v.upper,
        v.scale,
        max_nfev=max_nfev,
    )
    if cost > start:
        return choices, start
    return v.unpack(x), cost


def parameter_std(obj: Objective, nominal: Model, choices: list[Choice]) -> list[Params]:
    """Standard deviation of every named parameter of ``choices``, fitted jointly on ``obj``.

    The whitened residual's components have variance 1/2 under a right model
    (:class:`~mr_ident.diagnosis.objective.Objective`), so the continuous values have the
    Gauss-Newton covariance ``C = (JᵀJ)⁻¹ / 2``, J the residual's Jacobian by forward
    differences at the fit (one simulation per value); a named quantity ``g(x)`` (an
    amplitude from its two quadratures, a stiffness ratio) has ``∇g C ∇gᵀ`` (delta method).
    Discrete values are given std 0; a singular direction (a value the data do not
    determine) gets inf.
    """
    v = _Continuous.of(nominal, choices)
    cont, sizes = v.cont, v.sizes
    out: list[Params] = [{k: 0.0 for k in CAUSES[c.cause].named(c, nominal)} for c in choices]
    if not cont:
        return out
    r0 = obj.residuals(build(nominal, choices))
    steps = 1e-4 * np.maximum(np.abs(v.scale), 1e-12)
    cols = []
    for i, h in enumerate(steps):
        x = v.x.copy()
        x[i] += h
        cols.append((obj.residuals(build(nominal, v.unpack(x))) - r0) / h)
    J = np.column_stack(cols)
    with np.errstate(all="ignore"):
        cov = 0.5 * np.linalg.pinv(J.T @ J, rcond=1e-12, hermitian=True)
        weak = np.diag(cov) * np.sum(J * J, axis=0) > 1e8  # no information on that value
    k = 0
    for j, n in zip(cont, sizes, strict=True):
        cause, c = CAUSES[choices[j].cause], choices[j]
        C = cov[k : k + n, k : k + n]
        base = cause.named(c, nominal)
        grads = []
        for i in range(n):
            x = np.asarray(c.x, float).copy()
            x[i] += steps[k + i]
            moved = cause.named(replace(c, x=tuple(float(v) for v in x)), nominal)
            grads.append([(moved[key] - base[key]) / steps[k + i] for key in base])
        G = np.array(grads).T  # (n_named, n)
        var = np.einsum("ai,ij,aj->a", G, C, G)
        bad = np.any(np.abs(G[:, weak[k : k + n]]) > 0, axis=1)
        out[j] = {
            key: (math.inf if b or not np.isfinite(v) else float(math.sqrt(max(v, 0.0))))
            for key, v, b in zip(base, var, bad, strict=True)
        }
        k += n
    return out


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
) -> Selection:
    """Forward selection of causes (see the module docstring)."""
    applicable = [c for c in CAUSES.values() if c.applies(nominal)]

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
        simpler, cur_cost, cur_bic = _simplify(
            est_full, est_screen, nominal, plant, applicable, chosen, cur_bic
        )
        if simpler != chosen:  # what a replaced cause had left to the others may go now
            simpler, cur_cost, cur_bic = _prune(
                est_full, est_screen, nominal, simpler, cur_cost, cur_bic, every=True
            )
        chosen = simpler
    if chosen and est_screen is not est_full:  # the values from all of the estimation data
        chosen, cur_cost = joint_refit(est_full, nominal, chosen)
        cur_bic = est_full.bic(cur_cost, _n_free(chosen))
    stds = parameter_std(est_full, nominal, chosen)
    fits = [
        replace(_fit(est_full, nominal, chosen[: j + 1], cur_bic), std=stds[j])
        for j in range(len(chosen))
    ]
    inapplicable = [
        CauseFit(c.name, {}, math.inf, {}, nominal, applicable=False)
        for c in CAUSES.values()
        if not c.applies(nominal)
    ]
    return Selection(fits, ranking + inapplicable, build(nominal, chosen))


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
            got = swap(obj, screen, nominal, plant, chosen, j, k)
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
