"""Linear time-invariant systems: transfer-function matrices and state space.

A :class:`TransferMatrix` holds one numerator per (output, input) entry and one
denominator per entry, coefficients in descending powers of s (continuous,
``dt = None``) or z (discrete, sample time ``dt``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from .errors import ModelError

Poly = tuple[float, ...]


@dataclass(frozen=True)
class StateSpace:
    """``x+ = A x + B u, y = C x + D u`` (discrete) with sample time ``dt``."""

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    D: NDArray[np.float64]
    dt: float | None

    @property
    def n_states(self) -> int:
        return int(self.A.shape[0])


@dataclass(frozen=True)
class TransferMatrix:
    """An ``n_out x n_in`` matrix of rational transfer functions.

    Attributes
    ----------
    num, den : tuple of tuple of tuple of float
        ``num[o][i]`` and ``den[o][i]``: coefficients, descending powers.
    dt : float or None
        Sample time in s; None for continuous time.
    """

    num: tuple[tuple[Poly, ...], ...]
    den: tuple[tuple[Poly, ...], ...]
    dt: float | None

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.num), len(self.num[0])

    @classmethod
    def siso(cls, num: ArrayLike, den: ArrayLike, dt: float | None = None) -> TransferMatrix:
        return cls(((tuple(np.atleast_1d(np.asarray(num, float))),),),
                   ((tuple(np.atleast_1d(np.asarray(den, float))),),), dt)

    def __call__(self, x: ArrayLike) -> NDArray[np.complex128]:
        """Evaluate at complex points ``x`` (s or z), shape (K,) -> (K, n_out, n_in)."""
        xa = np.atleast_1d(np.asarray(x, dtype=complex))
        no, ni = self.shape
        out = np.empty((xa.size, no, ni), dtype=complex)
        for o in range(no):
            for i in range(ni):
                out[:, o, i] = np.polyval(self.num[o][i], xa) / np.polyval(self.den[o][i], xa)
        return out

    def freqresp(self, frequency: ArrayLike, *, dt: float | None = None) -> NDArray[np.complex128]:
        """Frequency response at ``frequency`` Hz, shape (K, n_out, n_in).

        Discrete systems are evaluated at ``z = exp(2j pi f dt)``; continuous ones at
        ``s = 2j pi f``.
        """
        f = np.asarray(frequency, dtype=float)
        if self.dt is None:
            return self(2j * np.pi * f)
        return self(np.exp(2j * np.pi * f * self.dt))

    def discretize(self, dt: float) -> TransferMatrix:
        """Zero-order-hold discretisation of every entry (exact for ZOH inputs)."""
        if self.dt is not None:
            raise ModelError(f"system is already discrete (dt={self.dt}); cannot discretise again")
        no, ni = self.shape
        num, den = [], []
        for o in range(no):
            rn, rd = [], []
            for i in range(ni):
                b, a, _ = scipy.signal.cont2discrete((self.num[o][i], self.den[o][i]), dt, method="zoh")
                b = np.trim_zeros(np.atleast_1d(np.squeeze(b)), "f")
                rn.append(tuple(b) if b.size else (0.0,))
                rd.append(tuple(np.asarray(a, float)))
            num.append(tuple(rn))
            den.append(tuple(rd))
        return TransferMatrix(tuple(num), tuple(den), dt)

    def to_ss(self) -> StateSpace:
        """A (non-minimal, block-diagonal) state-space realisation of all entries."""
        no, ni = self.shape
        blocks = []
        for o in range(no):
            for i in range(ni):
                if not np.any(self.num[o][i]):
                    continue                      # a zero entry needs no states
                A, B, C, D = scipy.signal.tf2ss(self.num[o][i], self.den[o][i])
                blocks.append((o, i, A, B, C, D))
        n = sum(b[2].shape[0] for b in blocks)
        A = np.zeros((n, n))
        B = np.zeros((n, ni))
        C = np.zeros((no, n))
        D = np.zeros((no, ni))
        k = 0
        for o, i, a, b, c, d in blocks:
            m = a.shape[0]
            A[k:k + m, k:k + m] = a
            B[k:k + m, i] = b[:, 0]
            C[o, k:k + m] = c[0]
            D[o, i] += d[0, 0]
            k += m
        return StateSpace(A, B, C, D, self.dt)

    def poles(self) -> NDArray[np.complex128]:
        return np.concatenate([np.roots(d) for row in self.den for d in row])
