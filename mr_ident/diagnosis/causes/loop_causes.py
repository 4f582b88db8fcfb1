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
from ...numerics.systems.model import Model
from ..criterion.prediction import predict
from .cause import Cause, Choice, Context, Params, hz


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
    ControllerNotch(),
    ControlDelay(),
    SamplingOffset(),
    PeriodicDisturbance(),
)
