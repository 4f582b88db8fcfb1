# SPDX-License-Identifier: Apache-2.0
"""Causes between u and y: they change P_h itself.

Each starts from the identified plant: a weighted least-squares fit of the cause's
parameters to P̂_h (bins weighted by 1/σ̂², no simulation, so cheap) gives the proposals
that the time-domain criterion then refines and scores
(:mod:`~mr_ident.diagnosis.selection.forward`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import scipy.optimize

from ...numerics.arrays import FloatArray
from ...numerics.systems.model import Model, plant_poles
from .cause import Cause, Choice, Context, Params, PlantData, clip, damping_percent, hz, percent


def plant_modes(model: Model) -> list[tuple[float, float]]:
    """Lightly damped (ζ < 0.5) modes of the model file's continuous plant.

    (frequency_hz, damping), lowest first.
    """
    if model.plant.dt is not None:
        return []
    out = set()
    for p in plant_poles(model):
        if p.imag > 0:
            w = abs(p)
            z = -p.real / w
            if z < 0.5:
                out.add((round(float(w / (2 * np.pi)), 9), round(float(z), 9)))
    return sorted(out)


def _subsample(plant: PlantData, most: int = 1500) -> PlantData:
    ok = np.all(np.isfinite(plant.std) & (plant.std > 0), axis=(1, 2)) & (plant.frequency > 0)
    idx = np.nonzero(ok)[0]
    idx = idx[:: max(1, math.ceil(idx.size / most))]
    return PlantData(plant.frequency[idx], plant.response[idx], plant.std[idx])


class PlantCause(Cause):
    """A cause that changes P_h: proposals from a fit to the identified plant."""

    plant_side = True

    def starts(self, ctx: Context) -> list[Choice]:
        """Raw starting points (a grid, or guesses read off P̂ - P)."""
        raise NotImplementedError

    def applies(self, nominal: Model) -> bool:
        """Whether the cause can occur in this loop (a continuous plant)."""
        return nominal.plant.dt is None

    def frf_residual(self, ctx: Context, plant: PlantData, choice: Choice) -> FloatArray:
        """(P̂ - P(choice)) / σ̂ on the bins, real and imaginary parts."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                P = self.apply(ctx.current, choice).plant_discrete().freqresp(plant.frequency)
            except (ArithmeticError, ValueError, np.linalg.LinAlgError):
                return np.full(2 * plant.response.size, 1e3)
        e = ((plant.response - P) / plant.std).ravel()
        out = np.concatenate([e.real, e.imag])
        return out if np.all(np.isfinite(out)) else np.full(out.size, 1e3)

    def proposals(self, ctx: Context) -> list[Choice]:
        """The raw starts, the best of them refined on the identified plant."""
        raw = self.starts(ctx)
        if ctx.plant is None or not raw:
            return raw
        plant = _subsample(ctx.plant)
        if plant.frequency.size < 8:
            return raw
        costs = [float(np.sum(self.frf_residual(ctx, plant, c) ** 2)) for c in raw]
        order = np.argsort(costs)
        out = []
        for j in order[:2]:
            c = raw[int(j)]
            lo, hi, sc = self.bounds(ctx.nominal, c)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = scipy.optimize.least_squares(
                    lambda x, c=c: self.frf_residual(ctx, plant, replace(c, x=tuple(x))),
                    clip(c.x, lo, hi),
                    bounds=(lo, hi),
                    x_scale=sc,
                    max_nfev=40,
                    diff_step=1e-6,
                )
            out.append((float(res.cost), replace(c, x=tuple(float(v) for v in res.x))))
        out.sort(key=lambda t: t[0])
        return [c for _, c in out] + [raw[int(j)] for j in order[:2]]


