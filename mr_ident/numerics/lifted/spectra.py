# SPDX-License-Identifier: Apache-2.0
"""The spectra of r, u, y that the methods fit, computed once per identification."""

from __future__ import annotations

import threading

from ..arrays import ComplexArray, FloatArray
from ..lifting import dft, half_spectra, time_lift


class Spectra:
    """The spectra of r, u, y a method needs, computed once per identification.

    :func:`~mr_ident.numerics.identify.identify` fits several windows on the same record
    (the automatic window's candidates, then the chosen widths); they share these. The
    candidates may run on threads of their own: each spectrum is computed once, under a lock.
    """

    def __init__(self, r: FloatArray, u: FloatArray, y: FloatArray, workers: int) -> None:
        self._signals = {"r": r, "u": u, "y": y}
        self._workers = workers
        self._half: dict[str, list[ComplexArray]] = {}
        self._time: dict[tuple[str, int], ComplexArray] = {}
        self._lock = threading.Lock()

    def halves(self, *names: str) -> list[list[ComplexArray]]:
        """The half spectra of the signals ``names``; those not yet computed in one pass.

        (:func:`~mr_ident.numerics.lifting.half_spectra`: their columns side by side.)
        """
        with self._lock:
            todo = [k for k in dict.fromkeys(names) if k not in self._half]
            if todo:
                done = half_spectra([self._signals[k] for k in todo], workers=self._workers)
                self._half.update(zip(todo, done, strict=True))
            return [self._half[k] for k in names]

    def time_lifted(self, name: str, ratio: int) -> ComplexArray:
        """The M-point DFT of the time-lifted signal ``name`` (M, F c)."""
        key = (name, ratio)
        with self._lock:
            if key not in self._time:
                x = time_lift(self._signals[name], ratio)
                self._time[key] = dft(x, workers=self._workers)
            return self._time[key]
