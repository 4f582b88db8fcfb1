# SPDX-License-Identifier: Apache-2.0
"""The criterion every cause is fitted and ranked by: whitened residuals and the BIC."""

from __future__ import annotations

import math
import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import replace

import numpy as np
import scipy.ndimage
import scipy.optimize

from ...errors import DataError
from ...numerics.arrays import BoolArray, ComplexArray, FloatArray
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from ...numerics.systems.simulate import loop_poles
from ...numerics.systems.window_response import LoopSpectrum, lifted_dft
from .holes import Holes
from .noise import loop_noise_gain
from .prediction import centred, predict

#: The noise std per bin is taken as at least this fraction of y's std: no sensor resolves
#: y finer (160 dB), and in a noise-free record the rest is rounding, which a fitted cause
#: must not explain (the nominal's residual level there is 1e-22 of y's power).
RESOLUTION = 1e-8
#: The LPM's noise level counts as leakage where it exceeds the nominal's projected
#: residual level by this factor (:meth:`Objective._leakage_removed`).
LEAK_FACTOR = 3.0


def settle_samples(model: Model, n_samples: int) -> int:
    """High-rate samples after which the zero-state simulation has forgotten its start.

    The measured loop was running before the record began; a simulation from rest differs
    from it by a transient that decays with the lifted loop's slowest pole ρ. Skipped until
    ``ρ^m < 1e-5``, at most a quarter of the record; a whole number of low-rate periods.
    """
    poles = loop_poles(model)
    rho = float(np.max(np.abs(poles), initial=0.0))
    F = model.ratio
    if rho <= 0.0:
        return 0
    m = math.ceil(math.log(1e-5) / math.log(min(rho, 1.0 - 1e-9)))
    return min(m * F, (n_samples // 4) // F * F)


def smooth_below(n: int) -> int:
    """The largest 5-smooth number (only factors 2, 3 and 5) not above n (n >= 1)."""
    best = 1
    p2 = 1
    while p2 <= n:
        p3 = p2
        while p3 <= n:
            p5 = p3
            while p5 * 5 <= n:
                p5 *= 5
            best = max(best, p5)
            p3 *= 3
        p2 *= 2
    return best


#: Largest condition number of the column-scaled Gram matrix that :func:`project_out`
#: solves by the normal equations (one refinement takes their error, about this times
#: eps, to its square: 1e-12 of the residual).
GRAM_COND = 1e10


def project_out(A: FloatArray, b: FloatArray) -> FloatArray:
    """``b`` less its least-squares fit by the columns of ``A`` (m, k), m >> k.

    By the normal equations of the unit-scaled columns, refined once, where their Gram
    matrix's condition is below :data:`GRAM_COND` (cheaper than an SVD: docs/benchmarks.md,
    "Choices in the code"); otherwise by the SVD with ``rcond`` 1e-10 (nearly equal columns).
    Columns below 1e-12 of the largest one's norm are left out (rounding: a mode y does not see);
    the others count alike, however weakly y sees their mode (an SVD of the unscaled
    columns would drop a free response 1e-10 the size of another's).
    """
    return Projector(A)(b)


class Projector:
    """:func:`project_out` by the columns of ``A`` (m, k), for many ``b`` of m rows.

    The columns are scaled and their Gram matrix formed and checked once.
    """

    def __init__(self, A: FloatArray):
        norm = np.sqrt(np.einsum("ij,ij->j", A, A))
        keep = norm > 1e-12 * np.max(norm, initial=0.0)
        self._An: FloatArray | None = None
        self._G: FloatArray | None = None  # None: by the SVD
        if np.any(keep):
            An = A[:, keep] / norm[keep]
            G = An.T @ An
            w = np.linalg.eigvalsh(G)
            self._An = An
            self._G = G if w[0] * GRAM_COND > w[-1] else None

    def __call__(self, b: FloatArray) -> FloatArray:
        """``b`` (m,) or (m, n) less its least-squares fit by the columns."""
        An, G = self._An, self._G
        if An is None:
            return b
        if G is not None:
            r = b - An @ np.linalg.solve(G, An.T @ b)
            return np.asarray(r - An @ np.linalg.solve(G, An.T @ r), float)
        return np.asarray(b - An @ np.linalg.lstsq(An, b, rcond=1e-10)[0], float)


#: Loops (a model less its output disturbance) whose modal form, free responses and their
#: projection an :class:`Objective` keeps: a search moves one value at a time, and a
#: disturbance's values leave the loop as it was. At most this many, and at most
#: :data:`LOOPS_BYTES` of their spectra (always the last one).
LOOPS_KEPT = 4
#: Bytes of kept loops' spectra (free responses and projection) at most.
LOOPS_BYTES = 16 << 20


class _Loop:
    """What a loop gives every model of it: its response and its free responses' spectrum.

    ``projector``: the projection off those (criterion's weight), once it is formed.
    """

    def __init__(self, spectrum: LoopSpectrum, free: ComplexArray | None):
        self.spectrum = spectrum
        self.free = free
        self.projector: Projector | None = None
        self.formed = False  # projector formed (it stays None where it is not finite)

    @property
    def nbytes(self) -> int:
        """Bytes of its spectra, the projection's columns counted as the free responses'."""
        return 0 if self.free is None else 2 * self.free.nbytes


class Objective:
    """Whitened residuals of a model family on the estimation record.

    In closed loop the measured loop was running before the record began: what the
    loop's modes carry of that unknown initial state is eliminated by least squares
    (variable projection onto every mode's free response from the window's start,
    whitened like the residual), so that neither the start-up transient nor a slow mode's
    tail counts as a model error, and no sample is skipped for it. The model's y is then
    computed in the frequency domain, as the lifted loop's circular response to r
    (:class:`~mr_ident.numerics.systems.window_response.LoopSpectrum`): it differs from a
    simulation by a free response alone, so after the projection the two residuals agree
    (to rounding; test/test_window_response.py against the loop simulated sample by
    sample), cheaper than a simulation per evaluation and with the settling samples (up
    to a quarter of a record) put to use. Every mode takes part, fast and deadbeat ones too:
    the DFT of a finite record of
    the noise as the loop shapes it is ``S_o(k) V(k)`` plus a leakage term from the
    loop's state at the record's ends, a smooth sum over the loop's modes that the LPM
    noise spectrum leaves out (it is the LPM's transient term). Where the loop suppresses
    the noise (integral action: ``|S_o|`` tiny at low frequency) that term outweighs the
    noise there by orders of magnitude, and a cause that merely adds a mode to the loop
    bought its basis for free (measured: loops with nothing hidden where an extra mode
    lowered the cost by 12 600; with every mode projected, 2 of 3 such false causes go).

    The spectrum ``E(k)`` of y - ŷ (``rfft``, orthonormal) is divided by the noise std:
    the level of :func:`~mr_ident.diagnosis.criterion.noise.noise_spectrum` times, in closed loop,
    the nominal loop's :func:`~mr_ident.diagnosis.criterion.noise.loop_noise_gain` on this record's
    bins (measured: without the gain a loop with a 1 %-damped closed-loop pole drew a
    false mode and a disturbance at that pole's frequency, the truth's likelihood ratio
    446; a notch fitted 40 % off with the truth rejected at 52; with it both are
    within the noise), so that the bins are independent with unit variance when
    the model is right: least squares is then efficient and
    ``-2 log L = 2 sum |E|^2 / S`` enters the BIC with the number of bins as the sample
    size. Only y - ŷ enters: in closed loop u - û(r) is the same noise filtered by the loop
    (one noise source), so counting it too would double the evidence, noise included; u
    given y is the controller's own equation
    (:mod:`~mr_ident.diagnosis.controller.relation`), which holds separate evidence and is
    checked before this.
    """

    def __init__(
        self,
        rec: LoopData,
        base: Model,
        noise: FloatArray,
        plant: tuple[FloatArray, ComplexArray] | None = None,
    ):
        self.rec = rec
        self.base = base
        self.plant = plant  # (frequency, P̂) of the record, for starting guesses
        r, u, y = centred(rec, base)
        # missing samples (NaN): zeros here, their values eliminated as unknowns (y:
        # criterion.holes) or left out of the sums (u: in closed loop only the sums of
        # squares read it; in open loop predict drives the plant with u's estimates)
        self.missing_y, self.missing_u = np.isnan(y), np.isnan(u)
        level = np.nanstd(y, axis=0) if self.missing_y.any() else None
        self.u, self.y = np.where(self.missing_u, 0.0, u), np.where(self.missing_y, 0.0, y)
        self.closed = base.controller is not None
        # nothing skipped but what makes the FFTs fast (a multiple of F, 5-smooth) or, in
        # a periodic record, its first period; the time-domain residual that the search
        # for disturbances reads starts where a simulation from rest has settled
        unit = rec.ratio or 1
        settle = settle_samples(base, rec.n_samples) if self.closed else 0
        self.skip, self.settle = (
            rec.n_samples - unit * smooth_below((rec.n_samples - s) // unit) for s in (0, settle)
        )
        if rec.period:
            self.skip = self.settle = rec.period
        # closed loop over whole periods: the model's y in the frequency domain, with no
        # simulation (numerics.systems.window_response; the same residual once the free responses
        # are projected out)
        self._spectral = self.closed and self.skip % base.ratio == 0
        if self._spectral:
            self._Y = np.fft.rfft(self.y[self.skip :], axis=0, norm="ortho")
            self._R = lifted_dft(r[self.skip :], base.ratio)
            self._L = (rec.n_samples - self.skip) // base.ratio
        self._loops: OrderedDict[Model, _Loop | None] = OrderedDict()
        self._by_free: dict[int, _Loop] = {}  # the kept loops by their free responses' id
        self._residuals: OrderedDict[Model, FloatArray] = OrderedDict()
        base_spectra = self._spectra(base)
        if base_spectra is None:
            raise DataError("the model cannot be simulated on this data (the loop is not stable)")
        # the noise level is given on the bins of the whole record: onto this one's, then
        # the loop's sharp shaping on this grid (closed loop, not periodic)
        n_eff = rec.n_samples - self.skip
        src = np.linspace(0.0, 0.5, noise.shape[0])
        dst = np.arange(n_eff // 2 + 1) / n_eff
        S = np.column_stack([np.interp(dst, src, noise[:, j]) for j in range(noise.shape[1])])
        if self.closed and not rec.period:
            g = loop_noise_gain(base, n_eff)
            S = self._leakage_removed(S, g, base_spectra) * g
        spread = np.std(y[self.skip :], axis=0) if level is None else level
        floor = (RESOLUTION * spread) ** 2
        self.weight = 1.0 / np.sqrt(np.maximum(S, floor))
        if rec.period:  # a periodic r has no DC: y's is an offset, not the model's to explain
            self.weight[0] = 0.0
        self.n_bins = int(self.weight.size)
        self.holes = Holes(self.missing_y[self.skip :], self.weight)

    def _leakage_removed(
        self,
        level: FloatArray,
        g: FloatArray,
        base_spectra: tuple[ComplexArray, ComplexArray | None],
    ) -> FloatArray:
        """The noise level, the LPM's but the nominal's projected residual's where smaller.

        Where the LPM's level exceeds the residual's by :data:`LEAK_FACTOR` (both with the
        loop's gain ``g`` divided out, smoothed alike).

        The LPM's transient term is a polynomial over its window; the leakage of a slow
        closed-loop mode (a controller's integrator: time constants of seconds in a record
        of tens) is not, and near DC the LPM reads it as noise (measured on drawn loops: the
        level 18-3800x too high in the lowest bins of 7 of 24 loops, all with integral
        action), so the criterion all but ignored those bins (a control delay whose effect
        sits below 1 Hz went unseen, weighed 1150x too little). The nominal's residual with
        every mode's free response projected out holds no leakage: its level is the noise
        where the model is right and more where it is wrong, so the smaller of the two
        never reads a model error as less than noise. ``base_spectra``: the nominal's
        (:meth:`_spectra`).
        """
        flat = np.nanmedian(level, axis=0) * g  # projection weights from the loop's shape
        res = self._whiten(base_spectra, 1.0 / np.sqrt(flat))
        nb = flat.size
        power = (res[:nb] ** 2 + res[nb:] ** 2).reshape(flat.shape) * flat / g
        smooth = scipy.ndimage.median_filter(power, size=(33, 1), mode="mirror") / math.log(2.0)
        return np.where(level > LEAK_FACTOR * smooth, smooth, level)

    def _raw(self, model: Model) -> tuple[FloatArray, FloatArray, ComplexArray | None] | None:
        """Residuals y - ŷ and u - û from the skip on; the free responses' spectrum or None."""
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # unstable or defective candidates are rejected
            try:
                pred = predict(model, self.rec, free_from=self.skip if self.closed else None)
            except (ArithmeticError, ValueError, Warning, np.linalg.LinAlgError):
                return None  # any warning, a library's own (scipy's BadCoefficients) included
        s = self.skip
        ey = np.where(self.missing_y[s:], 0.0, self.y[s:] - pred.y[s:])
        eu = np.where(self.missing_u[s:], 0.0, self.u[s:] - pred.u[s:])
        if not (np.all(np.isfinite(ey)) and np.all(np.isfinite(eu))):
            return None
        free = pred.free if pred.free is not None and pred.free.shape[-1] else None
        if free is not None and not np.all(np.isfinite(free)):
            return None
        return ey, eu, free

    def _spectra(self, model: Model) -> tuple[ComplexArray, ComplexArray | None] | None:
        """Spectrum of y - ŷ on the window's bins, (n_bins, n_y), and the free responses'.

        None where the model cannot be simulated (an unstable or defective loop).
        """
        if not self._spectral:
            raw = self._raw(model)
            return None if raw is None else (np.fft.rfft(raw[0], axis=0, norm="ortho"), raw[2])
        loop = self._loop(model)
        if loop is None:
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # as in _raw
            try:
                E = self._Y - loop.spectrum.y(self._R, self._L, self.skip, model)
            except (ArithmeticError, ValueError, Warning, np.linalg.LinAlgError):
                return None
        if not np.all(np.isfinite(E)):
            return None
        return E, loop.free

    def _loop(self, model: Model) -> _Loop | None:
        """The loop of ``model`` (the last ones kept: :data:`LOOPS_KEPT`); None: not simulable."""
        key = replace(model, disturbances=()) if model.disturbances else model
        if key in self._loops:
            self._loops.move_to_end(key)
            return self._loops[key]
        got: _Loop | None = None
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # as in _raw: a defective loop warns
            try:
                spectrum = LoopSpectrum(key)
                if spectrum.modal and spectrum.stable:
                    free = spectrum.free(self.rec.n_samples - self.skip)
                    if np.all(np.isfinite(free)):
                        got = _Loop(spectrum, free if free.shape[-1] else None)
            except (ArithmeticError, ValueError, Warning, np.linalg.LinAlgError):
                pass
        self._loops[key] = got
        if got is not None and got.free is not None:
            self._by_free[id(got.free)] = got
        total = sum(v.nbytes for v in self._loops.values() if v is not None)
        while len(self._loops) > LOOPS_KEPT or (len(self._loops) > 1 and total > LOOPS_BYTES):
            _, old = self._loops.popitem(last=False)
            if old is not None and old.free is not None:
                del self._by_free[id(old.free)]
                total -= old.nbytes
        return got

    def residuals(self, model: Model) -> FloatArray:
        """The whitened residual spectrum (real and imaginary parts) of ``model``.

        The last :data:`LOOPS_KEPT` models' are kept (a copy is returned): a model is
        often scored again, after its fit or in another ranking.
        """
        if model in self._residuals:
            self._residuals.move_to_end(model)
            return self._residuals[model].copy()
        res = self._whiten(self._spectra(model))
        self._residuals[model] = res.copy()
        if len(self._residuals) > LOOPS_KEPT:
            self._residuals.popitem(last=False)
        return res

    def cost(self, model: Model) -> float:
        """Sum of squares of :meth:`residuals`."""
        with np.errstate(over="ignore"):
            return float(np.sum(self.residuals(model) ** 2))

    def _whiten(
        self,
        spectra: tuple[ComplexArray, ComplexArray | None] | None,
        weight: FloatArray | None = None,
    ) -> FloatArray:
        """The residual times ``weight`` (default: the criterion's), free responses out.

        The free responses are weighted alike and projected out, and so are the missing
        samples of y (:mod:`~mr_ident.diagnosis.criterion.holes`); 1e3 everywhere where
        ``spectra`` is None or the result overflows.
        """
        own = weight is None  # the criterion's weight: its projections are kept
        holes = self.holes if own else None
        if weight is None:
            weight = self.weight
        if spectra is None:
            return np.full(2 * weight.size, 1e3)
        if holes is None and self.missing_y.any():
            holes = Holes(self.missing_y[self.skip :], weight)
        with np.errstate(all="ignore"):
            E = spectra[0]
            res = np.concatenate([(E.real * weight).ravel(), (E.imag * weight).ravel()])
            if holes is not None and np.all(np.isfinite(res)):
                res = holes.project(res)  # the holes' unknown residuals, eliminated
            if spectra[1] is not None:  # the unknown state at the start, eliminated by lstsq
                proj = self._projector(spectra[1], weight, holes, keep=own)
                if proj is not None:
                    res = proj(res)
        ok = np.all(np.isfinite(res)) and float(np.max(np.abs(res), initial=0.0)) < 1e100
        return res if ok else np.full(2 * weight.size, 1e3)

    def _projector(
        self, free: ComplexArray, weight: FloatArray, holes: Holes | None, *, keep: bool
    ) -> Projector | None:
        """Projection off the weighted free responses (and the holes); None: not finite.

        ``keep``: kept with its loop (:meth:`_loop`) while that is kept, and found again.
        """
        loop = self._by_free.get(id(free)) if keep else None
        if loop is not None and loop.free is free and loop.formed:
            return loop.projector
        nb = free.shape[0] * free.shape[1]
        A = np.empty((2 * nb, free.shape[-1]))  # the weighted free responses' real, imaginary
        np.multiply(free.real, weight[:, :, None], out=A[:nb].reshape(free.shape))
        np.multiply(free.imag, weight[:, :, None], out=A[nb:].reshape(free.shape))
        proj = None
        if np.all(np.isfinite(A)):
            if holes is not None:
                A = holes.project(A)
            proj = Projector(A)
        if loop is not None and loop.free is free:
            loop.projector, loop.formed = proj, True
        return proj

    def gauss_newton(
        self, at: Model, moved: Iterable[tuple[Model, float]]
    ) -> tuple[FloatArray, BoolArray]:
        """Covariance of values at ``at`` from forward differences, and which are unknown.

        ``moved``: per value, the model with that value moved by its step h, and h. The
        residual's Jacobian J by forward differences (one simulation per value); its
        components have variance 1/2 under a right model, so the covariance is
        ``(JᵀJ)⁻¹ / 2`` (a pseudo-inverse); a value is without information (True) where
        its variance times its column's squared norm exceeds 1e8.
        """
        r0 = self.residuals(at)
        J = np.column_stack([(self.residuals(m) - r0) / h for m, h in moved])
        with np.errstate(all="ignore"):
            cov = np.asarray(0.5 * np.linalg.pinv(J.T @ J, rcond=1e-12, hermitian=True), float)
            weak = np.asarray(np.diag(cov) * np.sum(J * J, axis=0) > 1e8, bool)
        return cov, weak

    def bic(self, cost: float, p: int) -> float:
        """``2 cost + p ln(n_bins)`` (see the class docstring)."""
        return 2.0 * cost + p * math.log(self.n_bins)

    def evaluate(self, model: Model, p: int) -> tuple[float, dict[str, float]]:
        """BIC and residual sums of squares of ``model`` (the latter from a simulation).

        BIC ``2 sum |E|^2 / S + p ln(n_bins)``; the sums of squares of y (and u in closed loop).
        """
        bic = 2.0 * float(np.sum(self.residuals(model) ** 2)) + p * math.log(self.n_bins)
        raw = self._raw(model)  # the sums of squares in time: one simulation
        if raw is None:
            return bic, {"y": math.inf} | ({"u": math.inf} if self.closed else {})
        rss = {"y": float(np.sum(raw[0] ** 2))}
        if self.closed:
            rss["u"] = float(np.sum(raw[1] ** 2))
        return bic, rss


def least_squares(
    obj: Objective,
    build: Callable[[FloatArray], Model],
    x0: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    scale: FloatArray,
    *,
    max_nfev: int = 40,
) -> tuple[FloatArray, float]:
    """Bounded least squares of ``obj``'s whitened residual from ``x0``.

    Returns the end point and its cost (:meth:`Objective.cost`).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            res = scipy.optimize.least_squares(
                lambda x: obj.residuals(build(x)),
                x0,
                bounds=(lower, upper),
                x_scale=scale,
                max_nfev=max_nfev,
                ftol=1e-8,
                xtol=1e-8,
                diff_step=1e-6,
            )
        except (ValueError, np.linalg.LinAlgError):  # a start where the loop is unstable
            return x0, obj.cost(build(x0))
    return np.asarray(res.x, float), 2.0 * float(res.cost)
