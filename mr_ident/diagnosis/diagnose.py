# SPDX-License-Identifier: Apache-2.0
"""Model validation: where a nominal model is wrong, why, and how much a fix gains.

Given measured r_h, u_h, y_h (a :class:`~mr_ident.numerics.signals.LoopData` with its
rates) and a nominal :class:`~mr_ident.numerics.systems.model.Model`, :func:`diagnose`:

1. **Where** (:mod:`~mr_ident.diagnosis.criterion.evidence`): the identified P̂_h (and, with a
   controller, the lifted J̃ and S̃) against the model's, bin by bin in σ units, with a
   test whose false-alarm rate under noise alone is at most ``alpha``.
2. **The controller's own equation** (:mod:`~mr_ident.diagnosis.controller.relation`):
   in closed loop the logged u must be the model controller's output for the logged y
   and r, with no noise between them. Where it is, no cause sits in the controller's
   path; where a notch, control delay or sampling offset makes it so, that cause is
   applied with its exact values before the plant's are sought; where nothing does, the
   controller-side causes stay in the search below.
3. **Why** (:mod:`~mr_ident.diagnosis.causes.cause`): every cause of the registry is a
   parametric extension of the model, fitted to the data by least squares on the
   whitened spectrum of the simulation residual y - ŷ
   (:class:`~mr_ident.diagnosis.criterion.objective.Objective`, noise from
   :mod:`~mr_ident.diagnosis.criterion.noise`). Causes are ranked by the Bayesian information
   criterion ``BIC = 2 sum_k |E(k)|^2 / S(k) + p ln n`` (n the number of bins, p the
   cause's free parameters; lower is better). The model being extended is the cause
   ``none`` (p = 0). A cause is accepted only when its BIC is below that of the model it
   extends; accepted causes are applied greedily (up to ``max_causes``), each step
   re-ranking the rest against the extended model.
4. **Validation decides** (:mod:`~mr_ident.diagnosis.selection.validation`): the chosen
   causes, their values fixed, are held against the validation data on the same criterion;
   only those whose gain there is significant (level ``alpha``) are applied, and only when
   together they also raise the fit of y there; else no extension is validated.
5. **Gain** (:mod:`~mr_ident.diagnosis.criterion.prediction`): fit % of y and u, and the FRF error
   in σ units, of the nominal and the extended model on validation data.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ParamSpec

import numpy as np

from ..errors import ConfigError, DataError
from ..numerics.excitation.bla import BandLevels
from ..numerics.identify import default_n
from ..numerics.lifted.pfg_check import ControllerCheck, check_controller
from ..numerics.signals import LoopData
from ..numerics.systems.model import Model
from ..numerics.threads import one_blas_thread
from .causes.cause import CauseFit, PlantData
from .causes.registry import build
from .controller.frf import ControllerFRF, where_differs
from .controller.relation import (
    ControllerPath,
    ControllerRelation,
    controller_path,
    settled_fits,
)
from .criterion.correlation import HOS_ALPHA, Correlation, correlation
from .criterion.distortion import NL_THRESHOLD_DB as NL_THRESHOLD_DB  # re-exported
from .criterion.distortion import blind_text, distortion, lines_nonlinear, lines_text
from .criterion.evidence import Evidence, frf_evidence, identify_record
from .criterion.gain import Gain, gain_on
from .criterion.noise import noise_spectrum
from .criterion.nonlinearity import summarize
from .criterion.objective import Objective, settle_samples
from .criterion.prediction import TimeFit, time_fit
from .criterion.realizations import SpreadLevels, records_spread, spread_nonlinear, spread_text
from .criterion.records import Records, plan, with_injection, with_r
from .criterion.records import check_record as check_record  # re-exported
from .criterion.records import min_record as min_record  # re-exported
from .criterion.records import split as split  # re-exported
from .criterion.timevarying import Segments, within
from .criterion.unexplained import (
    Unexplained,
    criterion_noise,
    loop_shaped,
    unexplained,
    with_distortion,
)
from .selection.correction import Correction, correction
from .selection.equivalence import with_equivalents
from .selection.forward import SCREEN_SAMPLES, select
from .selection.headline import Headline, headline
from .selection.validation import Validation, decide


@dataclass(frozen=True)
class Diagnosis:
    """Everything :func:`diagnose` found.

    Attributes
    ----------
    cause : str
        The verdict's cause (:attr:`headline`): the first applied cause,
        ``"nonlinear_distortion"``, ``"plant_correction"``, ``"unexplained"`` or ``"none"``.
    parameters : dict
        Its fitted parameters (or the finding's figures).
    ranking : list of CauseFit
        All causes fitted against the nominal model, best first.
    applied : list of CauseFit
        The causes applied: those the estimation data chose (jointly fitted) that the
        validation data confirm (:attr:`decision`); empty when no extension validated.
    extended : Model
        The nominal model with every applied cause (the nominal when none is).
    evidence_before : Evidence
        Nominal model against the estimation data.
    evidence_after : Evidence
        Extended model against the validation data.
    evidence_validation_before : Evidence
        Nominal model against the validation data.
    fit_before, fit_after : TimeFit
        On the validation data.
    estimation, validation : str
        Which data were used for what.
    controller : ControllerCheck or None
        The PFG from data against the PFG of the model's controller, on the estimation data
        (:mod:`~mr_ident.numerics.lifted.pfg_check`); None in open loop or for periodic
        data.
    criterion : Objective or None
        The estimation criterion every cause was fitted on (the whitened time-domain
        residual of the estimation data), to score another model on the same footing
        (:func:`~mr_bench.verdict.likelihood_ratio`).
    relation : ControllerRelation or None
        The controller's own equation on the estimation data (does the logged u follow
        from the logged y through the model's controller?) and the controller-side causes
        it determined (:mod:`~mr_ident.diagnosis.controller.relation`); None in open loop
        or with y at the low rate.
    decision : Validation or None
        The candidates the estimation data chose and what the validation data decided of
        each (:mod:`~mr_ident.diagnosis.selection.validation`).
    spread : list of SpreadLevels
        The plant estimates of every record given (``data``, ``validation``, ``more``) as
        realizations: their spread against their noise per band
        (:mod:`~mr_ident.diagnosis.criterion.realizations`); [] with one record or the
        same realization twice.
    records : int
        How many records :attr:`spread` compares (1: none).
    correction : Correction or None
        Where the extended model is still wrong on the estimation data: a low-order
        correction of P_h, fitted there and judged on the validation data
        (:mod:`~mr_ident.diagnosis.selection.correction`); in ``extended`` only when it
        validated. None when nothing was left.
    segments : Segments or None
        The plant estimates of consecutive segments of ``data`` against their noise
        (:mod:`~mr_ident.diagnosis.criterion.timevarying`); None when too short.
    unexplained : Unexplained or None
        The extended model's residual on the validation data against the noise: what
        part of y it leaves beyond the noise
        (:mod:`~mr_ident.diagnosis.criterion.unexplained`).
    headline : Headline or None
        The verdict: :attr:`cause` and :attr:`parameters` are its
        (:mod:`~mr_ident.diagnosis.selection.headline`).
    correlation : Correlation or None
        The validated residual's higher-order correlations with the model's signals
        (nonlinear distortion under any excitation,
        :mod:`~mr_ident.diagnosis.criterion.correlation`); None for periodic records
        (they have their own tests) and records too short for it.
    controller_frf : ControllerFRF or None
        Where the logged u is not the model controller's output: the controller's FRF
        identified from the estimation data at the low rate, with its std, beside the model's
        and the applied controller-side causes' (:mod:`~mr_ident.diagnosis.controller.frf`).
    """

    cause: str
    parameters: dict[str, float]
    ranking: list[CauseFit]
    applied: list[CauseFit]
    extended: Model
    evidence_before: Evidence
    evidence_validation_before: Evidence
    evidence_after: Evidence
    fit_before: TimeFit
    fit_after: TimeFit
    estimation: str
    validation: str
    traces: dict[str, Any] = field(default_factory=dict)
    distortion: list[BandLevels] = field(default_factory=list)
    controller: ControllerCheck | None = None
    criterion: Objective | None = field(default=None, repr=False, compare=False)
    relation: ControllerRelation | None = None
    decision: Validation | None = None
    spread: list[SpreadLevels] = field(default_factory=list)
    records: int = 1
    correction: Correction | None = None
    segments: Segments | None = None
    unexplained: Unexplained | None = None
    headline: Headline | None = None
    correlation: Correlation | None = None
    controller_frf: ControllerFRF | None = None

    @property
    def time_varying(self) -> bool:
        """The plant changes within the record: its segments differ beyond their noise.

        Not where the residual's higher-order correlations show nonlinear distortion: a
        nonlinear loop's segments differ with their amplitude, not in time.
        """
        hos = self.correlation is not None and self.correlation.detected
        return self.segments is not None and self.segments.varying and not hos

    @property
    def corrected(self) -> bool:
        """A correction beyond the listed causes validated and is in ``extended``."""
        return self.correction is not None and self.correction.accepted

    @property
    def nonlinear(self) -> bool:
        """Nonlinear distortion stands out of the noise.

        On one periodic record's unexcited lines (:func:`distortion`): a band's odd or even
        level counts above :data:`NL_THRESHOLD_DB` and above what noise alone reaches on as
        few lines with probability 1e-3 (its ``*_threshold_db``); across records of other
        realizations (:attr:`spread`), a band's spread the same way; under any excitation,
        the validated residual's higher-order correlations (:attr:`correlation`).
        """
        hos = self.correlation is not None and self.correlation.detected
        return lines_nonlinear(self.distortion) or spread_nonlinear(self.spread) or hos

    def distortion_text(self) -> str:
        """The finding in words, or "" when there is none."""
        parts = [lines_text(self.distortion), spread_text(self.spread, self.records)]
        parts += [self.correlation.text()] if self.correlation is not None else []
        return "; ".join(p for p in parts if p)

    def blind_text(self) -> str:
        """Why this record cannot show odd distortion, and what would; "" when it can."""
        return blind_text(self.distortion, self.records)


_P = ParamSpec("_P")


def _numeric_trouble_reported(fn: Callable[_P, Diagnosis]) -> Callable[_P, Diagnosis]:
    """Numeric trouble in the simulation or the fits becomes a DataError.

    A reported ``error:``, never a traceback. NumPy's and SciPy's BLAS on one thread
    meanwhile: on the fits' thin products and SVDs their threads cost more than they give
    (docs/benchmarks.md, "Diagnosis speed").
    """

    @functools.wraps(fn)
    def wrapper(*args: _P.args, **kwargs: _P.kwargs) -> Diagnosis:
        try:
            with one_blas_thread(with_scipy=True):
                return fn(*args, **kwargs)
        except (ArithmeticError, np.linalg.LinAlgError, Warning) as err:
            raise DataError(
                f"diagnose failed on a numeric problem ({type(err).__name__}: {err}); the "
                "model may be badly conditioned (very high order, poles far apart) or the "
                "data too short"
            ) from None

    return wrapper


@_numeric_trouble_reported
def diagnose(
    model: Model,
    data: LoopData,
    validation: LoopData | None = None,
    *,
    n: int | str | None = None,
    degree: int = 2,
    alpha: float = 0.01,
    max_causes: int = 3,
    holdout: float = 0.3,
    names: tuple[str, str] = ("data", "validation data"),
    more: Sequence[LoopData] = (),
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Where and why ``model`` disagrees with ``data``, the extended model, and its gain.

    Parameters
    ----------
    model : Model
        Nominal model.
    data : LoopData
        Measured data for estimation (and, without ``validation``, its last
        ``holdout`` fraction is held out for validation).
    validation : LoopData, optional
        Independent validation data.
    n : int or "auto", optional
        LPM window half-width for the frequency-domain evidence (default and "auto":
        :func:`~mr_ident.numerics.identify.default_n`; the per-bin test compares against
        one noise-estimate dof, so diagnose keeps one window for all bins).
    degree : int
        LPM polynomial degree.
    alpha : float
        Family-wise false-alarm level of the per-bin test (default 0.01).
    max_causes : int
        Most causes applied in turn.
    names : (str, str)
        What to call ``data`` and ``validation`` in error messages (e.g. their files).
    more : sequence of LoopData
        Further records of other excitation realizations: with ``data`` and
        ``validation`` they are compared as realizations (:attr:`Diagnosis.spread`).
    progress : callable, optional
        Told the name of each step as it begins (the command line shows the slow ones).

    Raises
    ------
    DataError
        Model and data disagree on rates or channels, or the data are too short.

    Examples
    --------
    The plant's gain is 30 % higher than the model says; diagnose names the cause,
    measures it and gives the extended model:

    >>> import dataclasses
    >>> import numpy as np
    >>> from mr_ident import simulate
    >>> from mr_ident.diagnosis import diagnose
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [10.0], "den": [1.0, 10.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> true = dataclasses.replace(model, plant_gain=1.3, noise_std=0.01)
    >>> data = simulate(true, duration=20.0, rng=np.random.default_rng(0))
    >>> d = diagnose(model, data)
    >>> d.cause, round(d.parameters["gain"], 2), d.extended.plant_gain == d.parameters["gain"]
    ('gain_error', 1.3, True)
    """

    def tell(step: str) -> None:
        if progress is not None:
            progress(step)

    n = _window(model, n, degree, alpha, holdout)
    check_record(model, data, n=n, what=names[0])
    model = with_injection(model, data, None)  # r where the data show it entered
    data = with_r(model, data, names[0])  # r's holes recovered (the simulation reads r)
    more = [with_r(model, other, f"record {j + 3}") for j, other in enumerate(more)]
    recs = plan(model, data, validation, n=n, holdout=holdout, names=names, more=more)
    est = recs.est
    tell("identifying the plant on the estimation data")
    ident = identify_record(est, model, n=n, degree=degree)
    ev_before = frf_evidence(model, est, n=n, degree=degree, alpha=alpha, ident=ident)
    noise = noise_spectrum(est, model, n=n, degree=degree, ident=ident)
    tell("checking the controller's own equation")
    path = controller_path(model, est, noise)
    tell("fitting and selecting the causes")
    plant = PlantData(ev_before.frequency, ev_before.P_hat, ev_before.P_std)
    ranking, chosen = _chosen_causes(path, model, est, plant, max_causes)
    ident_val = identify_record(recs.val_part, model, n=n, degree=degree)

    @functools.cache
    def val_objective() -> Objective:
        noise_val = noise_spectrum(recs.val_part, model, n=n, degree=degree, ident=ident_val)
        return Objective(recs.val_part, model, noise_val)

    tell("validating the causes on the validation data")
    check, applied = _validated(model, recs, chosen, val_objective, alpha=alpha)
    current = applied[-1].model if applied else model
    # where the listed causes end: a correction on the validated model, applied only when it
    # validates
    tell("trying a correction of the plant")
    corr = correction(
        model, current, est, ident, recs.val, recs.cut, n=n, degree=degree, alpha=alpha
    )
    current = corr.model if corr is not None and corr.model is not None else current
    tell("measuring the gain on the validation data")
    gain = gain_on(
        model, current, recs, _val_start(model, recs), ident_val, n=n, degree=degree, alpha=alpha
    )
    tell("testing for nonlinear distortion")
    spread, records = records_spread(
        [data, *([] if validation is None else [validation]), *more],
        model,
        n,
        degree,
        (ident,) if validation is None else (ident, ident_val),
    )
    lines = distortion(est)
    hos = correlation(current, recs.val, gain.start, gain.pred_after, alpha=HOS_ALPHA)
    left = _unexplained(model, current, recs, gain, hos, val_objective)
    # random records: their LPM noise holds the distortion, the spread across them names
    # it only by chance (a finding, not the verdict); the correlations do instead
    found = summarize(lines, spread if data.period is not None else [], hos)
    verdict = headline(applied, corr is not None and corr.accepted, found, left)
    tell("testing for a plant that changes in time")
    segments = within(data, model, n=n, degree=degree)
    return Diagnosis(
        cause=verdict.cause,
        parameters=verdict.parameters,
        ranking=ranking,
        applied=applied,
        extended=current,
        evidence_before=ev_before,
        evidence_validation_before=gain.evidence_before,
        evidence_after=gain.evidence_after,
        fit_before=gain.fit_before,
        fit_after=gain.fit_after,
        estimation=recs.est_desc,
        validation=recs.val_desc,
        traces=gain.traces,
        distortion=lines,
        controller=None if ident is None else check_controller(ident, n),
        criterion=path.criterion,
        relation=path.relation,
        decision=check,
        spread=spread,
        records=records,
        correction=corr,
        segments=segments,
        unexplained=left,
        headline=verdict,
        correlation=hos,
        controller_frf=where_differs(model, est, path.relation, applied, n=n, degree=degree),
    )


def _window(model: Model, n: int | str | None, degree: int, alpha: float, holdout: float) -> int:
    """The options checked; the LPM half-width of the evidence (one window for all bins)."""
    if not 0.0 < alpha < 1.0:
        raise ConfigError(f"alpha must be in (0, 1), got {alpha!r}")
    if isinstance(n, str) and n != "auto":
        raise ConfigError(f'n must be an integer >= 1 or "auto", got {n!r}')
    if not 0.05 <= holdout <= 0.5:
        raise ConfigError(f"holdout must be in [0.05, 0.5], got {holdout!r}")
    if n is None or isinstance(n, str):  # the evidence test needs one window (one dof) for all
        return default_n("freq-lifted", degree, model.ratio, model.n_u, max(model.n_u, model.n_y))
    return n


def _chosen_causes(
    path: ControllerPath, model: Model, est: LoopData, plant: PlantData, max_causes: int
) -> tuple[list[CauseFit], list[CauseFit]]:
    """Every cause ranked on the estimation data, and the set it chose (settled ones first)."""
    full, base = path.criterion, path.base
    unit = est.period or model.ratio
    # the screening part: whole periods (at least 8) or a multiple of F, periodic data too
    n_screen = min(est.n_samples, max(SCREEN_SAMPLES // unit, 8) * unit)
    screen = (
        full if n_screen == est.n_samples else Objective(est.part(0, n_screen), base, path.noise)
    )
    sel = select(full, screen, base, plant, max_causes=max_causes, ruled_out=path.why)
    chosen = settled_fits(full, model, path.relation) + with_equivalents(
        full, screen, base, plant, sel.chosen, sel.ranking
    )
    return sel.ranking, chosen


def _validated(
    model: Model,
    recs: Records,
    chosen: list[CauseFit],
    val_objective: Callable[[], Objective],
    *,
    alpha: float,
) -> tuple[Validation, list[CauseFit]]:
    """What the validation data decide of ``chosen``, and the causes they validated.

    Each validated cause with those before it in its model.
    """
    start = _val_start(model, recs)

    def fit_of(m: Model) -> TimeFit:
        return time_fit(m, recs.val, start)

    check = decide(val_objective, model, chosen, fit_of, alpha=alpha, start=recs.cut)
    applied = [
        replace(c, model=build(model, [a.choice for a in check.applied[: j + 1] if a.choice]))
        for j, c in enumerate(check.applied)
    ]
    return check, applied


def _unexplained(
    model: Model,
    current: Model,
    recs: Records,
    gain: Gain,
    hos: Correlation | None,
    val_objective: Callable[[], Objective],
) -> Unexplained | None:
    """What the extended model leaves of y on the validation data, against the noise."""
    val = recs.val
    # periodic: the residual's spread over periods (a periodic distortion left out)
    noise_var = None if recs.val_part.period is not None else criterion_noise(val_objective())
    if noise_var is not None and hos is not None and hos.detected:
        # the LPM's level holds the distortion: each output's correlation rest bounds its noise
        shaped = loop_shaped(hos.rest_vars, model, val.n_samples - gain.start)
        noise_var = np.minimum(noise_var, shaped)
    left = unexplained(current, val, gain.start, gain.pred_after, noise_var)
    if hos is not None and hos.detected:
        left = with_distortion(left, hos.fitted_vars, hos.rest_vars)
    return left


def _val_start(model: Model, recs: Records) -> int:
    """Where the validation fit starts: the cut, or past the transient of separate data."""
    if not recs.cut and model.controller is not None and recs.val.period is None:
        return settle_samples(model, recs.val.n_samples)
    return recs.cut
