# SPDX-License-Identifier: Apache-2.0
"""Causes outside the plant: in the controller's path (timing, filters) and on the output.

They leave P_h as it is (the lifted identification does not use the controller), so the
identified plant says nothing of them; the time-domain criterion does
(:mod:`~mr_ident.diagnosis.selection.forward`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ...numerics.arrays import FloatArray
from ...numerics.systems.lti import TransferMatrix
from ...numerics.systems.model import Model
from ..criterion.prediction import predict
from .cause import Cause, Choice, Context, Params, hz, percent


class _LoopCause(Cause):
    plant_side = False


class ControlDelay(_LoopCause):
    """The controller's held output is applied later than the model says."""

    controller_side = True
    name = "control_delay"
    parameters = ("delay_samples",)
    meaning = (
        "the controller's output is applied later than modelled: computation time, a bus "
        "cycle (whole high-rate samples)"
    )
    extends = "control_delay"
    discrete = True

    def applies(self, nominal: Model) -> bool:
        """With a controller."""
        return nominal.controller is not None

    def values(self, nominal: Model) -> list[float]:
        """One to 2F samples later."""
        return [float(d) for d in range(1, 2 * nominal.ratio + 1)]

    def proposals(self, ctx: Context) -> list[Choice]:
        """Every value."""
        return [Choice(self.name, (v,)) for v in self.values(ctx.nominal)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Not optimised (discrete)."""
        return np.array([1.0]), np.array([2.0 * nominal.ratio]), np.array([1.0])

    def apply(self, model: Model, choice: Choice) -> Model:
        """The control delay lengthened."""
        return replace(model, control_delay=model.control_delay + int(choice.x[0]))

    def describe(self, params: Params) -> str:
        """In words."""
        k = int(params["delay_samples"])
        if k < 0:  # from the controller's equation: the model's delay was too long
            return (
                f"the control output is applied {-k} high-rate sample{'s' * (k != -1)} earlier "
                "than modelled"
            )
        return f"the control output is applied {k} high-rate sample{'s' * (k != 1)} later"


class SamplingOffset(_LoopCause):
    """The controller samples y at another high-rate phase than the model's."""

    controller_side = True
    name = "sampling_offset"
    parameters = ("offset_samples",)
    meaning = "the controller samples y at another high-rate instant within its period"
    extends = "sample_phase"
    discrete = True

    def applies(self, nominal: Model) -> bool:
        """With a controller and F > 1."""
        return nominal.controller is not None and nominal.ratio > 1

    def values(self, nominal: Model) -> list[float]:
        """Every other phase."""
        base, F = nominal.sample_phase, nominal.ratio
        return [float(o) for o in range(-base, F - base) if o != 0]

    def proposals(self, ctx: Context) -> list[Choice]:
        """Every value."""
        return [Choice(self.name, (v,)) for v in self.values(ctx.nominal)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Not optimised (discrete)."""
        return np.array([-float(nominal.ratio)]), np.array([float(nominal.ratio)]), np.ones(1)

    def apply(self, model: Model, choice: Choice) -> Model:
        """The sampling phase moved."""
        return replace(model, sample_phase=model.sample_phase + int(choice.x[0]))

    def describe(self, params: Params) -> str:
        """In words."""
        return f"the controller samples y {int(params['offset_samples']):+d} high-rate samples off"


class ControllerNotch(_LoopCause):
    """A notch filter in the controller that the model lacks."""

    controller_side = True
    name = "controller_notch"
    parameters = ("frequency_hz", "damping", "depth")
    meaning = (
        "a notch in the controller that the model lacks (a filter added on the machine): "
        "(s²+2·depth·ζws+w²)/(s²+2ζws+w²) at fs_low"
    )
    extends = "controller_notches"

    def applies(self, nominal: Model) -> bool:
        """With a controller."""
        return nominal.controller is not None

    def proposals(self, ctx: Context) -> list[Choice]:
        """Notch frequencies across the controller's band."""
        fl = ctx.nominal.fs_low
        return [
            Choice(self.name, (float(f), 0.3, 0.1)) for f in np.geomspace(fl / 60, 0.46 * fl, 12)
        ]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Frequency below fs_low/2, damping 0.02..2, depth 0..1."""
        fl = nominal.fs_low
        return (
            np.array([fl / 200, 0.02, 0.0]),
            np.array([0.49 * fl, 2.0, 1.0]),
            np.array([0.01 * choice.x[0], 0.05, 0.05]),
        )

    def apply(self, model: Model, choice: Choice) -> Model:
        """A controller notch appended."""
        f, z, d = choice.x
        return replace(model, controller_notches=model.controller_notches + ((f, z, d),))

    def describe(self, params: Params) -> str:
        """In words."""
        depth_db = 20 * math.log10(max(params["depth"], 1e-6))
        width = 2 * params["damping"] * params["frequency_hz"]
        return (
            f"a notch at {hz(params['frequency_hz'])} in the controller that the model lacks "
            f"(depth {depth_db:.0f} dB, width about {hz(width)})"
        )


class ControllerGain(_LoopCause):
    """The controller's gain differs from the model's by a factor."""

    controller_side = True
    name = "controller_gain"
    parameters = ("gain",)
    meaning = (
        "the controller's gain differs from the model's: a retuned proportional gain, a scaled "
        "sensor or actuator constant inside the controller"
    )
    extends = "controller"

    def applies(self, nominal: Model) -> bool:
        """With a controller."""
        return nominal.controller is not None

    def proposals(self, ctx: Context) -> list[Choice]:
        """Lower and higher."""
        return [Choice(self.name, (g,)) for g in (0.8, 1.25)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """A factor 0.05..20."""
        return np.array([0.05]), np.array([20.0]), np.array([0.05])

    def apply(self, model: Model, choice: Choice) -> Model:
        """The controller's numerators scaled."""
        K = model.controller
        assert K is not None
        g = float(choice.x[0])
        num = tuple(tuple(tuple(g * c for c in p) for p in row) for row in K.num)
        return replace(model, controller=TransferMatrix(num, K.den, K.dt))

    def describe(self, params: Params) -> str:
        """In words."""
        g = params["gain"]
        return f"the controller's gain is {g:.4g} times the model's ({percent(g)})"


class ControllerRetuned(_LoopCause):
    """The controller's coefficients differ: a retuned controller, or one of higher order.

    ``Choice.x``: the numerator's coefficients (descending powers of z, ``order + 1``) and
    the denominator's after its leading 1 (``order``); ``Choice.fixed``: ``(order,)``. Only
    the controller's own equation determines it
    (:func:`~mr_ident.diagnosis.controller.relation.retune_start`): no proposal on y.
    """

    controller_side = True
    name = "controller_retuned"
    parameters = ("coefficients",)
    meaning = (
        "the controller on the machine is not the model's: its coefficients identified from "
        "the logged u and y (a retuned PID, an added filter); the model's controller replaced"
    )
    extends = "controller"

    def applies(self, nominal: Model) -> bool:
        """One input and one output, a controller and no controller notch."""
        return (
            nominal.controller is not None
            and nominal.n_u == nominal.n_y == 1
            and not nominal.controller_notches
        )

    @property
    def n_free(self) -> int:
        """A second-order controller's five (counted so for the choice among closing sets)."""
        return 5

    def free_in(self, choice: Choice) -> int:
        """Its coefficients, 2 n + 1 at order n.

        Of two orders that both close the controller's equation (a pole cancelling a zero),
        the lower is chosen, not the one round-off favours.
        """
        return 2 * int(choice.fixed[0]) + 1

    def proposals(self, ctx: Context) -> list[Choice]:
        """None: the equation fits it."""
        return []

    def value_names(self, choice: Choice) -> tuple[str, ...]:
        """b0..b_order, a1..a_order."""
        n = int(choice.fixed[0])
        return tuple(f"b{i}" for i in range(n + 1)) + tuple(f"a{i}" for i in range(1, n + 1))

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Unbounded."""
        x = np.asarray(choice.x, float)
        return np.full(x.size, -np.inf), np.full(x.size, np.inf), np.maximum(np.abs(x), 1e-3)

    def apply(self, model: Model, choice: Choice) -> Model:
        """The controller replaced."""
        n = int(choice.fixed[0])
        K = model.controller
        assert K is not None
        b, a = choice.x[: n + 1], (1.0, *choice.x[n + 1 :])
        return replace(model, controller=TransferMatrix(((tuple(b),),), ((a,),), K.dt))

    def named(self, choice: Choice, nominal: Model) -> Params:
        """The coefficients, the order, and how far the response moved.

        ``max_relative_change``: the largest ``|K'/K - 1|`` over 1e-3..0.49 fs_low, ``at_hz``
        where.
        """
        out = dict(zip(self.value_names(choice), map(float, choice.x), strict=True))
        K0 = nominal.controller
        assert K0 is not None
        K1 = self.apply(nominal, choice).controller
        assert K1 is not None
        f = np.geomspace(1e-3, 0.49, 200) * nominal.fs_low
        z = np.exp(2j * np.pi * f / nominal.fs_low)
        with np.errstate(all="ignore"):
            rel = np.abs(K1(z)[:, 0, 0] / K0(z)[:, 0, 0] - 1.0)
        rel = np.where(np.isfinite(rel), rel, 0.0)
        j = int(np.argmax(rel))
        n0 = max(len(K0.den[0][0]) - 1, 0)
        return out | {
            "order": float(choice.fixed[0]),
            "model_order": float(n0),
            "max_relative_change": float(rel[j]),
            "at_hz": float(f[j]),
        }

    def describe(self, params: Params) -> str:
        """In words."""
        n, n0 = int(params["order"]), int(params["model_order"])
        what = (
            f"a retuned controller of the model's order ({n})"
            if n == n0
            else f"a controller of order {n} (the model's is {n0}): a filter the model lacks"
        )
        return (
            f"the controller on the machine is {what}, identified from the logged u and y; its "
            f"response differs from the model's by up to {100 * params['max_relative_change']:.0f}"
            f" % (at {hz(params['at_hz'])})"
        )


#: Family-wise false-alarm level of a residual peak: below it no disturbance is proposed.
PEAK_ALPHA = 1e-3
#: Bins of the running median a residual peak is held against.
PEAK_WINDOW = 257


def residual_peaks(ctx: Context, k: int = 2) -> list[tuple[float, int, float]]:
    """Candidate disturbance frequencies: narrow peaks of the y residual's periodogram.

    (frequency_hz, output, amplitude), per output the ``k`` largest peaks of
    ``|E(k)|² / m(k)``, m the larger of two running medians of ``|E|²`` (over
    :data:`PEAK_WINDOW` bins, and over the neighbours 3 to 12 bins away) divided by ln 2
    (the median of an exponential), that exceed ``ln(n_bins / PEAK_ALPHA)``:
    under noise alone each ratio is about Exp(1), so the largest of n passes with
    probability about PEAK_ALPHA (a detector with a constant false-alarm rate). The local
    median follows whatever is broad in the residual (the noise as the loop shapes it, a
    model error elsewhere) and ignores a sinusoid's few bins; the near one tells a sinusoid
    (one or two bins) from noise through a lightly damped closed-loop pole (a hump a few bins
    wide, which a wide median would flatten); the noise spectrum of the
    criterion cannot serve here, since the LPM counts a disturbance r does not explain as
    noise over its whole window. The gate matters because a sinusoid on y passes the
    controller's sampler and comes back at its aliases, so one fitted disturbance can take
    up noise at F frequencies at once: the BIC's three parameters under-count that search.
    """
    import scipy.ndimage

    obj, base = ctx.objective, ctx.current
    pred = predict(base, obj.rec)
    s = obj.settle
    e = np.where(obj.missing_y[s:], 0.0, obj.y[s:] - pred.y[s:])  # a hole: no residual
    n = e.shape[0]
    E = np.fft.rfft(e, axis=0, norm="ortho")
    P = np.abs(E) ** 2
    wide = scipy.ndimage.median_filter(P, size=(PEAK_WINDOW, 1), mode="nearest")
    ring = np.ones((25, 1), bool)
    ring[10:15] = False  # the neighbours 3..12 bins away, not the peak's own leakage
    near = scipy.ndimage.median_filter(P, footprint=ring, mode="nearest")
    local = np.maximum(wide, near) / math.log(2)
    Z = P / np.maximum(local, 1e-300)
    f = np.fft.rfftfreq(n, 1.0 / base.fs_high)
    level = math.log(Z.shape[0] / PEAK_ALPHA)
    out = []
    for o in range(E.shape[1]):
        mag = Z[:, o].copy()
        mag[0] = 0.0
        for _ in range(k):
            j = int(np.argmax(mag))
            if mag[j] < level:
                break
            out.append((float(f[j]), o, float(2.0 * np.abs(E[j, o]) / np.sqrt(n))))
            mag[max(j - 8, 0) : j + 9] = 0.0
    return out


class PeriodicDisturbance(_LoopCause):
    """A sinusoid added to the output (the controller sees it too)."""

    name = "periodic_disturbance"
    parameters = ("frequency_hz", "in_phase", "quadrature")
    meaning = (
        "a sinusoid added to y that the controller also sees: an unbalance, a cogging or "
        "mains-frequency pick-up"
    )
    extends = "disturbances"
    repeatable = True
    linear = (1, 2)

    def proposals(self, ctx: Context) -> list[Choice]:
        """At the residual's spectral peaks (amplitude and phase are then solved for)."""
        obj = ctx.objective
        df = 2.0 * ctx.nominal.fs_high / max(obj.rec.n_samples - obj.settle, 1)
        return [Choice(self.name, (f, a, a), (float(o), df)) for f, o, a in residual_peaks(ctx)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Frequency within two bins of the start."""
        f, a, b = choice.x
        fs = nominal.fs_high
        df = choice.fixed[1] if len(choice.fixed) > 1 else 0.002 * f
        amp = max(math.hypot(a, b), 1e-12)
        return (
            np.array([max(f - df, 1e-6), -20 * amp, -20 * amp]),
            np.array([min(f + df, fs / 2), 20 * amp, 20 * amp]),
            np.array([0.05 * df, amp, amp]),
        )

    def apply(self, model: Model, choice: Choice) -> Model:
        """A sinusoid appended to the output disturbances."""
        f, a, b = choice.x
        o = int(choice.fixed[0]) if choice.fixed else 0
        dist = (f, float(math.hypot(a, b)), float(math.atan2(b, a)), o)
        return replace(model, disturbances=model.disturbances + (dist,))

    def named(self, choice: Choice, nominal: Model) -> Params:
        """Frequency, amplitude and phase."""
        f, a, b = choice.x
        return {"frequency_hz": f, "amplitude": math.hypot(a, b), "phase_rad": math.atan2(b, a)}

    def describe(self, params: Params) -> str:
        """In words."""
        return (
            f"a periodic disturbance at {hz(params['frequency_hz'])} on y, amplitude "
            f"{params['amplitude']:.3g}"
        )


LOOP_CAUSES: tuple[Cause, ...] = (
    ControllerGain(),
    ControllerNotch(),
    ControllerRetuned(),
    ControlDelay(),
    SamplingOffset(),
    PeriodicDisturbance(),
)
