"""Why a model is wrong: the causes, one class each, in a registry (:data:`CAUSES`).

Every cause is a parametric extension of the model: its name and parameters, when it
can occur in a loop (:meth:`Cause.applies`), its starting guesses and bounds, and how it
extends a :class:`~mr_ident.numerics.model.Model` (:meth:`Cause.fit`). All are fitted by
one engine (:func:`~mr_ident.diagnosis.objective.least_squares` on the whitened
residual of :class:`~mr_ident.diagnosis.objective.Objective`) and scored by one BIC
(:func:`fit_cause`). A new cause is one more class and one more entry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ..errors import ConfigError
from ..numerics.arrays import FloatArray
from ..numerics.model import Model
from ..numerics.results import Identification
from ..numerics.signals import LoopData
from ..numerics.systems import TransferMatrix
from .objective import Objective, best_starts, least_squares
from .prediction import predict

Params = dict[str, float]


@dataclass(frozen=True)
class CauseFit:
    """One cause fitted to the data.

    Attributes
    ----------
    cause : str
    parameters : dict
        Named as the cause's :attr:`Cause.parameters`.
    score : float
        BIC (lower is better).
    rss : dict
        Residual sum of squares of y (and u in closed loop).
    model : Model
        The model extended by this cause.
    applicable : bool
        False when the cause cannot occur in this loop (e.g. sampling_offset without a
        controller or with F = 1); then ``score`` is inf.
    """

    cause: str
    parameters: Params
    score: float
    rss: dict[str, float]
    model: Model
    applicable: bool = True


class Cause:
    """A way the nominal model can be wrong (see the module docstring).

    Subclasses set :attr:`name`, :attr:`parameters` (names in the report),
    :attr:`n_free` (free parameters counted by the BIC), :attr:`meaning` and
    :attr:`extends` (the model-file key the fit writes), and implement :meth:`fit`.
    """

    name: ClassVar[str]
    parameters: ClassVar[tuple[str, ...]] = ()
    n_free: ClassVar[int] = 0
    meaning: ClassVar[str] = ""
    extends: ClassVar[str] = ""
    #: May be applied again on top of itself (a second mode, a second disturbance).
    repeatable: ClassVar[bool] = False

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in the loop of ``base``."""
        return True

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fitted parameters and the extended model."""
        raise NotImplementedError


class NoCause(Cause):
    """The model as it is (the reference every cause must beat)."""

    name = "none"
    meaning = "the model explains the data within noise"

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        return {}, obj.base


class GainError(Cause):
    """The plant's gain differs: one factor on the plant."""

    name = "gain_error"
    parameters = ("gain",)
    n_free = 1
    meaning = "plant gain differs (true / nominal)"
    extends = "plant_gain"

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        base = obj.base
        x, model = least_squares(
            obj,
            lambda x: replace(base, plant_gain=base.plant_gain * float(x[0])),
            [[1.0], [0.7], [1.4]],
            [0.05],
            [20.0],
            [0.1],
        )
        return {"gain": float(x[0])}, model


class InputDelay(Cause):
    """An extra delay between u_h and the plant (exact ZOH, fractional samples)."""

    name = "input_delay"
    parameters = ("delay_s",)
    n_free = 1
    meaning = "extra delay between u_h and the plant"
    extends = "input_delay_s"

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in this loop."""
        return base.plant.dt is None

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        base = obj.base
        h = 1.0 / base.fs_high

        def build(x: FloatArray) -> Model:
            return replace(base, input_delay=base.input_delay + float(x[0]))

        grid = [[k * h] for k in (0.25, 0.75, 1.5, 3.0, 6.0)]
        x, model = least_squares(
            obj, build, best_starts(obj, build, grid, 2), [0.0], [20 * h], [0.2 * h]
        )
        return {"delay_s": float(x[0])}, model


class ExtraResonance(Cause):
    """An unmodelled mode multiplying the plant."""

    name = "extra_resonance"
    parameters = ("frequency_hz", "damping")
    n_free = 2
    meaning = (
        "an unmodelled mode: plant x w²/(s²+2ζws+w²); ζ up to 5 (an overdamped one is a low-pass)"
    )
    extends = "extra_modes"
    repeatable = True

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in this loop."""
        return base.plant.dt is None

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        base = obj.base
        fs = base.fs_high

        def build(x: FloatArray) -> Model:
            return replace(base, extra_modes=base.extra_modes + ((float(x[0]), float(x[1])),))

        fgrid = np.geomspace(fs / 200, 0.45 * fs, 12)
        starts = [[float(f0), z0] for f0 in fgrid for z0 in (0.05, 1.0)]
        if obj.plant is not None and obj.plant[0].size:
            f_id, P_id = obj.plant
            ratio = (
                np.abs(P_id / base.plant_discrete().freqresp(f_id))
                .reshape(f_id.size, -1)
                .max(axis=1)
            )
            k = int(np.nanargmax(ratio))
            starts = [
                [float(f_id[k]), float(np.clip(0.5 / max(ratio[k], 1.0), 0.005, 0.5))]
            ] + starts
        x, model = least_squares(
            obj,
            build,
            best_starts(obj, build, starts, 3),
            [fs / 1000, 0.002],
            [0.499 * fs, 5.0],
            [fs / 1000, 0.01],
        )
        return {"frequency_hz": float(x[0]), "damping": float(x[1])}, model


