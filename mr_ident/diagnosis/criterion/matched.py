# SPDX-License-Identifier: Apache-2.0
"""The model seen through the same estimator: its output error identified as the data are.

:func:`~.evidence.frf_evidence` holds the identified P̂ against the model's exact P. Two
things blind it at the lowest bins, where the plant bends fast (an integrator's 1/f²):

- the local fit's *bias*: a window that reaches DC is one-sided, and its polynomial cannot
  follow the plant there (an exact model's first bin read up to 85 σ); those bins are left
  untested;
- its *std*: σ̂ comes from the residual of the local fit, which holds the same misfit.
  Identified from the model's own noise-free loop under the record's r, the std at the
  lowest bins is that of the data (measured on the benchmark's pole-zero pairs and delay
  paths: the ratio 0.9-1.1 up to bin 30, in some records bin 100): it is the misfit, not
  the noise, and an error of 6 % there (a second delay path whose validation residual
  was 6.8 times the true loop's) read 0.2 σ.

Both are properties of the estimator applied to the plant, not of the noise, so they
cancel when the estimator sees the *model's output error* instead of y. The record's
measured u (what drove the plant; missing samples estimated as the open-loop prediction
does, :func:`~.prediction.driving_input`) drives the model's plant, disturbances
included, from rest; its output is taken from y:

    e = y - P_M u - O x̂₀,

``O x̂₀`` the plant's free response from the initial state of least squares (the record
need not start at rest; an integrator's free response, a constant and a ramp, would
otherwise fill the lowest bins); in open loop also the plant's step responses (u's mean,
taken out, drove an integrator's ramp: without them the noise level at the first bins
read 1e5-4e9 times the noise). The record ``(r, u, e)`` is identified with the data's
own settings (:func:`~.evidence.identify_record`: method, window n, degree): as the local
fit is linear in the outputs, its estimate is ``P̂ - P̂_M``, the data's estimate less the
model's seen through the same windows, and its residual holds the noise and what the
model misses, not the plant's misfit. Under "model right" (``y = P_M u + v``) ``e`` is the
noise v, so each bin's ``|P̂ - P̂_M|² / σ̂²`` follows the per-bin test's F(2, 2q), at every
bin, those whose window reaches DC included; the test is the per-bin test's, family-wise
over every bin (:func:`~.evidence.threshold`).

:func:`matched_evidence` returns the :class:`~.evidence.Evidence` of the model with the
data's estimate debiased, ``P_M + (P̂ - P̂_M)``, and the matched std: what the
correction (:mod:`~mr_ident.diagnosis.selection.correction`) tests and fits. Periodic
records (estimated from period means at the excited lines: no local fit) and plants with a
pole outside the unit circle (whose output from the measured u grows beyond the numbers'
reach) are returned unchanged.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from ...numerics.arrays import ComplexArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.lti import StateSpace
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import LoopStream
from .evidence import Evidence, identify_record, threshold
from .prediction import centred, driving_input, grows


@dataclass(frozen=True)
class Matched:
    """The model's output error through the estimator (module docstring), per bin.

    Attributes
    ----------
    frequency : ndarray, shape (K,)
        Hz, the bins of the data's identification.
    difference, std : ndarray, shape (K, n_y, n_u)
        ``P̂ - P̂_M`` (complex) and its std: the identification of the output error.
    dof : int
        Degrees of freedom q of the variance estimate.
    """

    frequency: FloatArray
    difference: ComplexArray
    std: FloatArray
    dof: int

    @property
    def sigma_error(self) -> FloatArray:
        """``max_entries |P̂ - P̂_M| / σ̂`` per bin, shape (K,) (NaN where σ̂ is not finite)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(self.difference) / self.std
        z = np.where(np.isfinite(z), z, np.nan).reshape(z.shape[0], -1)
        out: FloatArray = np.nanmax(np.where(np.isnan(z), -np.inf, z), axis=1)
        return np.where(np.isfinite(out), out, np.nan)

    def n_tests(self) -> int:
        """The finite complex entries: the per-bin test's family."""
        return int(np.isfinite(np.abs(self.difference) / self.std).sum())


