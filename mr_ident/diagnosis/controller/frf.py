# SPDX-License-Identifier: Apache-2.0
"""The controller's FRF from the data, with its std, at the controller's rate.

In closed loop the record holds the controller's input and output (:mod:`.relation`): per
low-rate period m it samples ``y_s[m]`` (y at the sampling phase; ``y - r`` with r the
setpoint) and its output ``u_c`` is held on the following samples (``r - u`` with r at the
plant input, ``-u`` with r the setpoint). The last sample of period m holds
``u_c[m - j]``, ``j = -((F - 1 - h) // F)`` periods back for the hold start
``h = sampling phase + control delay``. So at the low rate (M = N / F periods, bin spacing
``fs_low / M``)::

    U_c(k) = z^-j K(k) Y_s(k) + T(k) + V(k),   z = exp(2j pi k / M)

with T the transient (the controller's unknown state at the record's start, a trim) and V
what is logged in u beyond the controller's output (a measured u's own noise; nothing
when u is the command). The local polynomial method (degree R, window 2n + 1 bins; the
same estimator as the plant's, :func:`~mr_ident.numerics.local.lpm.lpm`) fits ``z^-j K``
and T as polynomials in each window; the estimate shown is ``K̂(k) = z^j Ĝ(k)``, the
model's timing taken off (a control delay the model lacks stays in its phase).

**Std.** Per window the fit is linear least squares ``U_c = Φ θ + V`` with Φ built from
``Y_s`` and the polynomial basis. Where V is independent of Y_s (a measured u's noise is
not fed back: it never reaches y), ``Cov θ̂ = σ_v² (Φ^H Φ)^-1`` and ``σ_v²`` is estimated
from the residual with ``q = 2n + 1 - (R + 1)(n_y + 1)`` degrees of freedom, so

    std K̂[a, b](k) = sqrt(E|K̂ - K|²) = sqrt(σ̂_v,a² [(Φ^H Φ)^-1]_bb)

(``noise_cov`` and ``inv_gram`` of the LPM; ``|z^j| = 1`` leaves it unchanged). On a
command log V is nothing and the std is rounding; the estimate is then K itself, up to
the polynomial's approximation of K over a window (a controller varies slowly at the
low rate's bin spacing). With a noise that is fed back (a disturbance added to u_c
inside the loop) Y_s correlates with V and the std does not hold.

**Missing samples.** A period whose sampled y or held output is missing leaves a hole in
``Y_s`` or ``U_c`` (a held output's lost sample is first taken from its hold where the log
holds it exactly: :func:`held_fill`); the local fit needs the periods' DFT whole. The
estimate is made on the
longest run of complete periods (the transient term takes its ends as it takes the
record's), when it holds at least ``4 n + 2`` periods; the finding names the run and its
share of the record. A record lost too often for that gets no estimate, and the report
says why (:attr:`ControllerFRF.reason`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...numerics.arrays import BoolArray, ComplexArray, FloatArray
from ...numerics.lifting import dft
from ...numerics.local.lpm import lpm, pad_circular, smallest_n
from ...numerics.results import FRF
from ...numerics.signals import LoopData
from ...numerics.structure import HELD_RTOL, hold_of
from ...numerics.systems.model import Model
from ..causes.cause import CauseFit
from ..causes.registry import CAUSES, build
from .relation import EXACT, ControllerRelation

#: Most bins of each curve written to the JSON report (log-spaced).
JSON_BINS = 200


@dataclass(frozen=True)
class ControllerFRF:
    """The controller identified from the data, against the model's and the fitted one's.

    Attributes
    ----------
    identified : FRF
        K̂ on the low-rate bins ``k fs_low / M``, k = 1..M//2, shape (K, n_u, n_y), with its
        std (module docstring).
    model : FRF
        The nominal model's controller (notches included) on the same bins (std 0).
    fit : FRF or None
        The controller of the extended model (the controller-side causes applied: a gain,
        a retuned controller, a notch, a delay relative to the model's), None when no
        controller-side cause was applied.
    dof : int
        Degrees of freedom q of the std.
    span : tuple of int
        The periods ``start, stop`` the estimate is made on: all M of the record, or its
        longest run without missing samples.
    periods : int
        The record's periods M.
    reason : str
        Why there is no estimate ("" when there is one: then :attr:`identified` has bins).
    """

    identified: FRF
    model: FRF
    fit: FRF | None
    dof: int
    span: tuple[int, int] = (0, 0)
    periods: int = 0
    reason: str = ""

    @classmethod
    def unavailable(cls, reason: str, periods: int) -> ControllerFRF:
        """No estimate, and why (the report says it)."""
        empty = FRF(np.zeros(0), np.zeros((0, 0, 0), complex), np.zeros((0, 0, 0)), "none")
        return cls(empty, empty, None, 0, (0, 0), periods, reason)

    @property
    def available(self) -> bool:
        """An estimate was made."""
        return not self.reason

    def relative(self, other: FRF) -> float:
        """Median over bins and entries of ``|K̂ - K_other| / |K_other|``."""
        d = np.abs(self.identified.response - other.response)
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.nanmedian(d / np.abs(other.response)))

    def sigma(self, other: FRF) -> float:
        """Median over bins and entries of ``|K̂ - K_other| / std``."""
        d = np.abs(self.identified.response - other.response)
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.nanmedian(d / self.identified.std))

    def text(self) -> str:
        """The finding in words."""
        if not self.available:
            return f"the controller is not identified from the data: {self.reason}"
        f = self.identified.frequency
        start, stop = self.span
        part = (
            ""
            if stop - start == self.periods
            else f", from periods {start}-{stop - 1}, the longest run without missing "
            f"samples ({100 * (stop - start) / self.periods:.0f} % of the record)"
        )
        fit = (
            f", the fitted controller's {100 * self.relative(self.fit):.2g} % "
            f"({self.sigma(self.fit):.2g} std)"
            if self.fit is not None
            else ""
        )
        return (
            f"the controller identified from the data ({f[0]:.3g}-{f[-1]:.3g} Hz at the "
            "controller's rate) departs from the model's by "
            f"{100 * self.relative(self.model):.2g} % (median){fit}{part}"
        )

    def summary(self) -> dict[str, Any]:
        """The JSON form: figures, and up to :data:`JSON_BINS` log-spaced bins of each curve."""
        if not self.available:
            return {"available": False, "reason": self.reason, "periods": self.periods}
        f = self.identified.frequency
        pick = np.unique(np.geomspace(1, f.size, min(JSON_BINS, f.size)).astype(int) - 1)

        def curve(x: FRF | None) -> dict[str, Any] | None:
            if x is None:
                return None
            g = x.response[pick]
            return {"re": g.real.tolist(), "im": g.imag.tolist(), "std": x.std[pick].tolist()}

        return {
            "available": True,
            "periods": self.periods,
            "span": list(self.span),
            "frequency_hz": f[pick].tolist(),
            "identified": curve(self.identified),
            "model": curve(self.model),
            "fit": curve(self.fit),
            "dof": self.dof,
            "relative_to_model": self.relative(self.model),
            "relative_to_fit": None if self.fit is None else self.relative(self.fit),
            "sigma_to_fit": None if self.fit is None else self.sigma(self.fit),
            "statistic": "K_hat: the local polynomial fit of the controller's output on what it "
            "samples, at the low rate; std sqrt(E|K_hat - K|^2); relative: median "
            "|K_hat - K| / |K|, sigma: median |K_hat - K| / std over bins and entries",
        }


def low_rate_signals(rec: LoopData, model: Model) -> tuple[FloatArray, FloatArray, int]:
    """What the controller samples and what it outputs, per period, and the periods between.

    Returns ``y_s`` (M, n_y), ``u_c`` (M, n_u) (the last sample of each period) and j:
    ``u_c[m]`` of the result is the controller's output of period ``m - j``. A missing
    sample of the output is taken from its hold where the log holds it exactly
    (:func:`held_fill`).
    """
    F = model.ratio
    M = rec.n_samples // F
    logged = held_fill(-rec.u if model.setpoint else rec.r - rec.u, F)
    sampled = rec.y - rec.r if model.setpoint else rec.y
    hold = model.sample_phase + model.control_delay
    j = -((F - 1 - hold) // F)
    return sampled[model.sample_phase :: F][:M], logged[F - 1 :: F][:M], j


def held_fill(x: FloatArray, ratio: int) -> FloatArray:
    """``x`` (N, c) with its NaN samples taken from their hold, where x is held over F samples.

    A command log holds the controller's output over the ``ratio`` samples from the residue
    :func:`~mr_ident.numerics.structure.hold_of` finds; every present sample of a hold
    interval is its value, so a missing one is any of them (exact). Only where they agree
    (to the hold's tolerance): an interval with a change off the grid keeps its hole. ``x``
    unchanged where it has no NaN or is not held over ``ratio`` samples (a measured u).
    """
    lost = np.isnan(x)
    if ratio == 1 or not lost.any():
        return x
    found = hold_of(x)
    if found is None or found[0] != ratio:
        return x
    # intervals start at the residue s: pad the front so that they fall on whole blocks
    pad = np.full(((ratio - found[1]) % ratio, x.shape[1]), np.nan)
    body = np.concatenate([pad, x])
    n_blocks = -(-body.shape[0] // ratio)
    tail = np.full((n_blocks * ratio - body.shape[0], x.shape[1]), np.nan)
    blocks = np.concatenate([body, tail]).reshape(n_blocks, ratio, -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a wholly lost interval stays NaN
        value = np.nanmax(blocks, axis=1)  # (n_blocks, c): the held value
        spread = value - np.nanmin(blocks, axis=1)
    # an interval whose present samples differ (a change off the hold's grid) gives none
    scale = float(np.nanmax(np.abs(x)))
    value = np.where(spread <= HELD_RTOL * scale, value, np.nan)
    filled = np.repeat(value, ratio, axis=0)[pad.shape[0] : pad.shape[0] + x.shape[0]]
    return np.where(lost, filled, x)


def longest_complete(ok: BoolArray) -> tuple[int, int]:
    """``start, stop`` of the longest run of True in ``ok`` (the first of equal runs)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    if edges.size == 0:
        return 0, 0
    starts, stops = edges[::2], edges[1::2]
    i = int(np.argmax(stops - starts))
    return int(starts[i]), int(stops[i])


def controller_frf(
    rec: LoopData, nominal: Model, fitted: Model | None, *, n: int, degree: int = 2
) -> ControllerFRF | None:
    """The controller's FRF identified from ``rec`` (module docstring), with its std.

    Parameters
    ----------
    rec : LoopData
        A closed-loop record with y at the high rate; (N, n_r), (N, n_u), (N, n_y). NaN
        marks a missing sample.
    nominal : Model
        Gives the rates and the timing (sampling phase, control delay) of the estimate.
    fitted : Model or None
        The model with the controller-side causes applied (its controller drawn as the fit).
    n, degree : int
        Window half-width (raised to the smallest the fit allows) and polynomial degree.

    Returns
    -------
    ControllerFRF or None
        None in open loop or with y at the low rate; :meth:`ControllerFRF.unavailable`
        when the record, or its longest run of periods without missing samples, holds
        fewer than ``4 n + 2`` periods.
    """
    if nominal.controller is None or rec.y_step != 1:
        return None
    ys, uc, j = low_rate_signals(rec, nominal)
    M, n_y, n_u = ys.shape[0], ys.shape[1], uc.shape[1]
    n = max(n, smallest_n(degree, n_y, n_u))
    complete = np.asarray(np.isfinite(ys).all(axis=1) & np.isfinite(uc).all(axis=1), bool)
    start, stop = longest_complete(complete)
    if stop - start < 4 * n + 2:
        run = stop - start
        lost = "" if run == M else f", its longest run without missing samples {run}"
        return ControllerFRF.unavailable(
            f"the record holds {M} periods{lost}; the local fit needs {4 * n + 2}", M
        )
    ys, uc, L = ys[start:stop], uc[start:stop], stop - start
    centres = np.arange(1, L // 2 + 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an unexcited bin: NaN there
        fit = lpm(
            pad_circular(dft(ys), centres, n),
            pad_circular(dft(uc), centres, n),
            n=n,
            degree=degree,
            workers=1,
        )
    f = np.asarray(centres * (nominal.fs_low / L), float)
    turn = np.exp(2j * np.pi * centres * j / L)[:, None, None]
    std = np.sqrt(
        np.einsum("kaa,kbb->kab", fit.noise_cov, fit.inv_gram).real.clip(min=0.0)
    )  # (K, n_u, n_y): sigma_v,a^2 [(Phi^H Phi)^-1]_bb
    identified = FRF(f, fit.G * turn, std, "controller from data (LPM, low rate)")
    zero = np.zeros(std.shape)
    model = FRF(f, nominal.controller_frf(L)[centres], zero, "model")
    fit_frf = None
    if fitted is not None and fitted is not nominal:
        F = nominal.ratio
        j_fit = -((F - 1 - fitted.sample_phase - fitted.control_delay) // F)
        shift: ComplexArray = np.exp(-2j * np.pi * centres * (j_fit - j) / L)[:, None, None]
        fit_frf = FRF(f, fitted.controller_frf(L)[centres] * shift, zero, "fit")
    return ControllerFRF(identified, model, fit_frf, fit.dof, (start, stop), M)


def where_differs(
    nominal: Model,
    est: LoopData,
    relation: ControllerRelation | None,
    applied: list[CauseFit],
    *,
    n: int,
    degree: int,
) -> ControllerFRF | None:
    """The controller's FRF from the data where the logged u departs from the model's."""
    if relation is None or relation.error_before <= EXACT:
        return None
    sides = [a.choice for a in applied if a.choice is not None and CAUSES[a.cause].controller_side]
    fitted = build(nominal, sides) if sides else None
    return controller_frf(est, nominal, fitted, n=n, degree=degree)
