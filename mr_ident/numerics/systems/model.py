# SPDX-License-Identifier: Apache-2.0
"""The nominal description of a multirate loop: :class:`Model`.

Read and written as YAML by :mod:`mr_ident.io.modelfile`; its form (keys marked * are
required)::

    fs_high: 240.0            # * high sample rate, Hz
    ratio: 3                  # * F = h_l / h_h, integer >= 1
    plant:                    # * continuous time, discretised with ZOH at fs_high
      num: [...]              #   descending powers of s (or z with domain: discrete)
      den: [...]
      domain: continuous      #   or "discrete" (sample time 1/fs_high)
    controller:               #   discrete time at the low rate, descending powers of z
      num: [0.1, 0.0]         #   omit the whole key for an open-loop experiment
      den: [1.0, -0.9]
    noise_std: 0.0            #   output noise std (simulation)
    reference_std: 1.0        #   white-noise excitation std (simulation)
    sample_phase: 0           #   high-rate sample (0..F-1) at which the controller samples y
    control_delay: 0          #   high-rate samples before the held output is applied
    injection: plant_input    #   where r enters: plant_input (u = r - H K S y, the seed
                              #   paper's loop) or setpoint (u = H K S (r - y): r is the
                              #   controller's reference, sampled with y); omitted: not
                              #   stated (simulated at the plant input)

Optional extensions (written by ``mr-ident diagnose --out-model``; all default to none;
their physical meaning is in the README's cause table)::

    plant_gain: 1.0           #   multiplies the plant
    input_delay_s: 0.0        #   delay between u_h and the plant, s (fractional samples exact)
    additive_modes:           #   each adds gain w^2/(s^2 + 2 damping w s + w^2) to one entry
      - {frequency_hz: 97.0, damping: 0.02, gain: 0.01, output: 0, input: 0}
    mode_changes:             #   the plant's mode nearest from_hz moves; its modal numerator
      - {from_hz: 80.0, frequency_hz: 88.0, damping: 0.03, residue_scale: 1.0}  # x residue_scale
    series_dynamics:          #   a low-pass in series: w/(s+w) (damping 0) or w^2/(s^2+2ζws+w^2)
      - {frequency_hz: 30.0, damping: 0.0, side: output, channel: 0}
    controller_notches:       #   (s^2+2 depth ζ w s+w^2)/(s^2+2 ζ w s+w^2) after the controller
      - {frequency_hz: 20.0, damping: 0.3, depth: 0.1}  # (Tustin at fs_low, prewarped)
    disturbances:             #   sinusoids added to output y (seen by the controller)
      - {frequency_hz: 13.0, amplitude: 0.01, phase_rad: 0.0, output: 0}
    plant_corrections:        #   fitted where no listed cause explains the data: each a
      - kind: additive        #   discrete modal system at 1/fs_high (the modal form below),
        domain: discrete      #   added to P_h (additive: n_y x n_u) or multiplying it at
        direct: 0.0           #   its input (multiplicative: P_h (I + C), C n_u x n_u)
        modes: [{frequency_hz: 83.0, damping: 0.04, c1: 0.01, c0: -0.0099}]

``additive_modes``, ``mode_changes``, ``series_dynamics`` and a fractional
``input_delay_s`` need a continuous-time plant. ``plant_corrections`` act on P_h, after the
hold and the delay, whatever the plant's domain. Every model is simulated and evaluated in
state space (:mod:`~mr_ident.numerics.systems.realize`): the polynomials of the file are turned
into sections once, and nothing past second order goes back to polynomial form.

The plant may instead be in modal form (``direct``, ``modes``, ``real_poles``: written by
``mr-ident fit``; :class:`~mr_ident.numerics.systems.modal.ModalPlant`, read by
:mod:`mr_ident.io.modal_yaml`).

MIMO: ``num`` is a nested list ``[n_out][n_in][coefficients]``; ``den`` is either
one coefficient list shared by all entries or nested the same way.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import ModelError
from ..arrays import ComplexArray, FloatArray
from ..results import FRF
from ..structure import INJECTIONS
from .lti import StateSpace, TransferMatrix
from .modal import ModalPlant
from .realize import (
    balanced,
    block_diag,
    diagonal,
    lowpass,
    mode_block,
    notch,
    parallel,
    realize,
    sections,
    series,
    shift,
    split_mode,
    zoh,
)


@dataclass(frozen=True)
class Model:
    """A validated multirate loop model.

    Attributes
    ----------
    fs_high : float
        High sample rate (Hz).
    ratio : int
        F.
    plant : TransferMatrix or ModalPlant
        Continuous (``dt`` None) or discrete at ``1/fs_high``; n_y x n_u. A
        :class:`~mr_ident.numerics.systems.modal.ModalPlant` (written by ``mr-ident fit``)
        is realised mode by mode.
    controller : TransferMatrix or None
        Discrete at ``ratio/fs_high``; n_u x n_y. None: open loop.
    noise_std, reference_std : float
    sample_phase, control_delay : int
    injection : {"plant_input", "setpoint"} or None
        Where the excitation r enters: added to the plant input at the high rate
        (``u_h = r_h - H_u K_l S_d y_h``; r has n_u channels) or as the controller's
        setpoint, sampled with y (``u_h = H_u K_l S_d (r_h - y_h)``; r has n_y channels).
        None: not stated (simulated at the plant input; the data tell it to identify). In
        open loop (no controller) r is the plant's input whatever it says.
    plant_gain : float
        Multiplies the plant.
    input_delay : float
        Seconds between u_h and the plant input.
    additive_modes : tuple of (frequency_hz, damping, gain, output, input)
        Each adds ``gain w^2 / (s^2 + 2 damping w s + w^2)`` to plant entry [output][input].
    mode_changes : tuple of (from_hz, frequency_hz, damping, residue_scale)
        Each moves the plant's lightly damped mode nearest ``from_hz`` (its pole pair, in
        every entry that has it) to ``frequency_hz`` and ``damping``, and multiplies its
        modal numerator ``c1 s + c0`` by ``residue_scale`` (1: the stiffness changed;
        ``(f / f0)^2``: the mass changed).
    series_dynamics : tuple of (frequency_hz, damping, side, channel)
        A low-pass in series with the plant on input (``side`` "input") or output
        ("output") ``channel``: first order ``w / (s + w)`` when ``damping`` is 0, else
        ``w^2 / (s^2 + 2 damping w s + w^2)``.
    controller_notches : tuple of (frequency_hz, damping, depth)
        Each a notch ``(s^2 + 2 depth damping w s + w^2) / (s^2 + 2 damping w s + w^2)``
        after the controller on every channel, Tustin-discretised at fs_low, prewarped at
        its frequency.
    disturbances : tuple of (frequency_hz, amplitude, phase_rad, output)
        Sinusoids added to output ``output`` of y (also seen by the controller).
    plant_corrections : tuple of (kind, ModalPlant)
        Low-order corrections of P_h, each discrete at ``1/fs_high``: ``"additive"``
        (``P_h + C``, C n_y x n_u) or ``"multiplicative"`` (``P_h (I + C)``, C n_u x n_u),
        applied in turn after the hold and the input delay (written by ``mr-ident
        diagnose`` where no listed cause explains the data).

    Raises
    ------
    ModelError
        If ``injection`` is not None, "plant_input" or "setpoint". (A model file is
        checked whole by :func:`~mr_ident.io.modelfile.model_from_dict`.)

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022 (the
       loop and its example).

    Examples
    --------
    >>> from mr_ident import Model, TransferMatrix
    >>> plant = TransferMatrix.siso([1.0], [1.0, 1.0])  # 1 / (s + 1), continuous
    >>> m = Model(fs_high=100.0, ratio=4, plant=plant)
    >>> m.n_y, m.n_u, m.controller is None  # no controller: open loop
    (1, 1, True)
    """

    fs_high: float
    ratio: int
    plant: TransferMatrix | ModalPlant
    controller: TransferMatrix | None = None
    noise_std: float = 0.0
    reference_std: float = 1.0
    sample_phase: int = 0
    control_delay: int = 0
    plant_gain: float = 1.0
    input_delay: float = 0.0
    additive_modes: tuple[tuple[float, float, float, int, int], ...] = ()
    mode_changes: tuple[tuple[float, float, float, float], ...] = ()
    series_dynamics: tuple[tuple[float, float, str, int], ...] = ()
    controller_notches: tuple[tuple[float, float, float], ...] = ()
    disturbances: tuple[tuple[float, float, float, int], ...] = ()
    plant_corrections: tuple[tuple[str, ModalPlant], ...] = ()
    injection: str | None = None

    def __post_init__(self) -> None:
        if self.injection is not None and self.injection not in INJECTIONS:
            raise ModelError(
                f"injection must be one of {', '.join(INJECTIONS)}, got {self.injection!r}"
            )

    @property
    def n_y(self) -> int:
        """Plant outputs."""
        return self.plant.shape[0]

    @property
    def n_u(self) -> int:
        """Plant inputs."""
        return self.plant.shape[1]

    @property
    def n_r(self) -> int:
        """Channels of the excitation r: n_u at the plant input, n_y at the setpoint."""
        return self.n_y if self.setpoint else self.n_u

    @property
    def setpoint(self) -> bool:
        """Whether r enters as the controller's setpoint (in open loop r is the plant's input)."""
        return self.injection == "setpoint" and self.controller is not None

    @property
    def fs_low(self) -> float:
        """Controller rate fs_high / F in Hz."""
        return self.fs_high / self.ratio

    def plant_ss(self) -> StateSpace:
        """The plant with every extension but the delay, in state space (its own domain).

        The file's polynomials as sections (mode changes applied entry by entry), the gain,
        the additive modes in parallel, the series dynamics on inputs and outputs.
        """
        return plant_ss(self)

    def plant_discrete(self) -> StateSpace:
        """P_h: the plant at the high rate, extensions and input delay included.

        ZOH in state space (exact for held inputs) when the plant is continuous.
        """
        P = self.plant_ss()
        h = 1.0 / self.fs_high
        if P.dt is None:
            P = zoh(P, h, delay=self.input_delay)
        elif d := int(round(self.input_delay * self.fs_high)):
            P = series(shift(self.n_u, d, h), P)
        return corrected(P, self.plant_corrections)

    def controller_ss(self) -> StateSpace:
        """K_l in state space at the low rate, with any controller notches after it.

        Raises
        ------
        ModelError
            The model has no controller.
        """
        if self.controller is None:
            raise ModelError("the model has no controller (open loop)")
        K = realize(self.controller)
        for f, zeta, depth in self.controller_notches:
            K = series(K, diagonal(notch(f, zeta, depth, self.ratio / self.fs_high), self.n_u))
        return K

    def disturbance(self, start: int, n_samples: int) -> FloatArray:
        """The output disturbance on samples start..start+N-1, shape (N, n_y)."""
        out = np.zeros((n_samples, self.n_y))
        if self.disturbances:
            t = (start + np.arange(n_samples)) / self.fs_high
            for f, a, ph, o in self.disturbances:
                out[:, o] += a * np.sin(2.0 * np.pi * f * t + ph)
        return out

    def plant_frf(self, n_samples: int) -> ComplexArray:
        """Exact P_h on DFT bins 0..N//2 of an N-sample record, shape (N//2+1, n_y, n_u)."""
        f = np.arange(n_samples // 2 + 1) * self.fs_high / n_samples
        return self.plant_discrete().freqresp(f)

    def plant_result(self, n_samples: int) -> FRF:
        """Exact P_h on the bins (0, fs_high/2] of an N-sample record, as an FRF (std 0)."""
        P = self.plant_frf(n_samples)[1:]
        f = np.arange(1, n_samples // 2 + 1) * self.fs_high / n_samples
        return FRF(f, P, np.zeros(P.shape), "model")

    def controller_frf(self, n_low: int) -> ComplexArray:
        """K_l on all low-rate bins 0..M-1, shape (M, n_u, n_y)."""
        if self.controller is None:
            raise ModelError("the model has no controller (open loop); the PFG needs one")
        K = self.controller.dft_response(n_low)
        if self.controller_notches:
            f_low = np.arange(n_low) * (self.fs_low / n_low)
            for f, zeta, depth in self.controller_notches:
                K = notch(f, zeta, depth, self.ratio / self.fs_high).freqresp(f_low)[:, :1, :1] * K
        return K

    def identify_arguments(self, n_samples: int) -> dict[str, Any]:
        """The loop arguments of :func:`~mr_ident.numerics.identify.identify` for N samples.

        ``controller_low`` (None in open loop, or when N is not a multiple of F, which
        identify then reports), ``phase`` and ``delay``.
        """
        K = (
            self.controller_frf(n_samples // self.ratio)
            if self.controller is not None and n_samples % self.ratio == 0
            else None
        )
        return {"controller_low": K, "phase": self.sample_phase, "delay": self.control_delay}


#: The kinds of a plant correction (:attr:`Model.plant_corrections`).
CORRECTION_KINDS = ("additive", "multiplicative")


def corrected(P: StateSpace, corrections: tuple[tuple[str, ModalPlant], ...]) -> StateSpace:
    """P_h (discrete) with each correction applied in turn (:attr:`Model.plant_corrections`).

    Raises
    ------
    ModelError
        An unknown kind, a correction that is not discrete at P_h's sample time, or one of
        the wrong shape.
    """
    for kind, C in corrections:
        if C.dt is None or P.dt is None or not np.isclose(C.dt, P.dt, rtol=1e-9):
            raise ModelError(
                f"a plant correction must be discrete at 1/fs_high = {P.dt!r} s, got dt={C.dt!r}"
            )
        no, ni = P.shape
        if kind == "additive" and C.shape == (no, ni):
            P = parallel(P, C.state_space())
        elif kind == "multiplicative" and C.shape == (ni, ni):
            S = C.state_space()
            P = series(StateSpace(S.A, S.B, S.C, S.D + np.eye(ni), S.dt), P)
        else:
            raise ModelError(
                f"a plant correction must be additive ({no}x{ni}) or multiplicative "
                f"({ni}x{ni}); got {kind!r} of shape {C.shape}"
            )
    return P


def _mode_pole(frequency_hz: float, damping: float) -> complex:
    w = 2.0 * np.pi * frequency_hz
    return complex(-damping * w, w * np.sqrt(max(1.0 - damping * damping, 0.0)))


@functools.lru_cache(maxsize=256)
def _entry(
    P: TransferMatrix, o: int, i: int, mode_changes: tuple[tuple[float, float, float, float], ...]
) -> StateSpace:
    """Plant entry [o][i] as sections, with mode changes applied.

    Cached: the diagnosis builds the same plant many times over.
    """
    S = sections(P.num[o][i], P.den[o][i], P.dt)
    for f0, f, zeta, scale in mode_changes:
        poles = S.poles()
        upper = poles[poles.imag > 0]
        if not upper.size:
            continue
        j = int(np.argmin(np.abs(np.abs(upper) - 2.0 * np.pi * f0)))
        if abs(abs(upper[j]) / (2.0 * np.pi * f0) - 1.0) > 0.05:
            continue  # this entry does not have the mode
        c1, c0, rest = split_mode(S, complex(upper[j]))
        S = parallel(rest, mode_block(f, zeta, scale * c1, scale * c0))
    return S


def _modal_changed(
    P: ModalPlant, mode_changes: tuple[tuple[float, float, float, float], ...]
) -> ModalPlant:
    """A modal plant with its mode nearest each ``from_hz`` moved (as :func:`_entry`)."""
    for f0, f, zeta, scale in mode_changes:
        x = P.poles if P.dt is None else np.log(P.poles.astype(complex)) / P.dt
        hz = np.where(P.poles.imag > 0, np.abs(x) / (2.0 * np.pi), np.inf)
        if not np.isfinite(hz).any():
            continue
        j = int(np.argmin(np.abs(hz - f0)))
        if abs(hz[j] / f0 - 1.0) > 0.05:
            continue
        p = _mode_pole(f, zeta)
        P = P.with_mode(j, p if P.dt is None else complex(np.exp(p * P.dt)), scale)
    return P


def plant_poles(model: Model) -> ComplexArray:
    """The poles of the file's plant (no extension), every conjugate included."""
    if isinstance(model.plant, ModalPlant):
        return model.plant.all_poles()
    return realize(model.plant).poles()


def plant_ss(model: Model) -> StateSpace:
    """:meth:`Model.plant_ss` (see there)."""
    P = model.plant
    no, ni = P.shape
    if isinstance(P, ModalPlant):
        S = _modal_changed(P, model.mode_changes).state_space()
        return _extended(model, S)
    parts, where = [], []
    for o in range(no):
        for i in range(ni):
            if np.any(P.num[o][i]):
                parts.append(_entry(P, o, i, model.mode_changes))
                where.append((o, i))
    return _extended(model, block_diag(parts, no, ni, where))


def _extended(model: Model, S: StateSpace) -> StateSpace:
    """The file's plant ``S`` with gain, additive modes and series dynamics."""
    dt = model.plant.dt
    no, ni = model.plant.shape
    S = StateSpace(S.A, S.B, model.plant_gain * S.C, model.plant_gain * S.D, dt)
    for f, zeta, gain, o, i in model.additive_modes:
        w = 2.0 * np.pi * f
        c0 = np.zeros((no, ni))
        c0[o, i] = gain * w * w
        S = parallel(S, mode_block(f, zeta, np.zeros((no, ni)), c0))
    for f, zeta, side, channel in model.series_dynamics:
        if side == "input":
            S = series(diagonal(lowpass(f, zeta), ni, channel=channel), S)
        else:
            S = series(S, diagonal(lowpass(f, zeta), no, channel=channel))
    return balanced(StateSpace(S.A, S.B, S.C, S.D, dt))
