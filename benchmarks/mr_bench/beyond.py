# SPDX-License-Identifier: Apache-2.0
"""Seeded random loops beyond the linear vocabulary: nonlinear actuators and unlisted effects.

The loop is :func:`~mr_bench.scenarios.draw_loop`'s; two records of it are simulated, the
second handed to the diagnosis as its validation record.

- **Nonlinear** (:data:`NONLINEAR`): the plant's input goes through a dead zone (width
  ``2 level σ_u``), a saturation (at ``σ_u / level``), Coulomb friction (``u - level σ_u
  sign(dy)``, dy the plant output's last step: the velocity where y is a position) or
  backlash (play ``2 level σ_u``), σ_u the rms of u in the linear loop, ``level`` from
  :data:`LEVELS`. Excited by a periodic multisine of 1 s periods (6 periods, the first a
  transient), one realization per record: ``odd`` (every odd line, :data:`DESIGNS`) or
  ``full`` (every line, random phases); lifted (no colliding aliases) when F > 1.
- **Outside the vocabulary** (:data:`UNLISTED`): a pole-zero pair in series with the
  plant (pole log-U(0.05, 0.35) fs_high, the zero a factor U(0.6, 0.85) or U(1.2, 1.6) from
  it, damping U(0.02, 0.1) each, unit DC gain), a second delay path (``u + c u[n - k]``,
  k 3..10 samples, |c| U(0.15, 0.4)), or a time-varying gain (``1 + a sin(2π t / T)``, a
  U(0.1, 0.3), T U(0.3, 1) of the record); white r of std 1, records of ``duration``.
  How far such an effect stands out of the noise (:func:`effect_db`) is measured on the
  validation record: a pole pair drawn where the loop has no gain left changes y less than
  its noise, and no diagnosis can be asked to correct it.

The loop is simulated sample by sample (the controller at its phase, the hold, the
control delay, as :func:`~mr_ident.numerics.systems.simulate.lifted_loop`) with the
actuator's map between the commanded u (what is logged) and the plant; the pole-zero pair
is linear and simulated by :func:`~mr_ident.numerics.systems.simulate.simulate`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from mr_ident.errors import ConfigError
from mr_ident.numerics.arrays import FloatArray
from mr_ident.numerics.excitation.multisine import design
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.simulate import loop_poles, simulate

from .scenarios import Loop, draw_loop

NONLINEAR: tuple[str, ...] = ("dead_zone", "saturation", "coulomb_friction", "backlash")
UNLISTED: tuple[str, ...] = ("pole_zero_pair", "second_delay_path", "time_varying_gain")
LEVELS: tuple[float, ...] = (0.1, 0.3, 1.0)
DESIGNS: tuple[str, ...] = ("odd", "full")
PERIODS = 6


@dataclass(frozen=True, eq=False)
class Beyond:
    """A loop with an effect beyond the vocabulary, its records and the truth.

    ``effect`` a name of :data:`NONLINEAR` or :data:`UNLISTED`; ``parameters`` its values;
    ``data``, ``validation`` the two records; ``true`` the true model where the effect is
    linear and time-invariant (the pole-zero pair), else None; ``distortion_db`` the true
    stochastic distortion above the noise of the period means, dB, the largest of four
    log-spaced bands (nonlinear cases; nan otherwise); ``effect_db`` the unlisted effect's
    change of y above the noise on the validation record (:func:`effect_db`; nan for the
    nonlinear cases); ``clean`` the noise-free y of the true loop under the validation
    record's r (unlisted effects; None for the nonlinear ones).
    """

    loop: Loop
    effect: str
    parameters: dict[str, float]
    data: LoopData
    validation: LoopData
    true: Model | None
    distortion_db: float
    design: str
    effect_db: float = math.nan
    clean: FloatArray | None = None

    def truth_fit(self) -> float:
        """The true loop's validation fit of y (%), as the diagnosis measures a model's.

        Its noise-free output against the validation record from the nominal's settling on
        (``fit_percent`` after ``settle_samples``, as ``diagnose`` skips a separate
        record's transient): the best any model can reach there. nan without ``clean``.
        """
        from mr_ident.diagnosis.criterion.objective import settle_samples
        from mr_ident.diagnosis.criterion.prediction import fit_percent

        if self.clean is None:
            return math.nan
        s = settle_samples(self.nominal, self.validation.n_samples)
        return fit_percent(self.validation.y[s:], self.clean[s:])

    @property
    def nominal(self) -> Model:
        """The model handed to the diagnosis."""
        return self.loop.nominal

    @property
    def nonlinear(self) -> bool:
        """Whether the effect is a nonlinearity."""
        return self.effect in NONLINEAR


Actuator = Callable[[float, float], float]


def _actuator(effect: str, p: dict[str, float], fs: float) -> Callable[[], Actuator]:
    """A factory of the actuator map w = g(u, dy) (a fresh state per record)."""
    if effect == "dead_zone":
        d = p["width"] / 2
        return lambda: lambda u, dy: math.copysign(max(abs(u) - d, 0.0), u)
    if effect == "saturation":
        s = p["limit"]
        return lambda: lambda u, dy: min(max(u, -s), s)
    if effect == "coulomb_friction":
        fc = p["force"]
        return lambda: lambda u, dy: u - fc * ((dy > 0) - (dy < 0))
    if effect == "backlash":
        g = p["play"] / 2

        def make() -> Actuator:
            b = [0.0]

            def play(u: float, dy: float) -> float:
                if u > b[0] + g:
                    b[0] = u - g
                elif u < b[0] - g:
                    b[0] = u + g
                return b[0]

            return play

        return make
    if effect == "second_delay_path":
        k, c = int(p["delay_samples"]), p["gain"]

        def make_path() -> Actuator:
            past = [0.0] * k

            def path(u: float, dy: float) -> float:
                old = past.pop(0)
                past.append(u)
                return u + c * old

            return path

        return make_path
    if effect == "time_varying_gain":
        a, w = p["amplitude"], 2 * math.pi / p["period_s"]

        def make_gain() -> Actuator:
            n = [0]

            def gain(u: float, dy: float) -> float:
                n[0] += 1
                return u * (1.0 + a * math.sin(w * (n[0] - 1) / fs))

            return gain

        return make_gain
    raise ConfigError(f"effect must be one of {', '.join(NONLINEAR + UNLISTED)}; got {effect!r}")


def simulate_actuated(
    model: Model,
    r: FloatArray,
    v: FloatArray,
    act: Actuator,
    sensor: Callable[[float], float] | None = None,
) -> LoopData:
    """The SISO loop of ``model`` with ``act`` between the commanded u and the plant.

    Sample by sample: y[n] = C x[n] + v[n] (D = 0: a held strictly proper plant); at the
    sampling phase the controller takes y[n]; its output is held from sample
    ``phase + control_delay`` of the period on; u[n] = r[n] - held; the plant takes
    ``act(u[n], y_clean[n] - y_clean[n-1])``; ``sensor`` maps what is measured (y[n], as the
    controller and the log see it). Equals
    :func:`~mr_ident.numerics.systems.simulate.simulate` for the identity map (to rounding).
    """
    P, K = model.plant_discrete(), model.controller_ss()
    if np.any(P.D != 0.0) or P.shape != (1, 1):
        raise ConfigError("simulate_actuated needs a SISO strictly proper P_h (D = 0)")
    A, B, C = P.A, P.B[:, 0], P.C[0]
    Ak, Bk, Ck, Dk = K.A, K.B[:, 0], K.C[0], float(K.D[0, 0])
    F, phase, delay = model.ratio, model.sample_phase, model.control_delay
    N = r.shape[0]
    u, y = np.empty(N), np.empty(N)
    x, xk = np.zeros(A.shape[0]), np.zeros(Ak.shape[0])
    held, pending = 0.0, deque[tuple[int, float]]()  # (sample it acts from, value)
    last = 0.0
    rr, vv = r[:, 0].tolist(), v[:, 0].tolist()
    for n in range(N):
        clean = float(C @ x)
        y[n] = clean + vv[n] if sensor is None else sensor(clean + vv[n])
        if n % F == phase:
            pending.append((n + delay, float(Ck @ xk) + Dk * y[n]))
            xk = Ak @ xk + Bk * y[n]
        while pending and pending[0][0] <= n:
            held = pending.popleft()[1]
        u[n] = rr[n] - held
        x = A @ x + B * act(u[n], clean - last)
        last = clean
    return LoopData(r, u[:, None], y[:, None], fs_high=model.fs_high, ratio=F)


def _multisine(loop: Loop, kind: str, seed: int, realizations: int) -> tuple[FloatArray, int]:
    """(realizations, PERIODS N, 1) of a multisine with 1 s periods, and N."""
    m = loop.nominal
    N = m.ratio * max(int(round(m.fs_high / m.ratio)), 64)
    ms = design(fs_high=m.fs_high, period=N, band=(m.fs_high / N, 0.45 * m.fs_high), kind=kind,
                periods=PERIODS, realizations=realizations, ratio=m.ratio,
                lifted=m.ratio > 1, seed=seed)  # fmt: skip
    return ms.r, N


def _stable(model: Model) -> bool:
    return bool(np.max(np.abs(loop_poles(model)), initial=0.0) < 1.0)


def _pole_zero(loop: Loop, rng: np.random.Generator) -> tuple[Model, dict[str, float]] | None:
    fs = loop.nominal.fs_high
    fp = math.exp(rng.uniform(math.log(0.05 * fs), math.log(0.35 * fs)))
    fz = fp * (rng.uniform(0.6, 0.85) if rng.uniform() < 0.5 else rng.uniform(1.2, 1.6))
    if fz > 0.45 * fs:
        return None
    zp, zz = rng.uniform(0.02, 0.1), rng.uniform(0.02, 0.1)
    wp, wz = 2 * math.pi * fp, 2 * math.pi * fz
    k = wp * wp / (wz * wz)
    if not isinstance(loop.nominal.plant, TransferMatrix):
        return None
    plant = loop.nominal.plant.times([k, k * 2 * zz * wz, wp * wp], [1.0, 2 * zp * wp, wp * wp])
    true = replace(loop.nominal, plant=plant)
    p = {"pole_hz": fp, "pole_damping": zp, "zero_hz": fz, "zero_damping": zz}
    return (true, p) if _stable(true) else None


def draw_effect(
    effect: str, loop: Loop, rng: np.random.Generator, level: float, duration: float
) -> dict[str, float]:
    """The effect's parameters (the module docstring); ConfigError for an unknown effect."""
    m = loop.nominal
    sim = simulate(m, reference=loop.reference, noise=np.zeros_like(loop.y_clean))
    sigma_u = float(np.std(sim.u))
    if effect == "dead_zone":
        return {"width": 2 * level * sigma_u, "level": level}
    if effect == "saturation":
        return {"limit": sigma_u / level, "level": level}
    if effect == "coulomb_friction":
        return {"force": level * sigma_u, "level": level}
    if effect == "backlash":
        return {"play": 2 * level * sigma_u, "level": level}
    if effect == "second_delay_path":
        c = float(rng.choice([-1.0, 1.0])) * rng.uniform(0.15, 0.4)
        return {"delay_samples": float(rng.integers(3, 11)), "gain": c}
    if effect == "time_varying_gain":
        return {"amplitude": rng.uniform(0.1, 0.3), "period_s": rng.uniform(0.3, 1.0) * duration}
    if effect == "pole_zero_pair":
        return {}
    raise ConfigError(f"effect must be one of {', '.join(NONLINEAR + UNLISTED)}; got {effect!r}")


def distortion_db(
    model: Model, act: Callable[[], Actuator], r: FloatArray, N: int, noise_std: float
) -> float:
    """True stochastic distortion above the noise of the period means, dB (worst band).

    ``r`` (M, PERIODS N, 1): M realizations, each simulated noise-free in steady state (the
    periods after the record's length of it once, the first dropped); per excited line the
    spread of ``Ȳ_m / R̄_m`` over the realizations (the nonlinear variance) against the
    variance the output noise (through the linear loop) leaves in ``Ȳ / R̄`` after the
    period mean; four log-spaced bands over the excited lines.
    """
    M, n = r.shape[0], r.shape[1]
    G = []
    for m in range(M):
        # in steady state: the record's periods after as many again (a slow loop's transient
        # outlasts one period, and differs per realization: it read as distortion, 12-21 dB
        # through a linear actuator)
        rr = np.concatenate([r[m], r[m]])
        rec = simulate_actuated(model, rr, np.zeros_like(rr), act())
        Y = np.fft.rfft(rec.y[n + N :, 0].reshape(-1, N), axis=1).mean(axis=0)
        R = np.fft.rfft(r[m, N:, 0].reshape(-1, N), axis=1).mean(axis=0)
        G.append((Y, R))
    R0 = G[0][1]
    lines = np.nonzero(np.abs(R0) > 1e-6 * np.abs(R0).max())[0]
    lines = lines[lines > 0]
    H = np.array([Y[lines] / R[lines] for Y, R in G])
    nl = np.var(H, axis=0, ddof=1) if M > 1 else np.zeros(lines.size)
    rng = np.random.default_rng(0)
    v = noise_std * rng.standard_normal((r.shape[1], 1))
    yv = simulate(model, reference=np.zeros((r.shape[1], 1)), noise=v).y[N:, 0].reshape(-1, N)
    Yv = np.fft.rfft(yv, axis=1)
    noise = np.var(Yv[:, lines], axis=0, ddof=1) / Yv.shape[0] / np.abs(R0[lines]) ** 2
    f = lines * model.fs_high / N
    edges = np.geomspace(f[0], f[-1] * (1 + 1e-9), 5)
    levels = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        b = (f >= lo) & (f < hi)
        if b.any():
            levels.append(10 * math.log10(1.0 + np.mean(nl[b]) / np.mean(noise[b])))
    return max(levels)


def effect_db(model: Model, y_true: FloatArray, r: FloatArray) -> float:
    """The change an unlisted effect makes to y, above the noise, dB (worst band).

    ``y_true`` the noise-free output of the loop with the effect under ``r``; against the
    nominal loop's noise-free output under the same r, after its transient
    (:func:`~mr_ident.diagnosis.criterion.objective.settle_samples`): per band (four
    log-spaced) ``10 log10(1 + mean |ΔY|² / mean |Y_v|²)``, Y_v the output noise through
    the nominal loop (one seeded realization), as :func:`distortion_db` measures the
    distortion.
    """
    from mr_ident.diagnosis.criterion.objective import settle_samples

    n = r.shape[0]
    skip = settle_samples(model, n)
    y_nom = simulate(model, reference=r, noise=np.zeros((n, 1))).y
    v = model.noise_std * np.random.default_rng(0).standard_normal((n, 1))
    y_v = simulate(model, reference=np.zeros((n, 1)), noise=v).y
    dY = np.fft.rfft(y_true[skip:, 0] - y_nom[skip:, 0])
    Yv = np.fft.rfft(y_v[skip:, 0])
    f = np.arange(dY.size) * model.fs_high / (n - skip)
    edges = np.geomspace(f[1], f[-1] * (1 + 1e-9), 5)
    levels = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        b = (f >= lo) & (f < hi)
        if b.any():
            ratio = np.mean(np.abs(dY[b]) ** 2) / max(np.mean(np.abs(Yv[b]) ** 2), 1e-300)
            levels.append(10 * math.log10(1.0 + ratio))
    return max(levels)


def draw_beyond(
    effect: str,
    rng: np.random.Generator,
    *,
    level: float = 0.3,
    kind: str = "odd",
    duration: float = 20.0,
    realizations: int = 4,
    max_loops: int = 50,
) -> Beyond:
    """A random loop with ``effect``, its two records and the truth (module docstring).

    ``level`` and ``kind`` (a multisine of :data:`DESIGNS`) for nonlinear effects;
    ``duration`` (s) of each white-noise record for the others; ``realizations`` of the
    noise-free truth of the distortion level.
    """
    for _ in range(max_loops):
        loop = draw_loop(rng, duration=duration)
        m = loop.nominal
        if effect == "pole_zero_pair":
            drawn = _pole_zero(loop, rng)
            if drawn is None:
                continue
            true, p = drawn
            recs = [
                simulate(replace(true, noise_std=m.noise_std), duration=duration, rng=rng)
                for _ in range(2)
            ]
            r = recs[1].r
            clean = simulate(true, reference=r, noise=np.zeros_like(recs[1].y)).y
            return Beyond(loop, effect, p, recs[0], recs[1], true, math.nan, "white",
                          effect_db(m, clean, r), clean)  # fmt: skip
        p = draw_effect(effect, loop, rng, level, duration)
        make = _actuator(effect, p, m.fs_high)
        if effect in NONLINEAR:
            if m.n_u != 1 or m.plant_discrete().D.any():
                continue
            r, N = _multisine(loop, kind, int(rng.integers(2**31)), realizations + 2)
            recs = []
            for j in (0, 1):
                v = m.noise_std * rng.standard_normal((r.shape[1], 1))
                rec = simulate_actuated(m, r[j], v, make())
                recs.append(replace(rec, period=N))
            db = distortion_db(m, make, r[2:], N, m.noise_std)
            return Beyond(loop, effect, p, recs[0], recs[1], None, db, kind)
        recs = []
        for _ in range(2):
            n = loop.reference.shape[0]
            r = rng.standard_normal((n, 1))
            recs.append(simulate_actuated(m, r, m.noise_std * rng.standard_normal((n, 1)), make()))
        r = recs[1].r
        clean = simulate_actuated(m, r, np.zeros_like(r), make()).y
        return Beyond(loop, effect, p, recs[0], recs[1], None, math.nan, "white",
                      effect_db(m, clean, r), clean)  # fmt: skip
    raise ConfigError(f"no loop in {max_loops} draws takes {effect!r}")


#: Nonlinear effects under white r (no periodic excitation): the actuator's and a sensor's.
RANDOM_NONLINEAR: tuple[str, ...] = ("saturation", "dead_zone", "clipping_sensor")
#: Share of the samples a clipping sensor clips.
CLIPPED = 0.05


def draw_random_nonlinear(
    effect: str, rng: np.random.Generator, *, level: float = 1.0, duration: float = 20.0
) -> Beyond:
    """A random SISO loop with a nonlinear ``effect`` of :data:`RANDOM_NONLINEAR`, white r.

    The actuator's (``level`` as :func:`draw_effect`'s) or a sensor that clips y at the
    level |y| exceeds in :data:`CLIPPED` of the linear loop's samples. Two records of white
    r (std 1) with the loop's output noise; ``distortion_db`` nan (no periodic truth).
    """
    for _ in range(50):
        loop = draw_loop(rng, duration=duration)
        m = loop.nominal
        if m.n_u != 1 or m.plant_discrete().D.any():
            continue
        sensor: Callable[[float], float] | None = None
        if effect == "clipping_sensor":
            lin = simulate(m, reference=loop.reference, noise=np.zeros_like(loop.y_clean))
            c = float(np.quantile(np.abs(lin.y - lin.y.mean()), 1.0 - CLIPPED))
            mid = float(lin.y.mean())
            p = {"clip": c, "share": CLIPPED}

            def clip(y: float, c: float = c, mid: float = mid) -> float:
                return min(max(y, mid - c), mid + c)

            def make() -> Actuator:
                return lambda u, dy: u

            sensor = clip
        else:
            p = draw_effect(effect, loop, rng, level, duration)
            make = _actuator(effect, p, m.fs_high)
        recs = []
        for _ in range(2):
            n = loop.reference.shape[0]
            r = rng.standard_normal((n, 1))
            v = m.noise_std * rng.standard_normal((n, 1))
            recs.append(simulate_actuated(m, r, v, make(), sensor))
        return Beyond(loop, effect, p, recs[0], recs[1], None, math.nan, "white")
    raise ConfigError(f"no loop in 50 draws takes {effect!r}")
