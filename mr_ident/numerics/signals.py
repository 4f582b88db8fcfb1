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


@dataclass(frozen=True)
class LoopData:
    """r_h (excitation), u_h (plant input), y_h (plant output) of one loop.

    Attributes
    ----------
    r, u, y : ndarray, shape (N, channels), float64
        1-D input becomes one column; arrays are not copied.
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
        excitation's labels came with the record (:mod:`mr_ident.numerics.schedule`).
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    fs_high: float | None = None
    ratio: int | None = None
    first: int = 0
    period: int | None = None
    labels: IntArray | None = None

    def __post_init__(self) -> None:
        arrays = {name: _column(getattr(self, name), name) for name in ("r", "u", "y")}
        lengths = {name: a.shape[0] for name, a in arrays.items()}
        if len(set(lengths.values())) != 1:
            raise DimensionError(f"r, u, y must have equal lengths, got {lengths}")
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
        """Samples ``start:stop`` (relative to this record), ``first`` moved with them."""
        return replace(
            self,
            r=self.r[start:stop],
            u=self.u[start:stop],
            y=self.y[start:stop],
            first=self.first + start,
            labels=None if self.labels is None else self.labels[start:stop],
        )
