# SPDX-License-Identifier: Apache-2.0
"""The controller's own equation: whether the logged u follows from the logged y and r.

In closed loop the record holds both sides of the controller: the y it sampled and the u
it applied, ``u_h = r_h - H_u K_l S_d y_h`` (r at the plant input) or ``u_h = H_u K_l S_d
(r_h - y_h)`` (r the setpoint: the model's ``injection``). Given the measured r and y, the model's
controller (its K_l, notches, sampling phase and control delay) predicts u with no noise
at all: the plant and its noise enter only through y, which is measured. So the
controller's side of the loop is checked on this equation alone, exactly, before any
cause of the plant is sought:

- where the model's controller reproduces the logged u to rounding
  (:data:`EXACT`), the controller runs as modelled, and no controller-side cause
  (a notch, a control delay, a sampling offset) can be in the loop;
- where it does not, the controller-side causes are fitted to this equation
  (:func:`relate`): a notch, a delay or an offset the machine has and the model lacks
  brings the residual to rounding, and is then known to the precision of the numbers,
  however little r excites the loop where it acts (on the y criterion alone a shallow,
  wide notch was determined to 5-50 %, not 2 %); unless a delay or offset alone closes
  it and makes the loop explain y worse (:attr:`ControllerRelation.contradicted`,
  checked by the diagnosis): then u and y are more likely logged skewed in time, and
  nothing of the equation is used;
- where no set of them does, the logged u is not the controller's output for the
  logged y (a u measured rather than commanded, with its own noise; a controller unlike
  the model in a way outside the vocabulary): the relation is reported and left out,
  and the controller-side causes are judged on y as the plant's are.

Only u given y is used: the likelihood of (y, u) given r is that of y given r (the
criterion, :mod:`~mr_ident.diagnosis.criterion.objective`) times that of u given y and r (this
equation), so the two hold separate evidence and nothing is counted twice.

The controller's state when the record began is unknown: its free responses (an
integrator's constant among them) are projected out, as the loop's are in the criterion,
and so is a constant per channel of u (a trim, an offset of y through K_l); the first
periods, whose held outputs were computed before the record, are left out.

Missing samples (NaN in u or y) are unknowns, as that state is: a missing u leaves its
own equation out (u appears in no other); a missing y the controller sampled enters every
later output through the controller's dynamics, linearly, so its value is eliminated
like the initial state, by projecting out the controller's response to a unit sample
there (:meth:`Equation.holes`). Nothing is interpolated; the equation stays exact.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.optimize

from ...numerics.arrays import BoolArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from ..causes.cause import Cause, CauseFit, Choice, Params, clip
from ..causes.registry import CAUSES, build
from ..criterion.objective import Objective
from ..selection.fitting import Continuous
from .equation import Equation as Equation  # re-exported
from .identified import controller_starts

#: The controller relation holds when the logged u departs from the model controller's
#: output by at most this fraction of that output (rms): float64 rounding through a
#: simulated loop is 1e-15-1e-9 of it; a float32 log 1e-7-6e-7, growing with
#: rms(u)/rms(r - u); a text log of 6 significant digits about 5e-7 times that ratio.
EXACT = 1e-5
#: Notched sets refined by least squares where no linear start closes the gap, if their
#: error is below REFINE_BELOW (on an exact record the right set's linear start is exact
#: already; a u with noise of its own leaves every start far above it).
REFINED = 3
REFINE_BELOW = 1e-3


@dataclass(frozen=True)
class ControllerRelation:
    """What the controller's equation says of a record.

    Attributes
    ----------
    error_before : float
        rms of ``u - û`` over the rms of the controller's output, the nominal model's
        controller (after the free responses are projected out).
    error_after : float
        The same with :attr:`choices` applied.
    choices : list of Choice
        The controller-side causes fitted to the equation (empty where it held at once).
    std : list of dict
        Per choice, the standard deviation of each named parameter on the equation.
    samples : int
        High-rate samples the equation was checked on.
    contradicted : bool
        The delay or offset that closes the equation makes the loop explain y worse than
        without it (:func:`~mr_ident.diagnosis.diagnose.diagnose` checks): the logged
        channels are then more likely skewed in time than the controller changed, and
        nothing of the equation is used.
    """

    error_before: float
    error_after: float
    choices: list[Choice]
    std: list[Params]
    samples: int
    contradicted: bool = False

    @property
    def exact(self) -> bool:
        """The equation holds to rounding with :attr:`choices` applied."""
        return self.error_after <= EXACT

    @property
    def settles(self) -> bool:
        """The equation decides the controller's path: exact and not contradicted by y."""
        return self.exact and not self.contradicted

    def text(self) -> str:
        """The finding in words."""
        pct = f"{100 * self.error_before:.2g} %"
        names = " and ".join(c.cause for c in self.choices)
        if self.contradicted:
            return (
                f"the logged u is the model controller's output for the logged y only with "
                f"{names} (to {self.error_after:.1g}), but the loop with them explains y "
                "worse than without: u and y are more likely logged skewed in time (a "
                "whole-record shift reads as a control delay, with a sampling offset of F - 1 "
                "for F > 1) than the controller changed; nothing of the equation is used and "
                "the controller-side causes are judged on y"
            )
        if self.exact and not self.choices:
            return (
                f"the logged u is the model controller's output for the logged y (to "
                f"{self.error_after:.1g} of it, {self.samples} samples): no cause in the "
                "controller's path"
            )
        if self.exact:
            return (
                f"the logged u departs from the model controller's output for the logged y by "
                f"{pct} (rms); with {names} it is that output to {self.error_after:.1g}, so "
                "the controller's own equation determines them"
            )
        return (
            f"the logged u is not the model controller's output for the logged y ({pct} rms "
            "apart, and no gain, notch, delay or offset, nor a controller identified from "
            "the data, closes the gap): u may be measured rather than commanded (with noise "
            "of its own), u and y may be logged skewed in time, or the controller differs in "
            "a way outside the vocabulary (a feedforward that is not constant, a "
            "nonlinearity); its causes are judged on y"
        )