class GainError(PlantCause):
    """The plant's gain differs: one factor on the plant."""

    name = "gain_error"
    parameters = ("gain",)
    meaning = "the plant's gain differs (true / nominal): a motor constant, an amplifier gain"
    extends = "plant_gain"

    def applies(self, nominal: Model) -> bool:
        """Any plant."""
        return True

    def starts(self, ctx: Context) -> list[Choice]:
        """The weighted least-squares ratio of P̂ to P, and 1."""
        out = [Choice(self.name, (1.0,))]
        if ctx.plant is not None and ctx.plant.frequency.size:
            p = _subsample(ctx.plant)
            P = ctx.current.plant_discrete().freqresp(p.frequency)
            w = 1.0 / p.std**2
            g = float(np.sum(w * np.real(np.conj(P) * p.response)) / np.sum(w * np.abs(P) ** 2))
            if math.isfinite(g) and g > 0:
                out.insert(0, Choice(self.name, (g,)))
        return out

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Gain in [0.05, 20]."""
        return np.array([0.05]), np.array([20.0]), np.array([0.1])

    def apply(self, model: Model, choice: Choice) -> Model:
        """The plant gain multiplied."""
        return replace(model, plant_gain=model.plant_gain * choice.x[0])

    def describe(self, params: Params) -> str:
        """In words."""
        return f"plant gain {params['gain']:.3g} x nominal ({percent(params['gain'])})"


class InputDelay(PlantCause):
    """An extra delay between u_h and the plant (exact ZOH, fractional samples)."""

    name = "input_delay"
    parameters = ("delay_s",)
    meaning = "an extra delay between u and the plant: drive or bus latency, a filter's lag"
    extends = "input_delay_s"

    def starts(self, ctx: Context) -> list[Choice]:
        """A grid of delays from a quarter to ten samples."""
        h = 1.0 / ctx.nominal.fs_high
        return [Choice(self.name, (k * h,)) for k in (0.25, 0.6, 1.0, 1.5, 2.5, 4.0, 6.0, 10.0)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """0 to 20 samples."""
        h = 1.0 / nominal.fs_high
        return np.array([0.0]), np.array([20 * h]), np.array([0.2 * h])

    def apply(self, model: Model, choice: Choice) -> Model:
        """The input delay lengthened."""
        return replace(model, input_delay=model.input_delay + choice.x[0])

    def describe(self, params: Params) -> str:
        """In words."""
        d = params["delay_s"]
        return f"an extra input delay of {1e3 * d:.3g} ms between u and the plant"


def _peaks(
    plant: PlantData, current: Model, k: int = 3
) -> list[tuple[float, complex, tuple[int, int]]]:
    """Where P̂ - P stands out most (σ units, smoothed, in its worst entry).

    (frequency_hz, P̂ - P there, (output, input) of that entry), the ``k`` largest peaks
    at least 10 % apart.
    """
    P = current.plant_discrete().freqresp(plant.frequency)
    d = plant.response - P
    K, ny, nu = d.shape
    z = (np.abs(d) / plant.std).reshape(K, -1)
    j = int(np.argmax(z.max(axis=0)))
    entry = (j // nu, j % nu)
    zs = np.convolve(z[:, j], np.ones(5) / 5, mode="same")
    out: list[tuple[float, complex, tuple[int, int]]] = []
    f = plant.frequency
    for _ in range(k):
        i = int(np.argmax(zs))
        if not np.isfinite(zs[i]) or zs[i] <= 0:
            break
        out.append((float(f[i]), complex(d.reshape(K, -1)[i, j]), entry))
        zs[np.abs(f - f[i]) < 0.1 * f[i] + 2 * (f[1] - f[0] if f.size > 1 else 0.0)] = -np.inf
    return out


class AdditiveMode(PlantCause):
    """An unmodelled mode adding to the plant: g w²/(s² + 2ζws + w²) in parallel."""

    name = "additive_mode"
    parameters = ("frequency_hz", "damping", "gain")
    meaning = (
        "an unmodelled structural mode adding to the plant (a frame or coupling resonance): "
        "g w²/(s²+2ζws+w²) in parallel, g its signed modal gain (static compliance)"
    )
    extends = "additive_modes"
    repeatable = True

    def starts(self, ctx: Context) -> list[Choice]:
        """At the peaks of |P̂ - P| / σ, the modal gain read off the peak for each damping."""
        if ctx.plant is None:
            return []
        out = []
        for f, d, (o, i) in _peaks(_subsample(ctx.plant), ctx.current):
            for z in (0.005, 0.02, 0.06, 0.2):
                # at resonance the mode adds -j g / (2 ζ)
                out.append(Choice(self.name, (f, z, float(-2.0 * z * d.imag)), (o, i)))
        return out

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Frequency in (fs/1000, fs/2), damping in [0.001, 1], any modal gain."""
        fs = nominal.fs_high
        g = max(abs(choice.x[2]), 1e-12)
        return (
            np.array([fs / 1000, 0.001, -np.inf]),
            np.array([0.499 * fs, 1.0, np.inf]),
            np.array([fs / 1000, 0.01, g]),
        )

    def apply(self, model: Model, choice: Choice) -> Model:
        """An additive mode appended."""
        f, z, g = choice.x
        o, i = (int(v) for v in choice.fixed) if choice.fixed else (0, 0)
        return replace(model, additive_modes=model.additive_modes + ((f, z, g, o, i),))

    def named(self, choice: Choice, nominal: Model) -> Params:
        """Frequency, damping, modal gain, and the entry (MIMO)."""
        out = super().named(choice, nominal)
        if nominal.n_y * nominal.n_u > 1 and choice.fixed:
            out |= {"output": float(choice.fixed[0]), "input": float(choice.fixed[1])}
        return out

    def describe(self, params: Params) -> str:
        """In words."""
        sign = "adding to" if params["gain"] > 0 else "subtracting from"
        return (
            f"an unmodelled mode at {hz(params['frequency_hz'])}, damping "
            f"{damping_percent(params['damping'])}, {sign} the plant (modal gain "
            f"{params['gain']:.3g})"
        )


