# SPDX-License-Identifier: Apache-2.0
"""Whether a diagnosis found what a scenario hides: tolerances, the verdict, the judge.

:func:`judge` compares what :func:`~mr_ident.diagnosis.diagnose` applied against the causes
:func:`~mr_bench.scenarios.draw_scenario` hid: named first, every parameter within
:data:`TOLERANCES`, the validation fit within :data:`MAX_FIT_GAP` of the true model's. A
fixed tolerance asks more than some records can give (a shallow notch where r excites the
loop little determines its frequency to 5 %, not 2 %); so the verdict also says whether the
truth lies within the data's own confidence region around the fit (:func:`likelihood_ratio`,
:data:`CONFIDENCE`): a miss with the truth outside that region is the diagnosis's (its
search or its criterion); a miss with the truth inside it is the record's, which cannot
tell the truth from the fit.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import scipy.stats

from mr_ident.diagnosis.causes.registry import CAUSES
from mr_ident.numerics.lifted.pfg_check import COVERAGE

if TYPE_CHECKING:
    from mr_ident.diagnosis.diagnose import Diagnosis
    from mr_ident.numerics.systems.model import Model

    from .scenarios import Scenario

#: Largest fit gap (the true model's validation fit % minus the extended model's).
MAX_FIT_GAP = 1.0
#: Level of the likelihood-ratio confidence region the truth is tested against.
CONFIDENCE = 0.99


@dataclass(frozen=True)
class Tolerance:
    """How close an estimate must come to the hidden value.

    ``kind`` "relative" (to |true|), "absolute", "samples" (absolute, in high-rate sample
    times) or "exact"; ``value`` the bound. ``width``: for the frequency of a damped
    second-order feature (a mode, a series resonance, a notch), the bound is at least this
    fraction of its half-power bandwidth ``2 ζ f`` (the scale on which such a feature's
    centre is defined and on which a filter placed against it must be centred); 0: none.
    """

    kind: str
    value: float = 0.0
    width: float = 0.0

    def within(self, estimate: float, true: float, fs_high: float, damping: float = 0.0) -> bool:
        """Whether ``estimate`` is within the tolerance of ``true`` (``damping``: ζ, for width)."""
        err = abs(estimate - true) if math.isfinite(estimate) else math.inf
        return err <= self.bound(true, fs_high, damping) if self.kind != "exact" else err < 1e-6

    def bound(self, true: float, fs_high: float, damping: float = 0.0) -> float:
        """The tolerance in the parameter's own units around ``true`` (0 for "exact").

        ``damping``: the feature's ζ, for :attr:`width` (0: the fixed bound alone).
        """
        scale = {"relative": abs(true), "samples": 1 / fs_high, "absolute": 1.0}
        fixed = self.value * scale[self.kind] if self.kind in scale else 0.0
        return max(fixed, self.width * 2.0 * abs(damping) * abs(true))

    def __str__(self) -> str:
        unit = {"relative": " %", "samples": " sample", "absolute": ""}
        k = 100 if self.kind == "relative" else 1
        text = f"{k * self.value:g}{unit[self.kind]}" if self.kind in unit else "exact"
        return text + (f" or {self.width:g} of 2ζf" if self.width else "")


#: A damped pair's frequency: 2 %, or a tenth of its half-power bandwidth where wider (the
#: same 2 % up to ζ = 0.1, 10 % at ζ = 0.5). What a record says of a feature's centre
#: grows with its width: the Cramér-Rao std of a series resonance's frequency on the
#: benchmark's 30 s records, 90th percentile, was 0.02 % at ζ < 0.1, 0.45 % at 0.1-0.25,
#: 1.8 % at 0.25-0.5 and 3.3 % at 0.5-0.8 (so a fixed 2 % asks 3 std of 3 % at ζ 0.6).
_F = Tolerance("relative", 0.02, width=0.1)
_Z, _X = Tolerance("relative", 0.25), Tolerance("exact")
#: Per cause and parameter: how close the diagnosis must come.
TOLERANCES: dict[str, dict[str, Tolerance]] = {
    "gain_error": {"gain": Tolerance("relative", 0.02)},
    "input_delay": {"delay_s": Tolerance("samples", 0.1)},
    "additive_mode": {"frequency_hz": _F, "damping": _Z, "gain": Tolerance("relative", 0.15)},
    "mode_shift": {"frequency_hz": _F, "damping": _Z, "residue_scale": Tolerance("relative", 0.1)},
    "series_lowpass": {"frequency_hz": Tolerance("relative", 0.02)},
    "series_resonance": {"frequency_hz": _F, "damping": _Z},
    "controller_notch": {"frequency_hz": _F, "damping": _Z, "depth": Tolerance("absolute", 0.05)},
    "control_delay": {"delay_samples": _X},
    "sampling_offset": {"offset_samples": _X},
    "periodic_disturbance": {
        "frequency_hz": Tolerance("relative", 0.005),
        "amplitude": Tolerance("relative", 0.15),
    },
}
#: The causes the generator hides.
CAUSE_NAMES: tuple[str, ...] = tuple(TOLERANCES)


@dataclass(frozen=True)
class Verdict:
    """How a diagnosis did on a scenario (:func:`judge`).

    ``named``: the one hidden cause named first, a hidden pair applied and nothing else,
    or nothing applied when nothing was hidden. ``parameters_ok``: named, and every
    hidden parameter within :data:`TOLERANCES` (``misses`` lists the others as text).
    ``fit_gap``: the true model's validation fit % of y minus the extended model's.
    ``success``: ``parameters_ok`` and ``fit_gap < MAX_FIT_GAP`` (nothing hidden: named).
    ``consistent``: as ``success``, but a parameter outside its tolerance counts as found
    when it lies within :data:`COVERAGE` of the diagnosis's own standard deviations of the
    truth (a value the data determine only loosely, reported honestly). ``stated``: as
    ``consistent``, but a hidden cause also counts as named when the diagnosis stated it
    among a chosen cause's equivalent explanations (the data cannot tell them apart; the
    diagnosis says so and gives both). ``credible``: as ``success``, but a parameter outside
    its tolerance counts as found when the truth lies within the data's
    :data:`CONFIDENCE` likelihood-ratio region around the fit (``lr`` of :func:`judge`
    at most the chi-square quantile of the hidden continuous values' count): no estimator
    can tell the truth from the fit on that record, so the miss is the record's.
    ``fixed``: as ``success`` with every frequency held to its fixed bound (the damped
    pairs' 2 % without the bandwidth allowance of :class:`Tolerance`).
    """

    named: bool
    parameters_ok: bool
    fit_gap: float
    success: bool
    misses: tuple[str, ...]
    consistent: bool = False
    stated: bool = False
    credible: bool = False
    fixed: bool = False


def likelihood_ratio(diagnosis: Diagnosis, model: Model) -> float:
    """``2 (J(model) - J(extended))`` on the diagnosis's estimation criterion J.

    J is the whitened residual's cost (:class:`~mr_ident.diagnosis.criterion.objective.Objective`);
    when ``model`` is the truth and the extended model's p continuous values were fitted
    to it, the statistic is about chi-square with p degrees of freedom (Wilks), so it tests
    whether the record can tell ``model`` from the fit at all.
    """
    J = diagnosis.criterion
    if J is None:
        raise ValueError("diagnosis has no criterion (made by an older version?)")
    return 2.0 * (J.cost(model) - J.cost(diagnosis.extended))


def hidden_dof(scenario: Scenario) -> int:
    """The continuous values of the scenario's hidden causes (the chi-square's dof)."""
    return sum(
        CAUSES[h.cause].n_free
        for h in scenario.hidden
        if h.cause in CAUSES and not CAUSES[h.cause].discrete
    )


def in_region(scenario: Scenario, lr: float) -> bool:
    """Whether the truth's likelihood ratio ``lr`` lies within the :data:`CONFIDENCE` region.

    The chi-square quantile with :func:`hidden_dof` degrees of freedom (at least one).
    """
    return lr <= float(scipy.stats.chi2.ppf(CONFIDENCE, max(hidden_dof(scenario), 1)))


def judge(
    scenario: Scenario,
    applied: Sequence[tuple[str, Mapping[str, float]]],
    fit_gap: float,
    stds: Sequence[Mapping[str, float]] | None = None,
    equivalents: Sequence[Sequence[tuple[str, Mapping[str, float], Mapping[str, float]]]]
    | None = None,
    lr: float | None = None,
) -> Verdict:
    """Whether a diagnosis found what ``scenario`` hides (the rules: :class:`Verdict`).

    ``applied``: the causes the diagnosis applied, in order, with their parameters;
    ``fit_gap``: the true model's validation fit % of y minus the extended model's;
    ``stds``: per applied cause, its parameters' standard deviations (for ``consistent``);
    ``equivalents``: per applied cause, the (cause, parameters, std) it stated as explaining
    the data as well (for ``stated``); ``lr``: :func:`likelihood_ratio` of the true
    model (for ``credible``).
    """
    spreads = list(stds) if stds is not None else [{} for _ in applied]
    v = _verdict(scenario, applied, fit_gap, spreads)
    options = [
        [(c, p, sd)] + list(equivalents[j] if equivalents is not None else ())
        for j, ((c, p), sd) in enumerate(zip(applied, spreads, strict=True))
    ]
    stated = any(
        (
            w := _verdict(
                scenario, [(c, p) for c, p, _ in combo], fit_gap, [sd for *_, sd in combo]
            )
        ).success
        or w.consistent
        for combo in itertools.product(*options)
    )
    credible = v.success or (
        v.named and _fits(scenario, v.fit_gap) and lr is not None and in_region(scenario, lr)
    )
    fixed = _verdict(scenario, applied, fit_gap, spreads, fixed=True).success
    return replace(v, stated=stated, credible=credible, fixed=fixed)


def _verdict(
    scenario: Scenario,
    applied: Sequence[tuple[str, Mapping[str, float]]],
    fit_gap: float,
    stds: Sequence[Mapping[str, float]],
    *,
    fixed: bool = False,
) -> Verdict:
    names, hidden = [c for c, _ in applied], [h.cause for h in scenario.hidden]
    one = len(hidden) == 1
    named = names[:1] == hidden if one else sorted(names) == sorted(hidden)
    misses, loose = [], []
    for h in scenario.hidden if named else ():
        j = names.index(h.cause)
        got, spread = applied[j][1], stds[j]
        for key, true in h.parameters.items():
            tol, est = TOLERANCES[h.cause][key], float(got.get(key, math.nan))
            zeta = 0.0 if fixed else float(h.parameters.get("damping", 0.0))
            if not tol.within(est, true, scenario.nominal.fs_high, zeta):
                sd = float(spread.get(key, 0.0) or 0.0)
                pm = f" ± {sd:.2g}" if sd else ""
                misses.append(f"{h.cause}.{key} {est:.4g}{pm} (true {true:.4g}, tol {tol})")
                loose.append(abs(est - true) <= COVERAGE * sd if math.isfinite(sd) else False)
    ok, gap = named and not misses, float(fit_gap)
    fits = _fits(scenario, gap)
    return Verdict(named, ok, gap, ok and fits, tuple(misses), named and all(loose) and fits)


def _fits(scenario: Scenario, fit_gap: float) -> bool:
    """The validation fit is the true model's within :data:`MAX_FIT_GAP` (or nothing hid)."""
    return not scenario.hidden or fit_gap < MAX_FIT_GAP


#: Distortion above the noise (dB, the truth's worst band) from which a nonlinearity must
#: be named (:func:`judge_beyond`).
NAMED_DB = 6.0
#: An extension describes an unlisted effect when its validation residual (100 - fit of y)
#: is at most this many times the true loop's (the model error's energy at most a tenth
#: of the noise's: 1.05² = 1.1), :func:`judge_beyond`.
TRUTH_RATIO = 1.05


@dataclass(frozen=True)
class BeyondVerdict:
    """How a diagnosis did on a loop beyond the vocabulary (:func:`judge_beyond`).

    ``named``: nonlinear distortion named (nonlinear cases; None otherwise); ``counts``:
    a nonlinear case whose true distortion is at least :data:`NAMED_DB` above the noise
    (where naming it is asked for), or an unlisted case whose effect changes y by at least
    as much above the noise (where describing it is asked for); ``worse_applied``: an
    extension (a cause or a correction) is in the extended model although its validation
    fit of y is below the nominal's; ``offered``: a correction was fitted (something was
    left after the causes); ``corrected``: one was applied and validates better than the
    nominal; ``explained``: nothing significant was left after the causes and they
    validate better than the nominal (the vocabulary described the effect; no correction
    needed); ``described``: corrected, or the extension validates better than the nominal
    and fits the validation record as the true loop does (its residual at most
    :data:`TRUTH_RATIO` times the truth's: what the data allow any model to be; judged
    against the truth, not by the diagnosis's own tests);
    ``varying``: the diagnosis says the plant changes within the record (its
    ``time_varying`` finding).
    """

    named: bool | None
    counts: bool
    worse_applied: bool
    offered: bool
    corrected: bool
    explained: bool
    varying: bool = False
    described: bool = False


def nonlinearity_named(diagnosis: Diagnosis) -> bool:
    """Whether the diagnosis named nonlinear distortion (its ``nonlinear`` finding)."""
    return bool(getattr(diagnosis, "nonlinear", False))


def judge_beyond(
    nonlinear: bool,
    distortion_db: float,
    diagnosis: Diagnosis,
    effect_db: float = math.nan,
    truth_fit: float = math.nan,
) -> BeyondVerdict:
    """The verdict (:class:`BeyondVerdict`) on a case with or without a nonlinearity.

    ``distortion_db``: the truth's distortion above the noise (nan for a linear effect);
    ``effect_db``: an unlisted effect's change of y above the noise (nan for a nonlinear
    one; ``mr_bench.beyond.effect_db``); ``truth_fit``: the true loop's validation fit of y,
    % (``Beyond.truth_fit``; nan: nothing is described but by a correction).
    """
    d = diagnosis
    extended = bool(d.applied) or bool(d.extended.plant_corrections)
    c = d.correction
    corrected = (
        c is not None and c.model is not None and c.best is not None
        and c.best.fit_y > c.fit_nominal
    )  # fmt: skip
    level = distortion_db if nonlinear else effect_db
    as_truth = math.isfinite(truth_fit) and 100.0 - d.fit_after.y <= TRUTH_RATIO * (
        100.0 - truth_fit
    )
    return BeyondVerdict(
        named=nonlinearity_named(d) if nonlinear else None,
        counts=math.isfinite(level) and level >= NAMED_DB,
        worse_applied=extended and d.fit_after.y < d.fit_before.y,
        offered=c is not None,
        corrected=corrected,
        explained=c is None and extended and d.fit_after.y > d.fit_before.y,
        varying=bool(getattr(d, "time_varying", False)),
        described=corrected or (extended and d.fit_after.y > d.fit_before.y and as_truth),
    )
