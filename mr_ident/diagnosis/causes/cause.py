# SPDX-License-Identifier: Apache-2.0
"""Why a model is wrong: what a cause is (:class:`Cause`) and what a fitted one holds.

Every cause is a parametric extension of the model: its name and parameters, when it can
occur in a loop (:meth:`Cause.applies`), where to start looking (:meth:`Cause.proposals`,
from the identified FRF or a grid), the bounds of its parameters, how it extends a
:class:`~mr_ident.numerics.systems.model.Model` (:meth:`Cause.apply`) and how it says what it
found in words a mechatronics engineer uses (:meth:`Cause.describe`). The registry is
:data:`~mr_ident.diagnosis.causes.registry.CAUSES`; one engine fits and selects them all
(:mod:`~mr_ident.diagnosis.selection.forward`). The causes themselves are in
:mod:`~mr_ident.diagnosis.causes.plant_causes` (between u and y) and
:mod:`~mr_ident.diagnosis.causes.loop_causes` (in the controller's path and on the output).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.systems.model import Model
from ..criterion.objective import Objective

Params = dict[str, float]


@dataclass(frozen=True)
class Choice:
    """One cause with parameter values.

    ``x`` are fitted; ``fixed`` are settings that are not (which mode moved, which output
    carries a disturbance).
    """

    cause: str
    x: tuple[float, ...]
    fixed: tuple[float, ...] = ()


@dataclass(frozen=True)
class Equivalent:
    """Another cause that explains the data as well as a chosen one (in its place).

    Attributes
    ----------
    cause : str
    parameters, std : dict
        Its fitted values (jointly with the other chosen causes) and their standard
        deviations.
    description : str
        The finding in words.
    delta_bic : float
        BIC of the set with this cause in place of the chosen one, minus the chosen set's:
        below the selection's margin, so the data do not tell the two apart.
    """

    cause: str
    parameters: Params
    std: Params
    description: str
    delta_bic: float


@dataclass(frozen=True)
class CauseFit:
    """One cause fitted to the data.

    Attributes
    ----------
    cause : str
    parameters : dict
        Named as the cause's :attr:`Cause.parameters` (and any derived quantities).
    score : float
        BIC of the model with this cause (and the causes chosen before it); lower is better.
    rss : dict
        Residual sum of squares of y (and u in closed loop).
    model : Model
        The model extended by this cause.
    applicable : bool
        False when the cause cannot occur in this loop; then ``score`` is inf.
    description : str
        The finding in words ("an unmodelled mode at 97 Hz, damping 2 %, adding to the
        plant").
    choice : Choice or None
        The fitted values as the engine holds them.
    std : dict
        Standard deviation of each of :attr:`parameters` (the Gauss-Newton covariance of
        the joint fit, by the delta method for derived quantities); empty where not
        computed (the ranking) and 0 for a discrete value.
    equivalents : tuple of Equivalent
        Other causes that, in this one's place, explain the data as well (the data do not
        tell them apart; :mod:`~mr_ident.diagnosis.selection.equivalence`), best first.
    """

    cause: str
    parameters: Params
    score: float
    rss: dict[str, float]
    model: Model
    applicable: bool = True
    description: str = ""
    choice: Choice | None = field(default=None, compare=False)
    std: Params = field(default_factory=dict)
    equivalents: tuple[Equivalent, ...] = ()


@dataclass(frozen=True)
class PlantData:
    """The identified plant the proposals start from: P̂_h and its std on bins.

    Attributes
    ----------
    frequency : ndarray, shape (K,)
    response, std : ndarray, shape (K, n_y, n_u)
    """

    frequency: FloatArray
    response: ComplexArray
    std: FloatArray


@dataclass(frozen=True)
class Context:
    """What a cause's proposals may look at.

    Attributes
    ----------
    current : Model
        The model the cause would extend (the nominal with the causes chosen so far).
    nominal : Model
    plant : PlantData or None
        The identified plant.
    objective : Objective
        The time-domain criterion (on the screening part of the record).
    """

    current: Model
    nominal: Model
    plant: PlantData | None
    objective: Objective


class Cause:
    """A way the nominal model can be wrong (see the module docstring).

    Subclasses set :attr:`name`, :attr:`parameters` (names of ``Choice.x`` in the report),
    :attr:`meaning` (the README's physical meaning), :attr:`extends` (the model-file key the
    fit writes) and implement :meth:`proposals`, :meth:`bounds`, :meth:`apply` and
    :meth:`describe`. :attr:`discrete` causes are enumerated, not optimised.
    """

    name: ClassVar[str]
    parameters: ClassVar[tuple[str, ...]] = ()
    meaning: ClassVar[str] = ""
    extends: ClassVar[str] = ""
    #: May be chosen again on top of itself (a second mode, a second disturbance).
    repeatable: ClassVar[bool] = False
    #: Integer-valued: every proposal is scored, none optimised.
    discrete: ClassVar[bool] = False
    #: Also changes P_h (a plant-side cause); else only the loop or the output.
    plant_side: ClassVar[bool] = True
    #: In the controller's path (what it samples, computes and applies): the controller's
    #: own equation decides it (:mod:`~mr_ident.diagnosis.controller.relation`).
    controller_side: ClassVar[bool] = False
    #: Indices of ``Choice.x`` in which the simulated output is affine (a disturbance's
    #: in-phase and quadrature amplitudes): solved by least squares at every proposal
    #: before it is scored, so a start with the wrong phase is not ranked out.
    linear: ClassVar[tuple[int, ...]] = ()

    @property
    def n_free(self) -> int:
        """Free parameters counted by the information criterion."""
        return len(self.parameters)

    def free_in(self, choice: Choice) -> int:
        """The free values of ``choice`` (a cause whose size varies counts its own)."""
        return self.n_free

    def applies(self, nominal: Model) -> bool:
        """Whether the cause can occur in the loop of ``nominal``."""
        return True

    def proposals(self, ctx: Context) -> list[Choice]:
        """Starting points for the fit on top of ``ctx.current`` (best guesses first)."""
        raise NotImplementedError

    def values(self, nominal: Model) -> list[float]:
        """Every value of a :attr:`discrete` cause on top of ``nominal``."""
        return []

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Lower and upper bounds of ``choice.x`` and its typical scale."""
        raise NotImplementedError

    def apply(self, model: Model, choice: Choice) -> Model:
        """``model`` extended by this cause with the values of ``choice``."""
        raise NotImplementedError

    def value_names(self, choice: Choice) -> tuple[str, ...]:
        """The names of ``choice.x`` (:attr:`parameters`, unless their number varies)."""
        return self.parameters

    def named(self, choice: Choice, nominal: Model) -> Params:
        """The parameters by name (the report's and the model file's quantities)."""
        return {k: float(v) for k, v in zip(self.parameters, choice.x, strict=True)}

    def describe(self, params: Params) -> str:
        """The finding in words."""
        return self.meaning


def percent(x: float) -> str:
    """A ratio as a signed percentage change ("+21 %")."""
    return f"{100.0 * (x - 1.0):+.0f} %"


def damping_percent(zeta: float) -> str:
    """A damping ratio in per cent, two significant figures, never in exponent form.

    >>> damping_percent(0.0213), damping_percent(1.0), damping_percent(0.39)
    ('2.1 %', '100 %', '39 %')
    """
    return f"{float(f'{100.0 * zeta:.2g}'):g} %"


def hz(f: float) -> str:
    """A frequency for the report, three significant figures."""
    return f"{f:.3g} Hz"


def clip(x: ArrayLike, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """``x`` inside the bounds (strictly, so that least squares may start there)."""
    span = np.asarray(hi, float) - np.asarray(lo, float)
    pad = np.where(np.isfinite(span), 1e-9 * span, 0.0)
    return np.clip(np.asarray(x, float), np.asarray(lo) + pad, np.asarray(hi) - pad)
