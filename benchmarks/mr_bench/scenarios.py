# SPDX-License-Identifier: Apache-2.0
"""Seeded random loops with hidden causes, for the diagnosis' tests and benchmark.

:func:`draw_scenario` draws a loop (:func:`draw_loop`), hides none, one or two causes in
it (:func:`draw_cause`, through :class:`~mr_ident.numerics.systems.model.Model` fields) and
simulates the true loop; :func:`~mr_bench.verdict.judge` tells whether a
diagnosis named them with their parameters within its tolerances. Draws (U uniform,
log-U log-uniform): fs_high in {240, 500, 1000} Hz, F in {1, 2, 3, 5}; a continuous
plant of order 2-6, with no integrator (one in two), 1/s or 1/s², in modal form (modes
``g w²/(s²+2ζws+w²)`` added, a rigid body ``1/s²`` or ``a/(s(s+a))`` with integrators,
an actuator low-pass for odd orders) or cascaded form (low-passes and resonances
multiplied, half with an anti-resonance below), modes log-U in fs_high/100..0.4 fs_high
and 30 % apart, damping U(0.01, 0.2), polynomials from roots as users write model files,
|P| = 1 at fb log-U in 0.01..0.1 fs_low; a lead, PI or PID with roll-off at fs_low, its
gain U(0.2, 0.5) times the critical gain; r white of std 1; output noise for an SNR
U(20, 60) dB. Each hidden cause keeps the loop stable and alone moves the noise-free y
by :data:`MIN_CHANGE` of its rms at least (else it is drawn again).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mr_ident.errors import ConfigError, MrIdentError
from mr_ident.numerics.arrays import FloatArray
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.simulate import loop_poles, simulate

from .verdict import CAUSE_NAMES

FS_HIGH: tuple[float, ...] = (240.0, 500.0, 1000.0)
RATIOS: tuple[int, ...] = (1, 2, 3, 5)
#: Least change of the noise-free y (rms, relative to y's) a hidden cause must make.
MIN_CHANGE = 0.03


@dataclass(frozen=True, eq=False)
class Loop:
    """A nominal loop (``noise_std`` set for ``snr_db``) and its noise-free record.

    ``integrators`` of the plant's ``order`` poles are at s = 0; ``modes`` are its complex
    pole pairs (natural frequency Hz, damping), lowest first; ``reference`` and ``y_clean``
    (N, 1) are the white-noise r of the record and the nominal's noise-free y.
    """

    nominal: Model
    form: str
    integrators: int
    order: int
    modes: tuple[tuple[float, float], ...]
    controller_kind: str
    gain_fraction: float
    snr_db: float
    reference: FloatArray
    y_clean: FloatArray


@dataclass(frozen=True)
class HiddenCause:
    """A cause hidden in a loop: its parameters and the Model fields it sets (:func:`apply`)."""

    cause: str
    parameters: dict[str, float]
    fields: dict[str, Any]

    def with_values(self, values: dict[str, float]) -> HiddenCause:
        """The same cause with some continuous parameters set to ``values`` (by name).

        Through :data:`PARAMETER_FIELDS`; the settings that are not parameters (which mode
        moved, a disturbance's phase) kept.
        """
        fields, params = dict(self.fields), dict(self.parameters)
        for name, v in values.items():
            key, i = PARAMETER_FIELDS[self.cause][name]
            if i is None:
                fields[key] = v
            else:
                entry = list(fields[key][0])
                entry[i] = v
                fields[key] = (tuple(entry),)
            params[name] = v
        return HiddenCause(self.cause, params, fields)


#: Where each continuous parameter of a hidden cause sits in its Model fields: (field,
#: index in the field's one entry, or None for a scalar field). Discrete ones are absent.
PARAMETER_FIELDS: dict[str, dict[str, tuple[str, int | None]]] = {
    "gain_error": {"gain": ("plant_gain", None)},
    "input_delay": {"delay_s": ("input_delay", None)},
    "additive_mode": {
        "frequency_hz": ("additive_modes", 0),
        "damping": ("additive_modes", 1),
        "gain": ("additive_modes", 2),
    },
    "mode_shift": {
        "frequency_hz": ("mode_changes", 1),
        "damping": ("mode_changes", 2),
        "residue_scale": ("mode_changes", 3),
    },
    "series_lowpass": {"frequency_hz": ("series_dynamics", 0)},
    "series_resonance": {
        "frequency_hz": ("series_dynamics", 0),
        "damping": ("series_dynamics", 1),
    },
    "controller_notch": {
        "frequency_hz": ("controller_notches", 0),
        "damping": ("controller_notches", 1),
        "depth": ("controller_notches", 2),
    },
    "periodic_disturbance": {
        "frequency_hz": ("disturbances", 0),
        "amplitude": ("disturbances", 1),
    },
}


@dataclass(frozen=True, eq=False)
class Scenario:
    """A loop, its hidden causes (none, one or two), the true model and its record.

    ``data``: r, u, y of the true loop with output noise, shape (N, 1) each; ``changes``:
    per hidden cause alone, the rms of the noise-free y's change over the rms of y.
    """

    loop: Loop
    hidden: tuple[HiddenCause, ...]
    true: Model
    data: LoopData
    changes: tuple[float, ...]

    @property
    def nominal(self) -> Model:
        """The model handed to the diagnosis."""
        return self.loop.nominal


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _plant(
    rng: np.random.Generator, fs: float, order: int, form: str, integrators: int
) -> tuple[FloatArray, FloatArray, list[tuple[float, float]]] | None:
    """(num, den, modes) of a random plant (the module docstring); None: draw again."""
    lo, hi, left = fs / 100, 0.4 * fs, order - integrators
    if form == "modal":
        n_modes, n_first = (order - 2 if integrators else order) // 2, order % 2
    else:
        n_modes = int(rng.integers(0, left // 2 + 1))
        n_first = left - 2 * n_modes
    f_modes = np.sort([_logu(rng, lo, hi) for _ in range(n_modes)])
    if np.any(f_modes[1:] / f_modes[:-1] < 1.3):
        return None  # modes 30 % apart
    modes = [(float(f), float(rng.uniform(0.01, 0.2))) for f in f_modes]
    if form == "modal":
        terms: list[tuple[Any, Any]] = []  # (num, den), added
        if integrators == 2:
            terms.append(([1.0], [1.0, 0.0, 0.0]))
        elif integrators == 1:
            a = 2 * np.pi * _logu(rng, lo, 0.1 * fs)
            terms.append(([a], [1.0, a, 0.0]))
        w_ref = 1.0 if integrators else 2 * np.pi * modes[0][0]
        for k, (f, z) in enumerate(modes):
            w = 2 * np.pi * f
            sign = -1.0 if k and rng.uniform() < 0.25 else 1.0
            g = sign * _logu(rng, 0.2, 2.0) * (w_ref / w) ** 2
            terms.append(([g * w * w], [1.0, 2 * z * w, w * w]))
        num, den = np.zeros(1), np.ones(1)
        for b, d in terms:
            num, den = np.polyadd(np.polymul(num, d), np.polymul(b, den)), np.polymul(den, d)
        if not integrators and np.polyval(num, 0.0) <= 0:
            return None  # a negative static gain: negative feedback would not hold
        if n_first:
            a = 2 * np.pi * _logu(rng, fs / 50, hi)
            num, den = a * num, np.asarray(np.polymul(den, [1.0, a]), float)
        return np.trim_zeros(num, "f"), den, modes
    zeros: list[complex] = []
    poles: list[complex] = [0.0] * integrators
    for f, z in modes:
        w = 2 * np.pi * f
        poles += list(np.roots([1.0, 2 * z * w, w * w]))
        proper = integrators + n_first > 0 or (f, z) != modes[-1]  # stays strictly proper
        if proper and rng.uniform() < 0.5:  # an anti-resonance below the resonance
            wz = w * rng.uniform(0.5, 0.85)
            zeros += list(np.roots([1.0, 2 * rng.uniform(0.01, 0.2) * wz, wz * wz]))
    poles += [-2 * np.pi * _logu(rng, lo, hi) for _ in range(n_first)]
    return np.atleast_1d(np.real(np.poly(zeros))), np.real(np.poly(poles)), modes


def _controller(
    rng: np.random.Generator, kind: str, fb: float, dt: float
) -> tuple[FloatArray, FloatArray]:
    """A lead, PI or PID with a roll-off at sample time ``dt`` (matched poles and zeros).

    The lead's zero and pole a factor U(1.7, 3.2) below and above fb, the PI's zero a
    factor U(3, 10) below, the roll-off U(4, 12) above; gain 1 at fb.
    """
    w = 2 * np.pi * fb
    zeros: list[float] = []
    poles = [w * rng.uniform(4.0, 12.0)]
    if kind in ("lead", "pid"):
        alpha = np.sqrt(rng.uniform(3.0, 10.0))
        zeros, poles = [w / alpha], [*poles, w * alpha]
    if kind in ("pi", "pid"):
        zeros, poles = [*zeros, w / rng.uniform(3.0, 10.0)], [*poles, 0.0]
    num = np.atleast_1d(np.poly(np.exp(-np.array(zeros) * dt)))
    den = np.asarray(np.poly(np.exp(-np.array(poles) * dt)), float)
    z = np.exp(1j * w * dt)
    return num / abs(np.polyval(num, z) / np.polyval(den, z)), den


def _stable(model: Model) -> bool:
    try:
        return bool(np.all(np.abs(loop_poles(model)) < 1.0))
    except (MrIdentError, ArithmeticError, np.linalg.LinAlgError):
        return False


def critical_gain(base: Model, num: FloatArray, den: FloatArray) -> float | None:
    """The gain k at which the loop of ``base`` with controller ``k num/den`` turns unstable.

    The first unstable gain after a stable one on 10^-3..10^3, bisected to 0.1 %; or None.
    """
    dt = base.ratio / base.fs_high

    def stable(k: float) -> bool:
        return _stable(replace(base, controller=TransferMatrix.siso(k * num, den, dt)))

    grid = np.geomspace(1e-3, 1e3, 19)
    seen = False
    for k0, k1 in zip(grid[:-1], grid[1:], strict=True):
        seen = seen or stable(k0)
        if seen and not stable(k1):
            lo, hi = float(k0), float(k1)
            while hi / lo > 1.001:
                mid = math.sqrt(lo * hi)
                lo, hi = (mid, hi) if stable(mid) else (lo, mid)
            return lo
    return None


def draw_loop(
    rng: np.random.Generator,
    *,
    duration: float = 60.0,
    fs_choices: Sequence[float] = FS_HIGH,
    ratios: Sequence[int] = RATIOS,
    max_draws: int = 200,
) -> Loop:
    """A random stable loop under a stabilising controller (see the module docstring).

    ``duration`` (s) sizes the record; fs_high and F are drawn from ``fs_choices`` and
    ``ratios``. ConfigError when ``max_draws`` draws give no stabilisable loop.
    """
    for _ in range(max_draws):
        fs, F = float(rng.choice(fs_choices)), int(rng.choice(ratios))
        order, form = int(rng.integers(2, 7)), str(rng.choice(["modal", "cascaded"]))
        integrators = int(rng.choice([0, 0, 1, 2]))
        drawn = _plant(rng, fs, order, form, integrators)
        kind = str(rng.choice(["lead", "pid"] if integrators else ["lead", "pi", "pid"]))
        fb, fraction = _logu(rng, 0.01, 0.1) * fs / F, float(rng.uniform(0.2, 0.5))
        if drawn is None:
            continue
        num, den, modes = drawn
        num = num / abs(np.polyval(num, 2j * np.pi * fb) / np.polyval(den, 2j * np.pi * fb))
        kn, kd = _controller(rng, kind, fb, F / fs)
        base = Model(fs, F, TransferMatrix.siso(num, den), TransferMatrix.siso(kn, kd, F / fs))
        kc = critical_gain(base, kn, kd) or 0.0  # 0: no stabilising gain found
        nominal = replace(base, controller=TransferMatrix.siso(fraction * kc * kn, kd, F / fs))
        if not kc or not _stable(nominal):
            continue
        N = F * int(round(duration * fs / F))
        r = nominal.reference_std * rng.standard_normal((N, 1))
        snr = float(rng.uniform(20.0, 60.0))
        y = simulate(nominal, reference=r, noise=np.zeros((N, 1))).y
        nominal = replace(nominal, noise_std=float(np.std(y)) * 10 ** (-snr / 20))
        return Loop(nominal, form, integrators, order, tuple(modes), kind, fraction, snr, r, y)
    raise ConfigError(f"no stabilisable loop in {max_draws} draws")


def draw_cause(cause: str, loop: Loop, rng: np.random.Generator) -> HiddenCause | None:
    """Parameters of ``cause`` for ``loop``; None: draw again, or it cannot occur there.

    gain_error 1 ± U(0.1, 0.4); input_delay U(0.3, 2.0) samples; additive_mode log-U
    (0.05, 0.4) fs_high, 15 % from the plant's modes, damping U(0.01, 0.1), a signed
    gain for a peak |g|/(2ζ) of log-U(0.3, 3) times the nominal |P| there; mode_shift a
    mode (f0, ζ0) to f = f0 (1 ± U(0.05, 0.25)) (below 0.45 fs_high, 10 % from other
    modes), a stiffness change (residue_scale 1, ζ = ζ0 f0/f) or a mass change
    (residue_scale (f/f0)², ζ = ζ0 f/f0), ζ times U(0.8, 1.25); series_lowpass (output,
    first order) log-U(0.05, 0.4) fs_high; series_resonance (input) the same, damping
    U(0.05, 0.7); controller_notch log-U(0.05, 0.45) fs_low, damping U(0.1, 0.5), depth
    U(0.01, 0.3); control_delay 1..F samples; sampling_offset 1..F-1 samples;
    periodic_disturbance log-U(0.02, 0.45) fs_high, amplitude U(0.05, 0.3) std(y), any
    phase. ConfigError for an unknown cause.
    """
    m, fs, F = loop.nominal, loop.nominal.fs_high, loop.nominal.ratio
    sign = float(rng.choice([-1.0, 1.0]))
    if cause == "gain_error":
        g = 1.0 + sign * rng.uniform(0.1, 0.4)
        return HiddenCause(cause, {"gain": g}, {"plant_gain": g})
    if cause == "input_delay":
        d = rng.uniform(0.3, 2.0) / fs
        return HiddenCause(cause, {"delay_s": d}, {"input_delay": d})
    if cause == "additive_mode":
        f, z = _logu(rng, 0.05 * fs, 0.4 * fs), rng.uniform(0.01, 0.1)
        g = sign * 2 * z * _logu(rng, 0.3, 3.0) * float(abs(m.plant.freqresp([f])[0, 0, 0]))
        if any(abs(f / f0 - 1.0) < 0.15 for f0, _ in loop.modes):
            return None
        p = {"frequency_hz": f, "damping": z, "gain": g}
        return HiddenCause(cause, p, {"additive_modes": ((f, z, g, 0, 0),)})
    if cause == "mode_shift":
        light = [mode for mode in loop.modes if mode[1] < 0.3]
        if not light:
            return None
        f0, z0 = light[int(rng.integers(len(light)))]
        ratio, mass = 1.0 + sign * rng.uniform(0.05, 0.25), bool(rng.uniform() < 0.5)
        f, s = f0 * ratio, ratio**2 if mass else 1.0
        z = min(z0 * (ratio if mass else 1 / ratio) * rng.uniform(0.8, 1.25), 0.3)
        if f > 0.45 * fs or any(abs(f / fm - 1) < 0.1 for fm, _ in loop.modes if fm != f0):
            return None
        p = {"frequency_hz": f, "damping": z, "residue_scale": s}
        return HiddenCause(cause, p, {"mode_changes": ((f0, f, z, s),)})
    if cause in ("series_lowpass", "series_resonance"):
        f, low = _logu(rng, 0.05 * fs, 0.4 * fs), cause == "series_lowpass"
        z = 0.0 if low else rng.uniform(0.05, 0.7)
        p = {"frequency_hz": f} if low else {"frequency_hz": f, "damping": z}
        side = "output" if low else "input"
        return HiddenCause(cause, p, {"series_dynamics": ((f, z, side, 0),)})
    if cause == "controller_notch":
        f = _logu(rng, 0.05 * m.fs_low, 0.45 * m.fs_low)
        z, depth = rng.uniform(0.1, 0.5), rng.uniform(0.01, 0.3)
        p = {"frequency_hz": f, "damping": z, "depth": depth}
        return HiddenCause(cause, p, {"controller_notches": ((f, z, depth),)})
    if cause == "control_delay":
        k = int(rng.integers(1, F + 1))
        return HiddenCause(cause, {"delay_samples": float(k)}, {"control_delay": k})
    if cause == "sampling_offset":
        if F == 1:
            return None
        k = int(rng.integers(1, F))
        return HiddenCause(cause, {"offset_samples": float(k)}, {"sample_phase": k})
    if cause == "periodic_disturbance":
        f = _logu(rng, 0.02 * fs, 0.45 * fs)
        a = rng.uniform(0.05, 0.3) * float(np.std(loop.y_clean))
        p = {"frequency_hz": f, "amplitude": a}
        return HiddenCause(cause, p, {"disturbances": ((f, a, rng.uniform(0, 2 * np.pi), 0),)})
    raise ConfigError(f"cause must be one of {', '.join(CAUSE_NAMES)}; got {cause!r}")


def apply(model: Model, hidden: Sequence[HiddenCause]) -> Model:
    """``model`` with the hidden causes' fields (tuples appended, other values replaced)."""
    changes: dict[str, Any] = {}
    for h in hidden:
        for key, value in h.fields.items():
            old = changes.get(key, getattr(model, key))
            changes[key] = old + value if isinstance(value, tuple) else value
    return replace(model, **changes)


def relative_change(loop: Loop, true: Model, seconds: float = 10.0) -> float:
    """The rms change of the noise-free y, nominal to ``true``, over its rms (first seconds)."""
    n = min(loop.reference.shape[0], true.ratio * math.ceil(seconds * true.fs_low))
    y0 = loop.y_clean[:n]
    y = simulate(true, reference=loop.reference[:n], noise=np.zeros_like(y0)).y
    return float(np.linalg.norm(y - y0) / np.linalg.norm(y0))


def draw_scenario(
    causes: Sequence[str],
    rng: np.random.Generator,
    *,
    duration: float = 60.0,
    fs_choices: Sequence[float] = FS_HIGH,
    ratios: Sequence[int] = RATIOS,
    max_loops: int = 200,
) -> Scenario:
    """A random loop with ``causes`` hidden in it, and its record.

    ``causes``: distinct names of :data:`CAUSE_NAMES`, none, one or a pair; ``rng`` the
    only source of randomness (the same state gives the same scenario); ``duration``,
    ``fs_choices``, ``ratios`` as :func:`draw_loop`. ConfigError for an unknown or
    repeated cause, or when no loop in ``max_loops`` draws can hide them.
    """
    if any(c not in CAUSE_NAMES for c in causes) or len(set(causes)) != len(causes):
        raise ConfigError(
            f"causes must be distinct names of {', '.join(CAUSE_NAMES)}; got {list(causes)}"
        )
    for _ in range(max_loops):
        loop = draw_loop(rng, duration=duration, fs_choices=fs_choices, ratios=ratios)
        hidden, changes = [], []
        for cause in causes:
            tried: set[str] = set()
            for _ in range(20):
                h = draw_cause(cause, loop, rng)
                if h is None or repr(h.fields) in tried:
                    continue
                tried.add(repr(h.fields))
                alone = apply(loop.nominal, [h])
                if _stable(alone) and (change := relative_change(loop, alone)) >= MIN_CHANGE:
                    hidden.append(h)
                    changes.append(change)
                    break
        true = apply(loop.nominal, hidden)
        if len(hidden) < len(causes) or not _stable(true):
            continue
        noise = true.noise_std * rng.standard_normal(loop.y_clean.shape)
        sim = simulate(true, reference=loop.reference, noise=noise)
        return Scenario(loop, tuple(hidden), true, sim, tuple(changes))
    raise ConfigError(f"no loop in {max_loops} draws can hide {list(causes)}")
