# SPDX-License-Identifier: Apache-2.0
"""Where the vocabulary ends: a low-order correction of P_h, offered only when it validates.

After the best causes, the extended model is held against the estimation data's FRF again
(:func:`~mr_ident.diagnosis.criterion.evidence.frf_evidence`), seen through the same
estimator (:func:`~mr_ident.diagnosis.criterion.matched.matched_evidence`: the local fit of
the model's output error, so that the fit's bias and misfit at the lowest bins cancel and
every bin is tested, those whose window reaches DC included); where bins are still
significant, no listed cause explains them. An error spread thinly over many bins, none of
them significant alone, is seen by the total of the squared σ-errors over the tested bins
against its null (:mod:`~mr_ident.diagnosis.criterion.broadband`); when either test is
significant, a stable low-order correction ``C`` of the
plant at the high rate is fitted to what is left (on every bin: the lowest ones hold its
low-frequency end), weighted by the matched std
(:func:`~mr_ident.numerics.fit.frf_fit.fit_frf`, discrete at ``1/fs_high``, so that no hold
or delay is assumed):

- **additive**: ``P_h + C``, fitted to ``P̂ - P̂_ext`` with σ̂ (``P̂_ext`` the extended
  model seen through the estimator: without its bias, the lowest bins' "correction" was a
  real pole at 0.001 Hz fitted to that bias);
- **multiplicative** (one input and one output): ``P_h (1 + C)``, fitted to
  ``(P̂ - P̂_ext) / P_ext`` with ``σ̂ / |P_ext|`` (C has a direct term: a pole-zero pair's
  ratio does not vanish at high frequency).

Every kind and order 1..:data:`MAX_ORDER` (states; a pair counts two) is a candidate, and
higher orders while the validation asks for them: past :data:`MAX_ORDER` one more at a time,
per kind, up to :data:`ORDER_CAP`, until :data:`PATIENCE` orders in a row gave no lower
validation BIC than the kind's lowest (a correction settled by order 4 costs nothing more).
A second delay path ``u + c u[n-d]`` is the comb ``1 + c z^-d``: d states, its poles at
z = 0, which the modal fit (distinct poles) places on a small circle (``c / (z^d - r^d)``,
within the noise at order d).

Each is judged on data it was not fitted on (the validation record, or the held-out part):
the criterion of the causes (:class:`~mr_ident.diagnosis.criterion.objective.Objective`,
whitened by the validation data's own noise level, taken from the causes' output error
identified as the data are, :func:`~mr_ident.diagnosis.criterion.matched.output_error`,
the noise before the loop shapes it: from y itself the local fit's misfit reads as noise,
at the lowest bins of the benchmark's loops hundreds to millions of times the noise, and a
correction's gain there went unseen) as ``BIC = 2 J + p ln n``, p the
correction's real parameters. A candidate validates when its BIC is lower than both the
nominal's and the extended model's ``2 J`` by more than the selection's
:data:`~mr_ident.diagnosis.selection.forward.ACCEPT_MARGIN`, its validation fit of y is
higher than both, and its gain against both is significant on the test the listed causes
must pass (:func:`~mr_ident.diagnosis.selection.validation.gain`: ``z > z_{1-alpha}``,
the noise taken at the level of the corrected model's residual where the two differ, so
that unmodelled nonlinear distortion, which inflates the BIC's differences alike for any
change, counts as noise; a gain on a few bins, a resonance's, is judged as surely as one
spread over the band). Of those that validate, the one of lowest BIC is applied (the
order thus chosen on the validation data); when none does, the lowest of all is reported
as a candidate that did not validate. Its words: :mod:`.correction_text` (past six poles
and zeros counted and summarised); the JSON lists every pole.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ...errors import MrIdentError
from ...numerics.arrays import FloatArray
from ...numerics.fit.frf_fit import fit_frf
from ...numerics.results import FRF, Identification
from ...numerics.signals import LoopData
from ...numerics.systems.modal import ModalPlant
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import loop_poles
from ..criterion.broadband import Broadband, broadband
from ..criterion.evidence import Evidence, frf_evidence, identify_record
from ..criterion.matched import matched_evidence, output_error
from ..criterion.noise import noise_spectrum
from ..criterion.objective import Objective, settle_samples
from ..criterion.prediction import time_fit
from .correction_text import describe, poles_text
from .forward import ACCEPT_MARGIN
from .validation import critical, gain, later

#: Orders (states) of a correction always tried: 1..MAX_ORDER.
MAX_ORDER = 4
#: Highest order tried: past :data:`MAX_ORDER` only while the validation BIC still falls.
ORDER_CAP = 12
#: Orders in a row without a lower validation BIC (per kind) after which none higher is tried.
PATIENCE = 2


@dataclass(frozen=True)
class Candidate:
    """One correction fitted on the estimation data and scored on the validation data.

    ``kind`` "additive" or "multiplicative"; ``order`` its states; ``correction`` C
    (discrete at 1/fs_high); ``model`` the extended model with it; ``n_params`` its real
    parameters; ``bic`` ``2 J + p ln n`` on the validation criterion; ``fit_y`` the
    validation fit of y in %; ``z_nominal``, ``z_causes`` its gain's z statistics against
    the nominal and the extended model (module docstring).
    """

    kind: str
    order: int
    correction: ModalPlant
    model: Model
    n_params: int
    bic: float
    fit_y: float
    z_nominal: float = math.nan
    z_causes: float = math.nan


@dataclass(frozen=True)
class Correction:
    """What :func:`correction` found where the listed causes end.

    Attributes
    ----------
    bands : list of (float, float)
        Hz: where the extended model was still significantly wrong on the estimation data
        (bin by bin; the tested range when only the broadband test was significant).
    best : Candidate or None
        Of the candidates that validate, the one of lowest validation BIC; when none does,
        the lowest of all (None: no candidate could be fitted).
    candidates : tuple of Candidate
        Every kind and order tried (that could be fitted and left the loop stable).
    accepted : bool
        ``best`` validates better than the nominal and than the causes (module docstring).
    score_nominal, score_causes : float
        ``2 J`` of the nominal and of the extended model on the validation criterion.
    z_nominal, z_causes : float
        The best candidate's gain's z statistic against each (module docstring).
    z_critical : float
        ``z_{1-alpha}``.
    fit_nominal, fit_causes : float
        Their validation fits of y (%).
    broadband : Broadband or None
        The broadband test of the extended model on the estimation data.
    per_bin : bool
        Some bin was significant (False: only the broadband test was, the error thin).
    """

    bands: list[tuple[float, float]]
    best: Candidate | None
    candidates: tuple[Candidate, ...]
    accepted: bool
    score_nominal: float
    score_causes: float
    fit_nominal: float
    fit_causes: float
    z_nominal: float = math.nan
    z_causes: float = math.nan
    z_critical: float = math.nan
    broadband: Broadband | None = None
    per_bin: bool = True

    @property
    def thin(self) -> bool:
        """Only the broadband test was significant (no single bin was)."""
        return not self.per_bin

    @property
    def model(self) -> Model | None:
        """The extended model with the correction when accepted, else None."""
        return self.best.model if self.accepted and self.best is not None else None

    @property
    def gain(self) -> float:
        """Validation BIC of the best candidate below the better of nominal and causes."""
        if self.best is None:
            return -math.inf
        return min(self.score_nominal, self.score_causes) - self.best.bic

    def text(self) -> str:
        """The finding in words (what the correction is, and what it gained or did not)."""
        where = (
            ", ".join(f"{lo:.3g}-{hi:.3g} Hz" for lo, hi in self.bands)
            if len(self.bands) <= 3
            else f"{len(self.bands)} bands between {self.bands[0][0]:.3g} and "
            f"{self.bands[-1][1]:.3g} Hz"
        )
        if self.thin and self.broadband is not None:
            where += (
                f" (spread thinly: no bin significant alone, the total "
                f"{self.broadband.z:.1f} sd above the noise's)"
            )
        if self.best is None:
            return f"not a listed cause at {where}, and no stable correction could be fitted"
        b = self.best
        fits = (
            f"validation fit of y {self.fit_nominal:.1f} % (nominal), {self.fit_causes:.1f} % "
            f"(causes), {b.fit_y:.1f} % (with it); validation BIC {-self.gain:+.1f}, z "
            f"{min(self.z_nominal, self.z_causes):.1f}"
        )
        what = f"not a listed cause at {where}: {describe(b.kind, b.correction)}"
        if self.accepted:
            return f"{what} ({fits})"
        return f"{what}, not applied: it did not validate ({fits})"

    def summary(self) -> dict[str, object]:
        """The JSON-ready account (the report's ``correction``)."""
        b = self.best
        return {
            "accepted": self.accepted,
            "description": self.text(),
            "bands_hz": [list(x) for x in self.bands],
            "kind": None if b is None else b.kind,
            "order": None if b is None else b.order,
            "poles": [] if b is None else poles_text(b.correction),
            "validation_score_nominal": _finite(self.score_nominal),
            "validation_score_causes": _finite(self.score_causes),
            "validation_bic": None if b is None else _finite(b.bic),
            "fit_nominal": _finite(self.fit_nominal),
            "fit_causes": _finite(self.fit_causes),
            "fit_corrected": None if b is None else _finite(b.fit_y),
            "z_nominal": _finite(self.z_nominal),
            "z_causes": _finite(self.z_causes),
            "z_critical": _finite(self.z_critical),
            "broadband": None if self.broadband is None else self.broadband.summary(),
            "candidates": [
                {
                    "kind": c.kind,
                    "order": c.order,
                    "validation_bic": _finite(c.bic),
                    "fit_y": _finite(c.fit_y),
                }
                for c in self.candidates
            ],
            "criterion": "2 J + p ln n on the validation data's whitened residual (J of the "
            f"causes' criterion); accepted when below the nominal's and the causes' 2 J by "
            f"more than {ACCEPT_MARGIN:g}, the validation fit of y higher than both, and the "
            "gain significant against both (z > z_critical, the test of the listed causes)",
        }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def window(ident: Identification | None, n: int) -> int:
    """The LPM's window half-width of ``ident`` (median of ``n_used``; 0: periodic lines)."""
    if ident is None:
        return 0
    used = ident.median_window
    return n if used is None else used


def _targets(ev: Evidence, multiplicative: bool) -> FRF | None:
    """What the correction must fit on the evidence's bins: P̂ - P or P̂ / P - 1, with σ.

    ``ev`` matched (:func:`~mr_ident.diagnosis.criterion.matched.matched_evidence`): its
    ``P̂ - P`` is the data's estimate less the model's through the same estimator, its σ
    the noise's. Every bin with a finite std, those whose window reaches DC too (they hold
    the correction's low-frequency end: without them a benchmark pole-zero pair at 2.7 Hz,
    corrected with them, was fitted a correction that validated worse).
    """
    f, P_hat, std, P = ev.frequency, ev.P_hat, ev.P_std, ev.P_model
    if not multiplicative:
        H, S = P_hat - P, std
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            H, S = P_hat / P - 1.0, std / np.abs(P)
    ok = (f > 0) & np.all(np.isfinite(H) & np.isfinite(S) & (S > 0), axis=(1, 2))
    if ok.sum() < 8:
        return None
    return FRF(f[ok], H[ok], S[ok], "correction")


def _stable(model: Model) -> bool:
    try:
        return bool(np.max(np.abs(loop_poles(model)), initial=0.0) < 1.0)
    except (MrIdentError, ArithmeticError, ValueError, np.linalg.LinAlgError):
        return False


def correction(
    nominal: Model,
    current: Model,
    est: LoopData,
    ident: Identification | None,
    val: LoopData,
    val_start: int,
    *,
    n: int,
    degree: int,
    alpha: float,
) -> Correction | None:
    """A correction of ``current`` where it is still wrong on ``est`` (module docstring).

    Parameters
    ----------
    nominal, current : Model
        The nominal model and the model with the best causes (the one corrected).
    est : LoopData
        The estimation data; ``ident`` its identification
        (:func:`~mr_ident.diagnosis.criterion.evidence.identify_record`).
    val : LoopData
        The validation data from sample ``val_start`` on (held out when > 0, the record
        simulated from its start so that the state carries over).
    n, degree, alpha
        As :func:`~mr_ident.diagnosis.diagnose.diagnose`.

    Returns
    -------
    Correction or None
        None when nothing is significant any more on the estimation data: no bin, nor the
        total over the band (:mod:`~mr_ident.diagnosis.criterion.broadband`).
    """
    ev = frf_evidence(current, est, n=n, degree=degree, alpha=alpha, ident=ident)
    ev = matched_evidence(ev, current, est, n=n, degree=degree, alpha=alpha)  # every bin tested
    bb = broadband(ev, n=window(ident, n), degree=degree, alpha=alpha)
    per_bin = bool(ev.significant.any())
    if not per_bin and not bb.significant:
        return None
    f_tested = ev.frequency[ev.tested]
    bands = ev.bands() if per_bin else [(float(f_tested.min()), float(f_tested.max()))]
    siso = nominal.n_u == 1 and nominal.n_y == 1
    kinds = ("additive", "multiplicative") if siso else ("additive",)
    targets = {k: t for k in kinds if (t := _targets(ev, k == "multiplicative")) is not None}
    fits = {k: [_fit(t, nominal.fs_high, o, k) for o in range(1, MAX_ORDER + 1)]
            for k, t in targets.items()}  # fmt: skip
    if not any(C is not None for row in fits.values() for C in row):
        return Correction(bands, None, (), False, *(math.nan,) * 4, broadband=bb, per_bin=per_bin)
    val_part = val.part(val_start, val.n_samples) if val_start else val
    start = val_start
    if not start and nominal.controller is not None and val.period is None:
        start = settle_samples(nominal, val.n_samples)  # separate data: skip the transient
    # the noise without the local fit's misfit: from the causes' output error (matched.py)
    # (periodic data: the noise from the period spread, no local fit, so no output error)
    seen = later(current, val_start)  # a fitted disturbance's phase on the held-out part
    periodic = val_part.period is not None
    err_val = None if periodic else output_error(seen, val_part)
    ident_val = (
        None if periodic else identify_record(err_val or val_part, nominal, n=n, degree=degree)
    )
    noise = noise_spectrum(
        val_part, nominal, n=n, degree=degree, ident=ident_val, shaped=err_val is None
    )
    crit = Objective(val_part, nominal, noise)
    fit_nom = time_fit(nominal, val, start).y
    fit_cur = fit_nom if current is nominal else time_fit(current, val, start).y
    power_nom = _bin_power(crit, nominal)
    power_cur = power_nom if current is nominal else _bin_power(crit, seen)
    score_nom, score_cur = 2.0 * float(power_nom.sum()), 2.0 * float(power_cur.sum())
    z_crit = critical(alpha)

    def score(kind: str, order: int, C: ModalPlant) -> Candidate | None:
        """C scored on the validation data (None: the loop with it is unstable)."""
        model = replace(current, plant_corrections=(*current.plant_corrections, (kind, C)))
        if not _stable(model):
            return None
        p = _n_params(C, kind == "multiplicative")
        moved = later(model, val_start)
        power = _bin_power(crit, moved)
        bic = 2.0 * float(power.sum()) + p * math.log(crit.n_bins)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fy = time_fit(model, val, start).y
        z_nom = gain(crit, nominal, moved).z
        z = (z_nom, z_nom if current is nominal else gain(crit, seen, moved).z)
        return Candidate(kind, order, C, model, p, bic, fy if math.isfinite(fy) else -1e9, *z)

    cands = [
        c
        for kind, target in targets.items()
        for c in _ladder(kind, target, nominal.fs_high, fits[kind], score)
    ]

    def validates(c: Candidate) -> bool:
        return (
            c.bic < min(score_nom, score_cur) - ACCEPT_MARGIN
            and c.fit_y > max(fit_nom, fit_cur)
            and min(c.z_nominal, c.z_causes) > z_crit
        )

    good = [c for c in cands if validates(c)]
    best = min(good or cands, key=lambda c: c.bic, default=None)
    z_nom, z_cur = (math.nan, math.nan) if best is None else (best.z_nominal, best.z_causes)
    return Correction(bands, best, tuple(cands), bool(good), score_nom, score_cur, fit_nom,
                      fit_cur, z_nom, z_cur, z_crit, bb, per_bin)  # fmt: skip


def _ladder(
    kind: str,
    target: FRF,
    fs: float,
    first: list[ModalPlant | None],
    score: Callable[[str, int, ModalPlant], Candidate | None],
) -> list[Candidate]:
    """The candidates of one kind: orders 1..:data:`MAX_ORDER` (``first``, fitted), then up.

    Past :data:`MAX_ORDER` one order at a time, up to :data:`ORDER_CAP`, until
    :data:`PATIENCE` orders in a row gave no lower validation BIC than the kind's lowest so
    far (an order that could not be fitted, or left the loop unstable, gives none): a
    correction that had settled by order 4 costs nothing more.
    """
    out: list[Candidate] = []
    lowest, idle = math.inf, 0
    for order in range(1, ORDER_CAP + 1):
        if order > MAX_ORDER and idle >= PATIENCE:
            break
        C = first[order - 1] if order <= MAX_ORDER else _fit(target, fs, order, kind)
        c = None if C is None else score(kind, order, C)
        if c is not None:
            out.append(c)
        if c is not None and c.bic < lowest:
            lowest, idle = c.bic, 0
        else:
            idle += 1
    return out


def _bin_power(crit: Objective, model: Model) -> FloatArray:
    """Per bin (and output) the whitened squared residual ``|E_k|² / S_k`` of ``model``."""
    r = crit.residuals(model)
    half = r.size // 2
    return np.asarray(r[:half] ** 2 + r[half:] ** 2, float)


def _n_params(C: ModalPlant, direct: bool) -> int:
    no, ni = C.shape
    return C.order * (1 + no * ni) + (no * ni if direct else 0)


def _fit(target: FRF, fs: float, order: int, kind: str) -> ModalPlant | None:
    """A stable discrete C of ``order`` states fitted to ``target``; None when none is.

    With a direct term when multiplicative (``1 + C`` need not tend to 1 at high frequency).
    """
    direct = kind == "multiplicative"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fit_frf(target, fs=fs, order=order, domain="discrete", direct=direct)
    except (MrIdentError, ArithmeticError, ValueError, np.linalg.LinAlgError):
        return None
    C = res.plant
    if res.delay or not np.all(np.abs(C.poles) < 1.0) or not np.all(np.isfinite(C.residues)):
        return None
    return C