def controller_side(nominal: Model) -> list[Cause]:
    """The registered causes in the controller's path that apply to ``nominal``."""
    return [c for c in CAUSES.values() if c.controller_side and c.applies(nominal)]


def relate(nominal: Model, rec: LoopData) -> ControllerRelation | None:
    """The controller's equation on ``rec``, with controller-side causes fitted where it fails.

    None in open loop or with y at the low rate (the controller's samples are not all
    logged). Otherwise the nominal's error; where it exceeds :data:`EXACT`, every
    combination of a control delay (the model's less down to none, or up to 2F samples
    more) and a sampling offset (every phase)
    is tried, each without and with a notch (started by :func:`notch_start`, refined by
    least squares where no start closes the gap); of the sets that bring the equation
    to :data:`EXACT`, the one with the fewest values is kept (then the smallest error).
    Where none does, the relation is returned with no causes (``exact`` False).
    """
    if nominal.controller is None or rec.y_step != 1:
        return None
    hold = nominal.sample_phase + nominal.control_delay
    if rec.n_samples < 4 * nominal.ratio * (hold // nominal.ratio + 6):
        return None  # too short to hold the longest candidate's start four times over
    eq = Equation(rec, nominal)
    e0 = eq.error(nominal)
    if e0 <= EXACT:
        return ControllerRelation(e0, e0, [], [], eq.samples)
    sides = {c.name: c for c in controller_side(nominal)}

    def values(name: str) -> list[list[Choice]]:
        cause = sides.get(name)
        vals = cause.values(nominal) if cause else []
        if name == "control_delay" and cause:  # shorter than modelled, too
            vals = [float(-k) for k in range(1, nominal.control_delay + 1)] + vals
        return [[]] + [[Choice(name, (v,))] for v in vals]

    timings = [d + o for d in values("control_delay") for o in values("sampling_offset")]
    found = _trials(eq, nominal, timings, notch="controller_notch" in sides)
    exact = [(err, ch) for err, ch in found if err <= EXACT]
    if not exact:  # no set of them closes the gap: nothing of it is used
        return ControllerRelation(e0, e0, [], [], eq.samples)
    err, chosen = min(exact, key=lambda t: (sum(CAUSES[c.cause].free_in(c) for c in t[1]), t[0]))
    if any(not CAUSES[c.cause].discrete for c in chosen):  # to the precision of the numbers
        err, chosen = _refit(eq, nominal, chosen)
    return ControllerRelation(e0, err, chosen, _std(eq, nominal, chosen), eq.samples)


def _trials(
    eq: Equation, nominal: Model, timings: list[list[Choice]], *, notch: bool
) -> list[tuple[float, list[Choice]]]:
    """Every set of controller-side causes tried, with the equation's error after it.

    Each timing alone and with a notch (:func:`notch_start`); where none is exact, least
    squares from the best notched starts; then, while none is exact, the controller from
    the data (its gain first, then its coefficients) after each timing.
    """
    found: list[tuple[float, list[Choice]]] = []
    notched: list[tuple[float, list[Choice]]] = []
    for discrete in timings:
        base = build(nominal, discrete)
        found.append((eq.error(base), discrete))
        start = notch_start(eq, base) if notch else None
        if start is not None:
            trial = discrete + [start]
            notched.append((eq.error(build(nominal, trial)), trial))
    found += notched
    if not any(err <= EXACT for err, _ in found):  # least squares from the best starts
        near = [t for t in sorted(notched, key=lambda t: t[0]) if t[0] < REFINE_BELOW]
        for _, trial in near[:REFINED]:  # (a u with its own noise is nowhere near: skipped)
            found.append(_refit(eq, nominal, trial))
    for stage in (0, 1):  # the controller from the data: its gain first, then its coefficients
        if any(err <= EXACT for err, _ in found):
            break
        for discrete in timings:
            base = build(nominal, discrete)
            for own in controller_starts(eq, base, coefficients=bool(stage)):
                trial = discrete + own
                found.append((eq.error(build(nominal, trial)), trial))
    return found


def notch_start(eq: Equation, base: Model) -> Choice | None:
    """A notch after ``base``'s controller from the equation, linearly; None if none fits.

    The controller's outputs are read off the logged u (``u_c = r - u`` at the last sample
    of each period, held from period ``m - j``); ``z`` is ``base``'s controller applied to
    the sampled y. A biquad ``B/A`` from z to u_c is linear in its five coefficients
    (equation error ``A u_c = B z``; each free response of the controller, passed through
    B, adds three columns), and its poles and zeros give the Tustin notch in closed form:
    with ``t = (p - 1)/(p + 1)`` per pole, ``tan²(π f dt) = t₁t₂``,
    ``ζ = -(t₁ + t₂) / (2 √(t₁t₂))`` and ``depth = (t₁' + t₂')/(t₁ + t₂)`` (primes: the
    zeros). Exact on an exact record; elsewhere a start for least squares.
    """
    F, M = eq.F, eq.M
    hold = base.sample_phase + base.control_delay
    z, free = eq.outputs(base)
    free = np.concatenate([free, eq.holes(base)], axis=2)  # missing y: unknowns as the state
    jl = -((F - 1 - hold) // F)  # the last sample of period m holds u_c[m - jl]
    k = np.arange(max(eq.start // F, 2), M - jl)
    last: BoolArray = np.any(eq.u_missing[F - 1 :: F], axis=1)  # u_c off a missing u: unknown
    k = k[~(last[k + jl] | last[k + jl - 1] | last[k + jl - 2])]

    def uc(lag: int) -> FloatArray:
        n = (k - lag + jl) * F + F - 1
        return np.asarray(eq.logged[n], float)

    cols = [-uc(1), -uc(2), z[k], z[k - 1], z[k - 2]]
    cols += [free[k - lag][:, :, i] for i in range(free.shape[-1]) for lag in range(3)]
    A = np.stack([c.ravel() for c in cols], axis=1)
    norm = np.sqrt(np.einsum("ij,ij->j", A, A))
    if not (np.all(np.isfinite(A)) and np.all(norm[:5] > 0)):
        return None
    norm = np.where(norm > 0, norm, 1.0)
    a1, a2, b0, b1, b2 = (np.linalg.lstsq(A / norm, uc(0).ravel(), rcond=1e-12)[0] / norm)[:5]
    with np.errstate(all="ignore"):
        P = (1 + a1 + a2) / (1 - a1 + a2)
        t = 2 * (a2 - 1) / (1 - a1 + a2)  # t₁ + t₂ of the poles
        tz = 2 * (b2 / b0 - 1) / (1 - b1 / b0 + b2 / b0)  # of the zeros
        if not (np.isfinite(P) and P > 0):
            return None
        x = np.array(
            [
                math.atan(math.sqrt(P)) * base.fs_high / (math.pi * F),
                -t / (2 * math.sqrt(P)),
                tz / t,
            ]
        )
    if not np.all(np.isfinite(x)):
        return None
    cause = CAUSES["controller_notch"]
    lo, hi, _ = cause.bounds(base, Choice(cause.name, tuple(x)))
    return Choice(cause.name, tuple(float(v) for v in clip(x, lo, hi)))


def _refit(eq: Equation, nominal: Model, choices: list[Choice]) -> tuple[float, list[Choice]]:
    """Every continuous value of ``choices`` fitted on the equation: (error, choices)."""
    v = Continuous.of(nominal, choices)
    start = eq.error(build(nominal, choices))
    if not v.cont:
        return start, choices

    def res(x: FloatArray) -> FloatArray:
        r = eq.residual(build(nominal, v.unpack(x)))
        return r if np.all(np.isfinite(r)) else np.full(r.shape, 1e3)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sol = scipy.optimize.least_squares(
                res,
                clip(v.x, v.lower, v.upper),
                bounds=(v.lower, v.upper),
                x_scale=v.scale,
                max_nfev=60,
                ftol=1e-15,
                xtol=1e-15,
                gtol=1e-15,
                diff_step=1e-7,
            )
            x = np.asarray(sol.x, float)
        except (ValueError, np.linalg.LinAlgError):
            return start, choices
    fitted = v.unpack(x)
    err = eq.error(build(nominal, fitted))
    return (err, fitted) if err < start else (start, choices)


def value_std(
    eq: Equation, model_at: Callable[[FloatArray], Model], x: Sequence[float]
) -> FloatArray:
    """Gauss-Newton std of the values ``x`` on the equation, ``model_at(x)`` the model.

    The residual's own spread as its noise (rounding, where the equation holds): to what
    precision the equation fixes the values. Forward differences, step 1e-6 of each value.
    """
    x0 = np.asarray(x, float)
    r0 = eq.residual(model_at(x0))
    sigma2 = float(np.sum(r0**2)) / max(r0.size - x0.size, 1)
    cols = []
    for i in range(x0.size):
        h = 1e-6 * max(abs(x0[i]), 1e-3)
        moved = x0.copy()
        moved[i] += h
        cols.append((eq.residual(model_at(moved)) - r0) / h)
    J = np.column_stack(cols)
    cov = sigma2 * np.linalg.pinv(J.T @ J)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _std(eq: Equation, nominal: Model, choices: list[Choice]) -> list[Params]:
    """Per choice, the std of each parameter on the equation (:func:`value_std`; discrete 0).

    The controller-side causes name their values as they are (``named`` is ``x``).
    """
    out: list[Params] = []
    for j, c in enumerate(choices):
        cause = CAUSES[c.cause]
        if cause.discrete:
            out.append({k: 0.0 for k in cause.parameters})
            continue

        def model_at(v: FloatArray, j: int = j, c: Choice = c) -> Model:
            moved = replace(c, x=tuple(float(t) for t in v))
            return build(nominal, choices[:j] + [moved] + choices[j + 1 :])

        sd = value_std(eq, model_at, c.x)
        out.append({k: float(v) for k, v in zip(cause.value_names(c), sd, strict=True)})
    return out


def settled_fits(obj: Objective, nominal: Model, rel: ControllerRelation | None) -> list[CauseFit]:
    """The controller-side causes the controller's equation determined, as CauseFits.

    Each with every one before it in its model; its score the BIC of that model on ``obj``
    (the values were not fitted there, so they count no parameter); its std from the
    equation. [] where the relation does not settle the controller's path.
    """
    if rel is None or not rel.settles:
        return []
    out = []
    for j, c in enumerate(rel.choices):
        cause = CAUSES[c.cause]
        model = build(nominal, rel.choices[: j + 1])
        bic, rss = obj.evaluate(model, 0)
        params = cause.named(c, nominal)
        text = cause.describe(params) + " (the controller's own equation, u from y, fixes it)"
        out.append(CauseFit(c.cause, params, bic, rss, model, True, text, c, rel.std[j]))
    return out


@dataclass(frozen=True, eq=False)
class ControllerPath:
    """The controller's path as its own equation settles it, and the criterion on top.

    ``relation`` (None in open loop), ``base`` the nominal with the settled controller-side
    causes, ``criterion`` the estimation criterion on ``base`` with the ``noise`` level,
    ``why`` the text that rules the controller-side causes out of the search (None when it
    does not).
    """

    relation: ControllerRelation | None
    base: Model
    criterion: Objective
    noise: FloatArray
    why: str | None


def controller_path(model: Model, est: LoopData, noise: FloatArray) -> ControllerPath:
    """The controller's own equation on ``est`` (:func:`relate`), checked against y.

    A delay or offset that closes the equation must also make the loop explain y better
    (on the criterion with ``noise``); where it makes it worse the relation is
    ``contradicted``. The settled causes are applied to ``model`` as ``base``.
    """
    relation = relate(model, est)
    shifts = relation.choices if relation is not None and relation.exact else []
    nominal_criterion = None
    if relation is not None and shifts and all(CAUSES[c.cause].discrete for c in shifts):
        # a delay or offset that closes the equation must also make the loop explain y
        # better; where it makes it worse, the channels are skewed in time (a shift of y
        # against u reads as one), not the controller changed (a notch is no skew)
        nominal_criterion = Objective(est, model, noise)
        if not nominal_criterion.cost(build(model, shifts)) < nominal_criterion.cost(model):
            relation = replace(relation, contradicted=True)
    settled = relation if relation is not None and relation.settles else None
    fixed = settled.choices if settled is not None else []
    base = build(model, fixed)
    if nominal_criterion is not None and not fixed:  # the skew's check built it already
        full = nominal_criterion
    else:
        full = Objective(est, base, noise)
    why = f"settled by the controller's own equation: {settled.text()}" if settled else None
    return ControllerPath(relation=relation, base=base, criterion=full, noise=noise, why=why)
