# SPDX-License-Identifier: Apache-2.0
"""Fitting causes to the criterion: one cause alone, several jointly, and their std.

The pieces :mod:`~mr_ident.diagnosis.selection.forward` and
:mod:`~mr_ident.diagnosis.selection.equivalence` build on: a single cause fitted on top of
the causes chosen so far (:func:`fit_single`; values the residual is affine in solved directly,
:func:`solve_linear`), every continuous value of a set re-fitted together
(:func:`joint_refit`), and the Gauss-Newton standard deviation of each named parameter
(:func:`parameter_std`). All on an :class:`~mr_ident.diagnosis.criterion.objective.Objective`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ...numerics.arrays import FloatArray
from ...numerics.systems.model import Model
from ..causes.cause import Cause, Choice, Context, Params, clip
from ..causes.registry import CAUSES, build
from ..criterion.objective import Objective, least_squares


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
class Continuous:
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
    def of(cls, nominal: Model, choices: list[Choice]) -> Continuous:
        """The continuous values of ``choices`` with their causes' bounds and scales."""
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
    v = Continuous.of(nominal, choices)
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
    (:class:`~mr_ident.diagnosis.criterion.objective.Objective`), so the continuous values have the
    Gauss-Newton covariance ``C = (JᵀJ)⁻¹ / 2``, J the residual's Jacobian by forward
    differences at the fit (one simulation per value); a named quantity ``g(x)`` (an
    amplitude from its two quadratures, a stiffness ratio) has ``∇g C ∇gᵀ`` (delta method).
    Discrete values are given std 0; a singular direction (a value the data do not
    determine) gets inf.
    """
    v = Continuous.of(nominal, choices)
    cont, sizes = v.cont, v.sizes
    out: list[Params] = [{k: 0.0 for k in CAUSES[c.cause].named(c, nominal)} for c in choices]
    if not cont:
        return out
    steps = 1e-4 * np.maximum(np.abs(v.scale), 1e-12)

    def stepped(i: int) -> Model:
        x = v.x.copy()
        x[i] += steps[i]
        return build(nominal, v.unpack(x))

    cov, weak = obj.gauss_newton(
        build(nominal, choices), ((stepped(i), h) for i, h in enumerate(steps))
    )
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
