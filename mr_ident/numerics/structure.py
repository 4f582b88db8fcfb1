# SPDX-License-Identifier: Apache-2.0
"""The loop's structure read from its data: F, where r enters, the controller's phase.

The controller's output is held over F high-rate samples, and that hold is in the data:

* ``u_h - r_h`` held over blocks of F samples (and u itself not): r was added to the plant
  input, ``u_h = r_h - H_u K_l S_d y_h`` (the seed paper's loop);
* ``u_h`` held (and ``u_h - r_h`` not): r is the controller's setpoint,
  ``u_h = H_u K_l S_d (r_h - y_h)`` (what a ros2_control PID offers); a setpoint given at
  the controller's rate (N/F samples) says so by its length;
* both held on the same blocks (r itself held there): the hold cannot tell where r enters;
* neither: u was measured after the actuator (noise, its dynamics) and shows no hold: F
  and the injection point come from the user.

A signal is held when its sample-to-sample changes, beyond round-off of its own scale
(:data:`HELD_RTOL`), fall on one residue s of the sample index modulo F for the largest
such F (:data:`HELD_SHARE` of them, so that a few glitches do not hide it). s, the sample
of each block at which the held value changes, is ``(phase + delay) mod F`` of the model's
controller, counted from the record's first sample.

With r at the setpoint, the controller takes one sample of r per block, at its sampling
phase q. For a white (or wide-band) r the held u is coherent with ``r[m F + q]`` and not
with the other samples of the block: :func:`read_structure` takes the q of the largest mean
coherence when it stands out (:data:`PHASE_MARGIN`), else says that r does not tell it
(a setpoint held or smooth over a block: then the phase does not matter much either).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError, FieldError
from .arrays import FloatArray

#: Changes of a held signal are below this share of its largest magnitude: round-off of
#: ``u - r`` from a held controller output and r (about 1e-16 of it in float64, 1e-7 when
#: logged as float32 or as text of 7 digits).
HELD_RTOL = 1e-6
#: A hold of F is seen when at least this share of the changes fall on one residue mod F.
HELD_SHARE = 0.99
#: Blocks at least, with a change, before a hold is believed (fewer: not enough data).
MIN_CHANGES = 16
#: The largest F looked for.
MAX_RATIO = 64
#: The phase's mean coherence must exceed the next best by this much to be read.
PHASE_MARGIN = 0.2
#: The controller's equation holds when its least-squares residual is below this share of
#: the target's spread (round-off: 1e-13 to 1e-16 on simulated loops; a u logged as float32,
#: 1e-7; r entering elsewhere: 7e-4 to 9e-2 on the paper's loop).
EQUATION_RTOL = 1e-6
#: The controller orders tried (a PID with a filtered derivative: 2).
EQUATION_ORDERS = (1, 2, 3, 4)
#: The inputs' lags of an equation of order k: 0 .. k + EQUATION_LAG - 1.
EQUATION_LAG = 2

T = TypeVar("T")

#: Where r enters the loop: added to the plant input, or as the controller's setpoint
#: (:attr:`LoopStructure.injection`, the models' ``injection``, identify's ``injection``).
PLANT_INPUT, SETPOINT = "plant_input", "setpoint"
INJECTIONS = (PLANT_INPUT, SETPOINT)


@dataclass(frozen=True)
class LoopStructure:
    """What the data show of the loop's structure.

    Attributes
    ----------
    held : {"u - r", "u", "u and u - r", "u = r", "none"}
        Which signal is held over blocks of F samples ("u = r": none, an open loop).
    ratio : int or None
        F read from the hold (None: no hold seen).
    hold_start : int or None
        s in 0..F-1: the sample of each block (counted from the record's first sample) at
        which the held value changes; the controller's ``(phase + delay) mod F``.
    injection : {"plant_input", "setpoint"} or None
        Where r enters, where the data tell it.
    phase : int or None
        With r at the setpoint: the sample of each block the controller takes r at, where
        r tells it.
    r_low : bool
        r has N/F samples: a setpoint given at the controller's rate.
    """

    held: str
    ratio: int | None
    hold_start: int | None
    injection: str | None
    phase: int | None = None
    r_low: bool = False

    def describe(self) -> str:
        """One sentence of what the data show."""
        if self.held == "u = r":
            return "u equals r: an open-loop experiment (r at the plant input), F not shown"
        if self.ratio is None:
            return "u shows no hold (measured after the actuator?): F and where r enters unknown"
        where = {
            PLANT_INPUT: "r enters at the plant input",
            SETPOINT: "r is the controller's setpoint",
            None: "where r enters is not told by the data",
        }[self.injection]
        phase = "" if self.phase is None else f", the controller samples r at sample {self.phase}"
        return (
            f"{self.held} changes every {self.ratio} samples (at sample {self.hold_start} of "
            f"each block): F = {self.ratio}, {where}{phase}"
        )


def hold_of(x: FloatArray, max_ratio: int = MAX_RATIO) -> tuple[int, int] | None:
    """``(F, s)`` of a signal held over blocks of F samples changing at residue s; else None.

    ``x`` (N, channels); NaN samples are skipped. None also when fewer than
    :data:`MIN_CHANGES` changes are seen (a constant signal tells nothing). F = 1 (no hold)
    is returned as None.
    """
    scale = float(np.nanmax(np.abs(x), initial=0.0)) if x.size else 0.0
    if not scale > 0:
        return None
    d = np.abs(np.diff(x, axis=0))
    changed = np.flatnonzero(np.any(d > HELD_RTOL * scale, axis=1)) + 1  # the new value's index
    if changed.size < MIN_CHANGES:
        return None
    best: tuple[int, int] | None = None
    for F in range(2, min(max_ratio, x.shape[0] // MIN_CHANGES) + 1):
        if (x.shape[0] - 2) // F + 1 < HELD_SHARE * changed.size:
            break  # one residue of 1..N-1 holds too few indices, for this F and every larger
        counts = np.bincount(changed % F, minlength=F)
        s = int(np.argmax(counts))
        if counts[s] >= HELD_SHARE * changed.size:
            best = (F, s)  # the largest such F: a hold of 6 also falls on one residue mod 3
    return best


def held_phase(first: int, x: FloatArray, ratio: int) -> tuple[int, float]:
    """The index (mod F) at which a signal held over F samples changes, and the contrast.

    The rule for a hold that :func:`hold_of` cannot see exactly (a u - r logged with noise),
    F given. ``x`` (N,) or (N, c), its first sample at absolute index ``first``. For each
    candidate h the variation between consecutive samples *inside* the hold intervals starting at
    indices = h (mod F) is summed; the true h gives (nearly) 0. The contrast is that sum
    relative to the next best candidate's (below 0.1: clear; near 1: not held, or F = 1).
    Missing samples (NaN) are left out.
    """
    F = int(ratio)
    if F == 1:
        return 0, 1.0
    # a missing sample (NaN) leaves out the two steps it is in
    step = np.abs(np.diff(x, axis=0))
    step = np.nansum(step, axis=1) if x.ndim == 2 else np.nan_to_num(step, nan=0.0)
    idx = (first + 1 + np.arange(step.shape[0])) % F  # index of the later sample
    per_class = np.bincount(idx, weights=step, minlength=F)  # variation entering index = c (mod F)
    inside = per_class.sum() - per_class  # hold at h: changes only allowed at h
    order = np.argsort(inside)
    best, second = float(inside[order[0]]), float(inside[order[1]])
    return int(order[0]), (best / second if second > 0 else 1.0)


def u_equals_r(r: FloatArray, u: FloatArray) -> bool:
    """Whether u equals r to round-off of its scale (NaN samples skipped): an open loop."""
    d = np.abs(u - r)
    scale = float(np.nanmax(np.abs(u), initial=0.0))
    return bool(scale > 0 and float(np.nanmax(d, initial=0.0)) <= HELD_RTOL * scale)


def _phase(r: FloatArray, u: FloatArray, F: int, s: int) -> int | None:
    """The sample q of each block whose r the held u follows, where it stands out."""
    from scipy.signal import coherence

    M = u.shape[0] // F
    if M < 64:
        return None
    r, u = (np.where(np.isnan(x), np.nanmean(x, axis=0), x) for x in (r, u))  # lost: the mean
    v = u[s : s + (M - 1) * F : F]  # the held value of each block
    scores = []
    for q in range(F):
        rq = r[q : q + (M - 1) * F : F]
        c = [
            np.nanmean(coherence(rq[:, i], v[:, j], nperseg=min(256, M // 4))[1])
            for i in range(r.shape[1])
            for j in range(v.shape[1])
        ]
        scores.append(float(np.nanmax(c)))
    order = np.argsort(scores)[::-1]
    if scores[order[0]] - scores[order[1]] < PHASE_MARGIN:
        return None
    return int(order[0])


def equation_fit(target: FloatArray, inputs: list[FloatArray], order: int) -> FloatArray | None:
    """The coefficients of ``target``'s exact low-order LTI equation in its past and ``inputs``.

    ``target[b] = sum_i a_i target[b-i] + sum_j sum_l g_jl inputs_j[b-l] + c`` (i = 1..order,
    l = 0..order+1 = :data:`EQUATION_LAG` + order - 1), by least squares over the blocks
    without NaN: ``[a_1.., g_j0.., .., c]``, or None where it is not exact (the residual
    above :data:`EQUATION_RTOL` of the target's spread) or the data are too few.
    """
    M, L = target.shape[0], order + EQUATION_LAG
    if M < 8 * L * (len(inputs) + 1):
        return None
    cols = [target[L - i : M - i] for i in range(1, order + 1)]
    for x in inputs:
        cols += [x[L - i : M - i] for i in range(L)]
    A = np.column_stack([*cols, np.ones(M - L)])
    t = target[L:]
    ok = np.isfinite(A).all(axis=1) & np.isfinite(t)
    if ok.sum() < 4 * A.shape[1]:
        return None
    A, t = A[ok], t[ok]
    spread = float(np.linalg.norm(t - t.mean()))
    if not spread > 0:
        return None
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    sol = np.linalg.lstsq(A / scale, t, rcond=None)[0]
    if np.linalg.norm(t - (A / scale) @ sol) > EQUATION_RTOL * spread:
        return None
    coef: FloatArray = sol / scale
    return coef


def _injection_by_equation(
    r: FloatArray, u: FloatArray, y: FloatArray, F: int, s: int
) -> str | None:
    """Where r enters when r and u are held alike: the controller's equation tells it.

    With r at the plant input, the controller's output ``r - u`` is a function of the
    sampled y alone (``-K_l S_d y``); with r at the setpoint, u is one of ``r - y`` and not
    ``r - u`` of y alone. Each is an exact low-order LTI relation between the block values
    (u as held from sample s of each block; y at the controller's sampling phase, every
    phase tried) where the logged y is what the controller sampled. None where neither
    holds exactly (a y other than the controller's, a nonlinear controller).
    """
    M = min(u.shape[0] // F, r.shape[0] // F) - 1
    ub, rb = u[s::F][:M, 0], r[s::F][:M, 0]
    sampled = [y[q::F][:M, 0] for q in range(F)]
    # the plant input's equation first: it is the setpoint's with u - r for u, which also
    # holds where r enters at the plant input
    for target, with_r, where in ((rb - ub, False, PLANT_INPUT), (ub, True, SETPOINT)):
        for ys in sampled:
            inputs = [ys, rb] if with_r else [ys]
            if any(equation_fit(target, inputs, order) is not None for order in EQUATION_ORDERS):
                return where
    return None


def read_structure(r: ArrayLike, u: ArrayLike, y: ArrayLike | None = None) -> LoopStructure:
    """The loop's structure as r and u show it (:class:`LoopStructure`).

    Parameters
    ----------
    r : array_like, shape (N, n_r) or (N/F, n_r)
        The excitation as logged; N/F samples: a setpoint at the controller's rate.
    u : array_like, shape (N, n_u)
        The plant input as logged (NaN: missing samples, skipped).
    y : array_like, shape (N, n_y), optional
        The plant output as logged: where r and u are held alike (r given at the
        controller's rate, held), the controller's equation tells where r enters
        (:func:`_injection_by_equation`).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> r = rng.standard_normal((3000, 1))
    >>> held = np.repeat(rng.standard_normal((1000, 1)), 3, axis=0)
    >>> read_structure(r, r - held).describe()
    'u - r changes every 3 samples (at sample 0 of each block): F = 3, r enters at the plant input'
    """
    ra = np.asarray(r, dtype=float)
    ua = np.asarray(u, dtype=float)
    ra = ra[:, None] if ra.ndim == 1 else ra
    ua = ua[:, None] if ua.ndim == 1 else ua
    N = ua.shape[0]
    hu = hold_of(ua)
    if ra.shape[0] != N:  # a setpoint at the controller's rate
        F_len = N // ra.shape[0] if ra.shape[0] and N % ra.shape[0] == 0 else None
        if hu is None:
            return LoopStructure("none", F_len, None, SETPOINT if F_len else None, r_low=True)
        return LoopStructure("u", hu[0], hu[1], SETPOINT, r_low=True)
    same = ra.shape[1] == ua.shape[1]
    if same and u_equals_r(ra, ua):  # nothing between r and u: no controller acts
        return LoopStructure("u = r", None, None, PLANT_INPUT)
    hd = hold_of(ua - ra) if same else None
    if hu is None and hd is None:
        return LoopStructure("none", None, None, None)
    if hd is not None and hu is None:
        return LoopStructure("u - r", hd[0], hd[1], PLANT_INPUT)
    assert hu is not None
    if hd is not None and hd == hu:
        ya = None if y is None else np.asarray(y, dtype=float).reshape(N, -1)
        told = None
        if ya is not None and ya.shape[0] == N and ra.shape[1] == ua.shape[1] == 1:
            told = _injection_by_equation(ra, ua, ya, hu[0], hu[1])
        return LoopStructure("u and u - r", hu[0], hu[1], told)
    F, s = hu
    return LoopStructure("u", F, s, SETPOINT, _phase(ra, ua, F, s))


def _agreed(
    name: str, shown: T | None, given: list[tuple[str, T]], refusal: Callable[[str, T], str]
) -> T | None:
    """The data's value where they show one, else the first given; None without either.

    A given that differs from the data's value: ConfigError ``refusal(who, value)``; givens
    that differ from each other (the data showing none): ConfigError naming ``name``.
    """
    if shown is not None:
        for who, v in given:
            if v != shown:
                raise ConfigError(refusal(who, v))
        return shown
    if not given:
        return None
    first, value = given[0]
    for who, v in given[1:]:
        if v != value:
            raise ConfigError(f"{name} disagrees: {first} says {value}, {who} says {v}")
    return value


#: The request's fields :attr:`Settled.notes` name as ``{field}``
#: (:class:`~mr_ident.errors.FieldError`'s convention).
NOTE_FIELDS = ("injection",)


@dataclass(frozen=True)
class Settled:
    """The loop's structure the data and the user agree on.

    ``ratio``: F; ``injection``: where r enters; ``phase``: the controller's sampling phase
    for a setpoint (None: the caller's, e.g. the model's); ``found``: what the data show;
    ``notes``: what the user should know (a value taken because the data do not tell it),
    naming the request's fields as ``{field}`` (:data:`NOTE_FIELDS`) for the caller to say.
    """

    ratio: int
    injection: str
    phase: int | None
    found: LoopStructure
    notes: tuple[str, ...] = ()


def settle_structure(
    found: LoopStructure,
    *,
    ratios: list[tuple[str, int]],
    injections: list[tuple[str, str]],
    phases: list[tuple[str, int]],
) -> Settled:
    """F, the injection point and a setpoint's phase: the data's, and the given must agree.

    Each list holds ``(who says it, value)`` as the user gave it (a request's field, the
    data file, the model), first the one that counts. Where the data show a value, a given
    one that differs is refused (ConfigError naming both); where they do not, the first
    given is taken (F: FieldError naming ``{ratio}`` and ``{model}`` when none is; the
    injection point: the plant input, with a note).
    """
    notes: list[str] = []
    ratio = _agreed(
        "ratio",
        found.ratio,
        ratios,
        lambda who, F: (
            f"{found.held} changes every {found.ratio} samples: F = {found.ratio}, not {F} ({who})"
        ),
    )
    if ratio is None:
        raise FieldError(
            "ratio F unknown: u shows no hold to read it from; pass {ratio} or {model}",
            "ratio",
            "model",
        )
    injection = _agreed(
        "injection",
        found.injection,
        injections,
        lambda who, v: (  # "the model says injection ...", "{injection} says ..."
            f"{found.describe()}; {who} says {'' if 'injection' in who else 'injection '}{v}"
        ),
    )
    if injection is None:
        injection = PLANT_INPUT
        if found.ratio is not None or found.held == "none":
            notes.append(
                f"{found.describe()}; r taken as added at the plant input (state the "
                "injection point, e.g. {injection} setpoint, where it is the setpoint)"
            )
    phase = None
    if injection == SETPOINT:
        phase = _agreed(
            "phase",
            found.phase,
            phases,
            lambda who, q: (
                f"the held u follows r sampled at sample {found.phase} of each "
                f"block, not at {q} ({who})"
            ),
        )
        if found.phase is None and phase is not None:
            notes.append(f"r does not tell the controller's phase: {phase} taken ({phases[0][0]})")
    return Settled(ratio, injection, phase, found, tuple(notes))