def modes(plant: TransferMatrix) -> list[tuple[float, float]]:
    """Lightly damped complex pole pairs of a continuous plant: (frequency_hz, damping)."""
    if plant.dt is not None:
        return []
    out = []
    for p in np.unique(np.round(plant.poles(), 9)):
        if p.imag > 0:
            w = abs(p)
            z = -p.real / w
            if z < 0.7:
                out.append((float(w / (2 * np.pi)), float(z)))
    return sorted(out)


def shift_mode(model: Model, f0: float, z0: float, f: float, z: float) -> Model:
    """Move the plant's pole pair (f0, z0) to (f, z).

    Numerators unchanged (so the high-frequency asymptote, e.g. the mass line, is kept).
    """
    w0 = 2 * np.pi * f0
    target = -z0 * w0 + 1j * w0 * math.sqrt(max(1 - z0 * z0, 0.0))
    w = 2 * np.pi * f
    new = -z * w + 1j * w * math.sqrt(max(1 - z * z, 0.0))
    dens = []
    for row in model.plant.den:
        drow = []
        for a in row:
            roots = np.roots(a)
            hit = np.nonzero(np.abs(roots - target) < 1e-6 * max(abs(target), 1.0))[0]
            hitc = np.nonzero(np.abs(roots - np.conj(target)) < 1e-6 * max(abs(target), 1.0))[0]
            if hit.size and hitc.size:
                roots = roots.copy()
                roots[hit[0]], roots[hitc[0]] = new, np.conj(new)
                drow.append(tuple(float(c) for c in np.real(a[0] * np.poly(roots))))
            else:
                drow.append(tuple(a))
        dens.append(tuple(drow))
    return replace(model, plant=TransferMatrix(model.plant.num, tuple(dens), None))


class ResonanceShift(Cause):
    """A modelled mode at another frequency or damping (its numerator kept)."""

    name = "resonance_shift"
    parameters = ("frequency_hz", "damping")
    n_free = 2
    meaning = "a modelled mode moved: its poles, the numerator kept"
    extends = "plant.den"

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in this loop."""
        return bool(modes(base.plant))

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        base = obj.base
        fs = base.fs_high
        best: tuple[float, FloatArray, Model] | None = None
        for f0, z0 in modes(base.plant):

            def build(x: FloatArray, f0: float = f0, z0: float = z0) -> Model:
                return shift_mode(base, f0, z0, float(x[0]), float(x[1]))

            starts = [[f0 * s, z0] for s in (0.8, 0.9, 1.0, 1.1, 1.25)]
            x, m = least_squares(
                obj,
                build,
                best_starts(obj, build, starts, 2),
                [0.4 * f0, 0.001],
                [min(2.5 * f0, 0.499 * fs), 0.9],
                [0.01 * f0, 0.01],
            )
            cost = obj.cost(m)
            if best is None or cost < best[0]:
                best = (cost, x, m)
        assert best is not None
        return {"frequency_hz": float(best[1][0]), "damping": float(best[1][1])}, best[2]


class _Timing(Cause):
    """A discrete timing cause: every candidate is simulated, the best kept."""

    key: ClassVar[str]

    def candidates(self, base: Model) -> list[tuple[int, Model]]:
        """Every candidate value with its model (simulated and scored in turn)."""
        raise NotImplementedError

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        scored = [(obj.cost(m), v, m) for v, m in self.candidates(obj.base)]
        _, v, model = min(scored, key=lambda t: t[0])
        return {self.key: float(v)}, model


class SamplingOffset(_Timing):
    """The controller samples y at another high-rate phase than the model's."""

    name = "sampling_offset"
    parameters = ("offset_samples",)
    key = "offset_samples"
    n_free = 1
    meaning = "the controller samples y at another high-rate phase"
    extends = "sample_phase"

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in this loop."""
        return base.controller is not None and base.ratio > 1

    def candidates(self, base: Model) -> list[tuple[int, Model]]:
        """Every candidate value with its model (simulated and scored in turn)."""
        return [
            (o, replace(base, sample_phase=base.sample_phase + o))
            for o in range(-base.sample_phase, base.ratio - base.sample_phase)
            if o != 0
        ]


class ControlDelay(_Timing):
    """The controller's held output is applied later than the model says."""

    name = "control_delay"
    parameters = ("delay_samples",)
    key = "delay_samples"
    n_free = 1
    meaning = "the held controller output is applied later (computation delay)"
    extends = "control_delay"

    def applies(self, base: Model) -> bool:
        """Whether the cause can occur in this loop."""
        return base.controller is not None

    def candidates(self, base: Model) -> list[tuple[int, Model]]:
        """Every candidate value with its model (simulated and scored in turn)."""
        return [
            (d, replace(base, control_delay=base.control_delay + d))
            for d in range(1, 2 * base.ratio + 1)
        ]


