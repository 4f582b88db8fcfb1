# SPDX-License-Identifier: Apache-2.0
"""The controller from the data: its gain, or its coefficients, from the logged u and y.

Where the logged u is the controller's command, ``u_c = r - u`` is the controller's
output for the y it sampled, with no noise between them (:mod:`.relation`). Two ways the
machine's controller can differ from the model's are then linear in the data:

- **a gain** ``g K``: the equation's residual is affine in g (the free responses of
  ``g K`` span the same space as K's for g != 0), so two evaluations give it:
  ``r(g) = a + g b`` with ``b = r(2) - r(1)``, ``a = r(1) - b``, and the least-squares
  ``g = -<a, b> / <b, b>`` (:func:`gain_start`);
- **other coefficients** ``K' = B(z) / A(z)`` of order n: the equation error
  ``A(q) u_c[m] = B(q) y_s[m] + c`` (``y_s`` the sampled y, c a constant: a trim) is linear in
  the 2n + 1 coefficients and c, and every lagged value is logged, so no initial state
  enters; least squares over the record's periods identifies the controller, exactly
  on an exact record (:func:`retune_start`). Tried at the model's order (a retuned
  controller: a PID with other gains) and up to two orders higher (a filter the model
  lacks).

Both are starts: :func:`~.relation.relate` keeps a set only where it brings the
equation to rounding, and refines it by least squares there.
"""

from __future__ import annotations

import numpy as np

from ...numerics.arrays import BoolArray, FloatArray
from ...numerics.systems.model import Model
from ..causes.cause import Choice
from ..causes.registry import CAUSES
from .equation import Equation

#: Orders above the model controller's tried for a controller identified from the data.
EXTRA_ORDERS = 2


def gain_start(eq: Equation, base: Model) -> Choice | None:
    """The controller gain that best closes ``eq`` on top of ``base``; None if none does."""
    cause = CAUSES["controller_gain"]
    r1 = eq.residual(cause.apply(base, Choice(cause.name, (1.0,))))
    r2 = eq.residual(cause.apply(base, Choice(cause.name, (2.0,))))
    b = r2 - r1
    a = r1 - b
    bb = float(b @ b)
    if not (np.all(np.isfinite(b)) and bb > 0):
        return None
    g = -float(a @ b) / bb
    if not 0.05 < g < 20.0:
        return None
    return Choice(cause.name, (g,))


def model_order(base: Model) -> int:
    """The order of ``base``'s (SISO) controller: its denominator's degree."""
    K = base.controller
    assert K is not None
    return len(K.den[0][0]) - 1


def retune_start(eq: Equation, base: Model, order: int) -> Choice | None:
    """A controller of ``order`` fitted to ``eq`` by equation error (module docstring).

    ``base`` gives the timing (sampling phase, control delay); None where the data do not
    determine it (too few periods, a singular fit).
    """
    F, M = eq.F, eq.M
    hold = base.sample_phase + base.control_delay
    ys = eq.sampled[base.sample_phase :: F][:M, 0]
    ys_missing: BoolArray = eq.y_missing[base.sample_phase :: F][:M, 0]
    jl = -((F - 1 - hold) // F)  # the last sample of period m holds u_c[m - jl]
    k = np.arange(max(eq.start // F, order + 2), M - jl)
    last: BoolArray = np.any(eq.u_missing[F - 1 :: F], axis=1)
    bad = np.zeros(k.size, bool)
    for lag in range(order + 1):
        bad |= last[k + jl - lag] | ys_missing[k - lag]
    k = k[~bad]
    if k.size < 4 * (2 * order + 2):
        return None

    def uc(lag: int) -> FloatArray:
        n = (k - lag + jl) * F + F - 1
        return np.asarray(eq.logged[n, 0], float)

    cols = [-uc(i) for i in range(1, order + 1)] + [ys[k - i] for i in range(order + 1)]
    A = np.column_stack([*cols, np.ones(k.size)])
    norm = np.sqrt(np.einsum("ij,ij->j", A, A))
    if not (np.all(np.isfinite(A)) and np.all(norm > 0)):
        return None
    sol = np.linalg.lstsq(A / norm, uc(0), rcond=1e-13)[0] / norm
    a, b = sol[:order], sol[order : 2 * order + 1]
    x = np.concatenate([b, a])
    if not np.all(np.isfinite(x)) or not np.any(b):
        return None
    return Choice("controller_retuned", tuple(float(v) for v in x), (float(order),))


def controller_starts(eq: Equation, base: Model, *, coefficients: bool) -> list[list[Choice]]:
    """The controller-from-data sets on top of ``base``'s timing: its gain, or its coefficients."""
    out: list[list[Choice]] = []
    g = gain_start(eq, base) if CAUSES["controller_gain"].applies(base) else None
    if g is not None and not coefficients:
        out.append([g])
    if coefficients and CAUSES["controller_retuned"].applies(base):
        n0 = model_order(base)
        for order in range(max(n0, 1), n0 + EXTRA_ORDERS + 1):
            c = retune_start(eq, base, order)
            if c is not None:
                out.append([c])
    return out