class ModeShift(PlantCause):
    """A modelled mode at another frequency and damping, its modal numerator scaled."""

    name = "mode_shift"
    parameters = ("frequency_hz", "damping", "residue_scale")
    meaning = (
        "a modelled mode moved: its poles and its modal numerator (residue); numerator kept: "
        "the stiffness changed; numerator scaled with (f/f0)²: the mass changed"
    )
    extends = "mode_changes"

    def applies(self, nominal: Model) -> bool:
        """A continuous plant with a lightly damped mode."""
        return bool(plant_modes(nominal))

    def starts(self, ctx: Context) -> list[Choice]:
        """Each mode moved by -20..+25 %, as a stiffness or a mass change."""
        out = []
        for f0, z0 in plant_modes(ctx.nominal):
            for s in (0.8, 0.9, 0.95, 1.05, 1.1, 1.25):
                for scale in (1.0, s * s):
                    out.append(Choice(self.name, (f0 * s, z0, scale), (f0,)))
        return out

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Frequency within 0.5..2 f0 (below fs/2), damping in [0.001, 0.9], scale 0.1..10."""
        f0 = choice.fixed[0]
        return (
            np.array([0.5 * f0, 0.001, 0.1]),
            np.array([min(2.0 * f0, 0.499 * nominal.fs_high), 0.9, 10.0]),
            np.array([0.01 * f0, 0.01, 0.1]),
        )

    def apply(self, model: Model, choice: Choice) -> Model:
        """A mode change appended."""
        f, z, s = choice.x
        return replace(model, mode_changes=model.mode_changes + ((choice.fixed[0], f, z, s),))

    def named(self, choice: Choice, nominal: Model) -> Params:
        """Frequency, damping, residue scale; the mode it moved; stiffness and mass ratios.

        Mode ``c/(m s² + d s + k)``: the numerator scales with 1/m and w² = k/m, so
        ``m/m0 = 1/scale`` and ``k/k0 = (f/f0)² / scale``.
        """
        f, z, s = choice.x
        f0 = choice.fixed[0]
        z0 = min(plant_modes(nominal), key=lambda m: abs(m[0] - f0))[1]
        return {
            "frequency_hz": f,
            "damping": z,
            "residue_scale": s,
            "from_hz": f0,
            "from_damping": z0,
            "stiffness_ratio": (f / f0) ** 2 / s,
            "mass_ratio": 1.0 / s,
        }

    def describe(self, params: Params) -> str:
        """In words, saying whether the stiffness or the mass changed."""
        k, m = params["stiffness_ratio"], params["mass_ratio"]
        dk, dm = abs(k - 1.0), abs(m - 1.0)
        if dm < dk / 3:
            what = f"the stiffness changed ({percent(k)}), the modal mass did not"
        elif dk < dm / 3:
            what = f"the modal mass changed ({percent(m)}), the stiffness did not"
        else:
            what = f"stiffness {percent(k)} and modal mass {percent(m)}"
        return (
            f"the mode at {hz(params['from_hz'])} moved to {hz(params['frequency_hz'])}, "
            f"damping {damping_percent(params['from_damping'])[:-2]} -> "
            f"{damping_percent(params['damping'])}: "
            f"{what}"
        )


class SeriesLowpass(PlantCause):
    """A first-order low-pass in series: sensor or actuator bandwidth."""

    name = "series_lowpass"
    parameters = ("frequency_hz",)
    meaning = (
        "a first-order low-pass in series with the plant: a sensor's or an amplifier's "
        "bandwidth, w/(s+w) (one channel cannot tell sensor from actuator)"
    )
    extends = "series_dynamics"

    def starts(self, ctx: Context) -> list[Choice]:
        """Corner frequencies from fs/200 to 2 fs."""
        fs = ctx.nominal.fs_high
        return [Choice(self.name, (float(f),)) for f in np.geomspace(fs / 200, 2 * fs, 14)]

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Corner in [fs/1000, 10 fs]."""
        fs = nominal.fs_high
        return np.array([fs / 1000]), np.array([10 * fs]), np.array([choice.x[0] * 0.1])

    def apply(self, model: Model, choice: Choice) -> Model:
        """A first-order low-pass on the output."""
        return replace(
            model, series_dynamics=model.series_dynamics + ((choice.x[0], 0.0, "output", 0),)
        )

    def describe(self, params: Params) -> str:
        """In words."""
        return f"a series low-pass at {hz(params['frequency_hz'])} (sensor or actuator bandwidth)"


