# SPDX-License-Identifier: Apache-2.0
"""The one container of a loop's signals: r_h, u_h, y_h and what is known about them.

Data files, simulations, the live window and the diagnosis all hand r, u, y around as
a :class:`LoopData`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DataError, DimensionError
from .arrays import FloatArray, IntArray


def _column(x: object, name: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DimensionError(
            f"{name} must have shape (n_samples,) or (n_samples, n_channels), got {a.shape}"
        )
    return a


def y_at_low_rate(n_samples: int, n_y: int, ratio: int | None) -> bool:
    """Whether a y of ``n_y`` samples is the low-rate output of an N-sample record.

    N samples: the high rate (False); N/F: the low rate, y_h at samples q, q + F, ... (True;
    with F unknown, any N/n_y > 1 that divides N passes here and is checked once F is known).
    DimensionError naming the lengths otherwise.
    """
    N = int(n_samples)
    if n_y == N:
        return False
    if ratio is None:
        if 0 < n_y < N and N % n_y == 0:
            return True
        low = "N/F (the low rate)"
    else:
        if ratio > 1 and n_y * ratio == N:
            return True
        low = f"N/F = {N / ratio:g} (the low rate, F = {ratio})"
    raise DimensionError(
        f"y has {n_y} samples: neither N = {N} (the high rate, as r and u) nor {low}"
    )


@dataclass(frozen=True)
class LoopData:
    """r_h (excitation), u_h (plant input), y_h (plant output) of one loop.

    Attributes
    ----------
    r, u, y : ndarray, shape (N, channels), float64
        1-D input becomes one column; arrays are not copied. ``y`` may hold N/F rows: the
        output measured at the low rate only (``y_h`` at samples q, q + F, ...; see
        :attr:`y_step` and ``y_phase``).
    fs_high : float or None
        High sample rate in Hz, where known.
    ratio : int or None
        F, where known.
    first : int
        Absolute index of the first sample (a live window's position in its stream).
    period : int or None
        Samples per period of a periodic excitation, where the data are periodic.
    labels : ndarray of int, shape (N, 3), or None
        Each sample's labels (realization, period, sample of the period) where an
        excitation's labels came with the record (:mod:`mr_ident.numerics.excitation.schedule`).
    y_phase : int
        q: with y at the low rate, the high-rate sample (0..F-1) of each period at which it
        was taken, ``y[m] = y_h[m F + q]`` (0 otherwise).

    Raises
    ------
    DimensionError
        If a signal is not 1-D or 2-D, r and u differ in length, y has neither N nor N/F
        samples, ``y_phase`` is outside 0..F-1, or ``labels`` is not (N, 3).

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import LoopData
    >>> d = LoopData(np.zeros(6), np.zeros(6), np.zeros(2), fs_high=300.0, ratio=3)
    >>> d.n_samples, d.y_step, d.r.shape  # y at the low rate: one sample per period
    (6, 3, (6, 1))
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    fs_high: float | None = None
    ratio: int | None = None
    first: int = 0
    period: int | None = None
    labels: IntArray | None = None
    y_phase: int = 0

    def __post_init__(self) -> None:
        arrays = {name: _column(getattr(self, name), name) for name in ("r", "u", "y")}
        lengths = {name: a.shape[0] for name, a in arrays.items()}
        if lengths["u"] != lengths["r"]:
            raise DimensionError(f"r, u, y must have equal lengths, got {lengths}")
        y_at_low_rate(lengths["r"], lengths["y"], self.ratio)
        step = lengths["r"] // max(lengths["y"], 1)
        if not 0 <= self.y_phase < step and self.y_phase:
            raise DimensionError(
                f"y_phase must be in 0..{step - 1} (y every {step} samples), got {self.y_phase}"
            )
        for name, a in arrays.items():
            object.__setattr__(self, name, a)
        if self.labels is not None:
            lab = np.asarray(self.labels)
            if lab.shape != (lengths["r"], 3):
                raise DimensionError(
                    f"labels must have shape (n_samples={lengths['r']}, 3), got {lab.shape}"
                )
            object.__setattr__(self, "labels", lab.astype(np.int64, copy=False))

    @property
    def n_samples(self) -> int:
        """N, the number of samples."""
        return int(self.r.shape[0])

    @property
    def y_step(self) -> int:
        """High-rate samples per sample of y: 1, or F for an output at the low rate."""
        return self.n_samples // int(self.y.shape[0])

    @property
    def end(self) -> int:
        """Absolute index one past the last sample."""
        return self.first + self.n_samples

    def rates(self) -> tuple[float, int]:
        """``(fs_high, ratio)``; DataError when either is unknown."""
        if self.fs_high is None or self.ratio is None:
            raise DataError(
                f"fs_high and ratio must be known, got {self.fs_high} and {self.ratio}"
            )
        return float(self.fs_high), int(self.ratio)

    def part(self, start: int, stop: int) -> LoopData:
        """Samples ``start:stop`` (relative to this record), ``first`` moved with them.

        With y at the low rate, ``start`` and ``stop`` must be multiples of F.
        """
        s = self.y_step
        if s > 1 and (start % s or stop % s):
            raise DimensionError(
                f"with y at the low rate (F = {s}) a part must start and stop at multiples of "
                f"F, got {start}:{stop}"
            )
        return replace(
            self,
            r=self.r[start:stop],
            u=self.u[start:stop],
            y=self.y[start // s : stop // s],
            first=self.first + start,
            labels=None if self.labels is None else self.labels[start:stop],
        )