def residual_peak(obj: Objective, base: Model) -> list[tuple[float, int, float]]:
    """Candidate disturbance frequencies.

    The largest peak of the y residual's spectrum per output, as (frequency_hz, output,
    amplitude).
    """
    pred = predict(base, obj.rec)
    s = obj.skip
    e = obj.y[s:] - pred.y[s:]
    n = e.shape[0]
    nfft = 4 * n
    E = np.abs(np.fft.rfft(e * np.hanning(n)[:, None], n=nfft, axis=0))
    f = np.fft.rfftfreq(nfft, 1.0 / base.fs_high)
    out = []
    for o in range(E.shape[1]):
        k = int(np.argmax(E[1:, o])) + 1
        amp = 2.0 * E[k, o] / np.hanning(n).sum()
        out.append((float(f[k]), o, float(amp)))
    return out


class PeriodicDisturbance(Cause):
    """A sinusoid added to the output (the controller sees it too)."""

    name = "periodic_disturbance"
    parameters = ("frequency_hz", "amplitude")
    n_free = 3  # a phase too
    meaning = "a sinusoid added to y (the controller sees it too)"
    extends = "disturbances"
    repeatable = True

    def fit(self, obj: Objective) -> tuple[Params, Model]:
        """Fit the parameters by the shared least-squares engine; extend the model."""
        base, fs = obj.base, obj.base.fs_high
        best: tuple[float, FloatArray, Model] | None = None
        for f0, o, amp in residual_peak(obj, base):

            def build(x: FloatArray, o: int = o) -> Model:
                return replace(
                    base,
                    disturbances=base.disturbances
                    + (
                        (
                            float(x[0]),
                            float(math.hypot(x[1], x[2])),
                            float(math.atan2(x[2], x[1])),
                            o,
                        ),
                    ),
                )

            df = fs / obj.rec.n_samples
            x, m = least_squares(
                obj,
                build,
                [[f0, amp, 0.0], [f0, 0.0, amp]],
                [max(f0 - 2 * df, 1e-6), -np.inf, -np.inf],
                [min(f0 + 2 * df, fs / 2), np.inf, np.inf],
                [0.1 * df, max(amp, 1e-12), max(amp, 1e-12)],
            )
            cost = obj.cost(m)
            if best is None or cost < best[0]:
                best = (cost, x, m)
        assert best is not None
        x = best[1]
        return {"frequency_hz": float(x[0]), "amplitude": float(math.hypot(x[1], x[2]))}, best[2]


#: The cause vocabulary, by name, in the order of the README table.
CAUSES: dict[str, Cause] = {
    c.name: c
    for c in (
        NoCause(),
        GainError(),
        InputDelay(),
        ExtraResonance(),
        ResonanceShift(),
        SamplingOffset(),
        ControlDelay(),
        PeriodicDisturbance(),
    )
}


def _check(name: str) -> Cause:
    if name not in CAUSES:
        raise ConfigError(f"cause must be one of {', '.join(CAUSES)}; got {name!r}")
    return CAUSES[name]


def objective(
    rec: LoopData, base: Model, noise: FloatArray, ident: Identification | None
) -> Objective:
    """The criterion on ``rec`` extending ``base`` (the identified plant for starting guesses)."""
    plant = (ident.plant.frequency, ident.plant.response) if ident is not None else None
    return Objective(rec, base, noise, plant)


def fit_one(cause: Cause, obj: Objective) -> CauseFit:
    """Fit ``cause`` with the engine and score it (BIC); inapplicable: score inf."""
    if not cause.applies(obj.base):
        return CauseFit(cause.name, {}, math.inf, {}, obj.base, applicable=False)
    params, model = cause.fit(obj)
    score, rss = obj.evaluate(model, cause.n_free)
    return CauseFit(cause.name, params, score, rss, model)


def fit_cause(
    cause: str,
    rec: LoopData,
    base: Model,
    noise: FloatArray,
    *,
    ident: Identification | None = None,
) -> CauseFit:
    """Fit one cause of :data:`CAUSES` on ``rec``, extending ``base``.

    ``noise`` from :func:`~mr_ident.diagnosis.noise.noise_spectrum`, ``ident`` (optional)
    from :func:`~mr_ident.diagnosis.evidence.identify_record` for starting guesses.
    """
    return fit_one(_check(cause), objective(rec, base, noise, ident))


def rank_causes(
    rec: LoopData,
    base: Model,
    noise: FloatArray,
    causes: tuple[str, ...] = tuple(CAUSES),
    *,
    ident: Identification | None = None,
) -> list[CauseFit]:
    """Fit every cause and rank them by BIC (lowest first; inapplicable ones last)."""
    chosen = [_check(c) for c in causes]
    obj = objective(rec, base, noise, ident)
    fits = [fit_one(c, obj) for c in chosen]
    return sorted(fits, key=lambda c: (not c.applicable, c.score))