class SeriesResonance(PlantCause):
    """Second-order dynamics in series: an actuator or sensor resonance, or a 2-pole filter."""

    name = "series_resonance"
    parameters = ("frequency_hz", "damping")
    meaning = (
        "second-order dynamics in series with the plant, w²/(s²+2ζws+w²): a compliant "
        "coupling to the sensor, an actuator resonance, a two-pole filter (ζ near 0.7)"
    )
    extends = "series_dynamics"

    def starts(self, ctx: Context) -> list[Choice]:
        """A grid of frequencies and dampings, and the peaks of |P̂ - P|."""
        fs = ctx.nominal.fs_high
        out = [
            Choice(self.name, (float(f), z))
            for f in np.geomspace(fs / 100, 0.45 * fs, 10)
            for z in (0.05, 0.3, 0.8)
        ]
        if ctx.plant is not None:
            for f, _, _ in _peaks(_subsample(ctx.plant), ctx.current, 2):
                out += [Choice(self.name, (f, z)) for z in (0.02, 0.08)]
        return out

    def bounds(self, nominal: Model, choice: Choice) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Frequency in [fs/1000, fs/2], damping in [0.005, 1].

        A resonance: at most critically damped (an over-damped pair is two real poles,
        the far one a mere lag: the series low-pass and a delay say that with fewer
        values) and below the Nyquist frequency, where sampled data can show its peak.
        """
        fs = nominal.fs_high
        return (
            np.array([fs / 1000, 0.005]),
            np.array([0.5 * fs, 1.0]),
            np.array([0.01 * choice.x[0], 0.02]),
        )

    def apply(self, model: Model, choice: Choice) -> Model:
        """A second-order low-pass on the input."""
        f, z = choice.x
        return replace(model, series_dynamics=model.series_dynamics + ((f, z, "input", 0),))

    def describe(self, params: Params) -> str:
        """In words."""
        return (
            f"series second-order dynamics at {hz(params['frequency_hz'])}, damping "
            f"{damping_percent(params['damping'])} (an actuator or sensor resonance, or a filter)"
        )


PLANT_CAUSES: tuple[Cause, ...] = (
    GainError(),
    InputDelay(),
    AdditiveMode(),
    ModeShift(),
    SeriesLowpass(),
    SeriesResonance(),
)