def free_response(P: StateSpace, n_samples: int) -> FloatArray:
    """The plant's output from each unit initial state at rest input: (N, n_y, n_x).

    ``C A^k`` of the discrete plant ``P`` (:meth:`~mr_ident.numerics.systems.model.Model.
    plant_discrete`) for k = 0..N-1, by doubling (``[O; O A^m]``, m the rows so far), each
    state's column scaled to unit norm (only the span matters: the least-squares initial
    state of :func:`output_error`).
    """
    A, C = np.asarray(P.A, float), np.asarray(P.C, float)
    nx, ny = A.shape[0], C.shape[0]
    if nx == 0:
        return np.zeros((n_samples, ny, 0))
    rows, power = C[None], A.copy()  # rows (k, n_y, n_x): C A^0 .. C A^(k-1)
    while rows.shape[0] < n_samples:
        rows = np.concatenate([rows, rows @ power], axis=0)
        power = power @ power
    obs = rows[:n_samples]
    norm = np.sqrt(np.sum(obs**2, axis=(0, 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        out: FloatArray = np.where(norm > 0, obs / norm, 0.0)
    return out


def step_responses(P: StateSpace, n_samples: int) -> FloatArray:
    """The plant ``P``'s output from rest to a unit step of each input: (N, n_y, n_u), unit norm.

    In open loop u's mean is taken out (:func:`~.prediction.centred`); what it did to y,
    ``P`` of a constant from the record's start (an integrator's ramp), is in their span.
    """
    from ...numerics.systems.simulate import StateRecursion

    n_u = np.asarray(P.B).shape[1]
    with warnings.catch_warnings():  # an integrator's Jordan block: the direct recursion
        warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
        out = np.stack(
            [StateRecursion(P).run(np.ones((n_samples, 1)) * np.eye(n_u)[j]) for j in range(n_u)],
            axis=2,
        )
    norm = np.sqrt(np.sum(out**2, axis=(0, 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled: FloatArray = np.where(norm > 0, out / norm, 0.0)
    return scaled


def output_error(model: Model, rec: LoopData) -> LoopData | None:
    """``rec`` with y replaced by the model's output error (module docstring).

    ``e = y - P_M u - O x̂₀``, shape of ``rec.y`` (a low-rate y taken at its phase), NaN
    where y is missing; r and u as the identification takes them
    (:func:`~.prediction.centred`). None when the plant has a pole outside the unit circle.
    """
    P = model.plant_discrete()
    if grows(P):
        return None
    r, u, y = centred(rec, model)
    drive = driving_input(rec, model)
    with warnings.catch_warnings():  # an integrator's Jordan block: the direct recursion
        warnings.filterwarnings("ignore", "simulate: state matrix", RuntimeWarning)
        _, y_plant = LoopStream(replace(model, controller=None, injection=None)).next(drive)
    step = rec.n_samples // y.shape[0]
    obs = free_response(P, rec.n_samples)
    if model.controller is None:  # open loop: what u's mean, taken out, did (a ramp, 1/s)
        obs = np.concatenate([obs, step_responses(P, rec.n_samples)], axis=2)
    if step > 1:  # y at the low rate
        y_plant, obs = y_plant[rec.y_phase :: step], obs[rec.y_phase :: step]
    e = y - y_plant
    seen = np.isfinite(e)
    if obs.shape[2] and seen.any():
        A = (obs * seen[:, :, None]).reshape(-1, obs.shape[2])
        x0, *_ = np.linalg.lstsq(A, np.where(seen, e, 0.0).ravel(), rcond=None)
        e = e - obs @ x0
    return replace(rec, r=r, u=u, y=e)


def matched(
    model: Model, rec: LoopData, *, n: int, degree: int, ident_error: LoopData | None = None
) -> Matched | None:
    """The identification of ``model``'s output error on ``rec`` (module docstring).

    ``n``, ``degree``: the data's identification's (:func:`~.evidence.identify_record`).
    ``ident_error``: :func:`output_error` of the two when at hand. None for a periodic
    record or an unstable plant (returned unchanged by :func:`matched_evidence`).
    """
    if rec.period is not None:
        return None
    err = ident_error if ident_error is not None else output_error(model, rec)
    if err is None:
        return None
    ident = identify_record(err, model, n=n, degree=degree)
    if ident is None:
        return None
    dof = ident.lifted_J.dof if ident.lifted_J is not None else 0
    return Matched(
        np.asarray(ident.plant.frequency, float),
        np.asarray(ident.plant.response, complex),
        np.asarray(ident.plant.std, float),
        int(dof),
    )


def matched_evidence(
    ev: Evidence, model: Model, rec: LoopData, *, n: int, degree: int, alpha: float
) -> Evidence:
    """``ev`` (``model`` against ``rec``) with the estimate debiased and the std matched.

    ``P̂ := P_M + (P̂ - P̂_M)`` and ``σ̂`` of the output error's identification, at every
    bin (all tested: ``tested`` True), each significant above the per-bin test's threshold
    over all of them (module docstring). The lifted maps' test is kept as it came. ``ev``
    itself for a periodic record or an unstable plant.

    Raises
    ------
    ValueError
        ``ev`` is not on the bins of ``rec``'s identification.
    """
    m = matched(model, rec, n=n, degree=degree)
    if m is None:
        return ev
    if m.frequency.shape != ev.frequency.shape or not np.allclose(m.frequency, ev.frequency):
        raise ValueError(
            f"ev must be on the bins of rec's identification ({m.frequency.size} bins), got "
            f"{ev.frequency.size}"
        )
    z = m.sigma_error
    thr = threshold(alpha, m.n_tests(), m.dof or ev.dof)
    return replace(
        ev,
        P_hat=ev.P_model + m.difference,
        P_std=m.std,
        sigma_error=z,
        threshold=thr,
        significant=np.nan_to_num(z, nan=0.0) > thr,
        dof=m.dof or ev.dof,
        tested=np.ones(ev.frequency.size, bool),
    )
