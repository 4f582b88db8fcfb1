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

Optional extensions (written by ``mr-ident diagnose --out-model``; all default to none)::

    plant_gain: 1.0           #   multiplies the plant
    input_delay_s: 0.0        #   delay between u_h and the plant, s (fractional samples exact)
    extra_modes:              #   each multiplies the plant by w^2 / (s^2 + 2 damping w s + w^2)
      - {frequency_hz: 80.0, damping: 0.05}
    disturbances:             #   sinusoids added to output y (seen by the controller)
      - {frequency_hz: 13.0, amplitude: 0.01, phase_rad: 0.0, output: 0}

``extra_modes`` and a fractional ``input_delay_s`` need a continuous-time plant.

MIMO: ``num`` is a nested list ``[n_out][n_in][coefficients]``; ``den`` is either
one coefficient list shared by all entries or nested the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ModelError
from .arrays import ComplexArray, FloatArray
from .results import FRF
from .systems import TransferMatrix


@dataclass(frozen=True)
class Model:
    """A validated multirate loop model.

    Attributes
    ----------
    fs_high : float
        High sample rate (Hz).
    ratio : int
        F.
    plant : TransferMatrix
        Continuous (``dt`` None) or discrete at ``1/fs_high``; n_y x n_u.
    controller : TransferMatrix or None
        Discrete at ``ratio/fs_high``; n_u x n_y. None: open loop.
    noise_std, reference_std : float
    sample_phase, control_delay : int
    plant_gain : float
        Multiplies the plant.
    input_delay : float
        Seconds between u_h and the plant input.
    extra_modes : tuple of (frequency_hz, damping)
        Each multiplies the (continuous) plant by ``w^2 / (s^2 + 2 damping w s + w^2)``.
    disturbances : tuple of (frequency_hz, amplitude, phase_rad, output)
        Sinusoids added to output ``output`` of y (also seen by the controller).
    """

    fs_high: float
    ratio: int
    plant: TransferMatrix
    controller: TransferMatrix | None = None
    noise_std: float = 0.0
    reference_std: float = 1.0
    sample_phase: int = 0
    control_delay: int = 0
    plant_gain: float = 1.0
    input_delay: float = 0.0
    extra_modes: tuple[tuple[float, float], ...] = ()
    disturbances: tuple[tuple[float, float, float, int], ...] = ()

    @property
    def n_y(self) -> int:
        """Plant outputs."""
        return self.plant.shape[0]

    @property
    def n_u(self) -> int:
        """Plant inputs."""
        return self.plant.shape[1]

    @property
    def fs_low(self) -> float:
        """Controller rate fs_high / F in Hz."""
        return self.fs_high / self.ratio

    def plant_effective(self) -> TransferMatrix:
        """The plant with gain and extra modes applied (before delay and discretisation)."""
        P = self.plant
        if self.plant_gain != 1.0:
            P = P.times([self.plant_gain], [1.0])
        for f, zeta in self.extra_modes:
            w = 2.0 * np.pi * f
            P = P.times([w * w], [1.0, 2.0 * zeta * w, w * w])
        return P

    def plant_discrete(self) -> TransferMatrix:
        """The plant at the high rate (ZOH-discretised when given in continuous time).

        Extensions included.
        """
        P = self.plant_effective()
        if P.dt is None:
            return P.discretize(1.0 / self.fs_high, delay=self.input_delay)
        d = int(round(self.input_delay * self.fs_high))
        return P.times([1.0], [1.0] + [0.0] * d) if d else P

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
        return self.controller.dft_response(n_low)

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
