# SPDX-License-Identifier: Apache-2.0
"""Periodic multi-realization data (r, u, y of shape (M, n)) and the BLA result file."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import DataError
from ..numerics.arrays import FloatArray
from ..numerics.excitation.bla import BLA, LINE_PFG_SOURCE
from .atomic import atomic_write
from .datafile import load_npz


class Realizations(NamedTuple):
    """A periodic NPZ's realizations (:func:`read_realizations`).

    r, u, y of shape (M, n) each (y (M, n/F) when measured at the low rate), with the
    file's ``fs_high`` and ``ratio`` where given and ``y_phase`` q (0 when not given).
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    fs_high: float | None
    ratio: int | None
    y_phase: int

    @property
    def low_rate_y(self) -> bool:
        """Whether y holds the low-rate samples only."""
        return bool(self.y.shape[1] != self.r.shape[1])


def read_realizations(path: str | Path, ratio: int | None = None) -> Realizations:
    """r, u, y of an NPZ as (M, n) each, with ``fs_high``, ``ratio`` and ``y_phase``.

    One channel; a 1-D array is one realization. ``y`` may hold n/F samples per row (the
    output at the low rate, samples q, q + F, ...; F the file's ``ratio`` or ``ratio``
    here, q its ``y_phase``). DataError naming the file and what does not fit.
    """
    p = Path(path)
    if p.suffix.lower() != ".npz":
        raise DataError(f"periodic data with realizations must be an .npz file, got {str(p)!r}")
    z = load_npz(p, ("r", "u", "y"), "periodic data (r, u, y of shape (M, n))")
    arrs = [np.atleast_2d(np.asarray(z[k], float)) for k in "ruy"]
    fs = float(z["fs_high"]) if "fs_high" in z else None
    F = int(z["ratio"]) if "ratio" in z else None
    slow = ratio or F
    low_y = (
        slow is not None
        and slow > 1
        and arrs[2].shape[0] == arrs[0].shape[0]
        and arrs[2].shape[1] * slow == arrs[0].shape[1]
    )
    if (
        any(a.ndim != 2 for a in arrs)
        or arrs[0].shape != arrs[1].shape
        or (arrs[2].shape != arrs[0].shape and not low_y)
    ):
        raise DataError(
            f"{p}: r, u, y must each be (M realizations, n samples) of one channel (y may "
            f"hold n/F samples, the output at the low rate, with F given); got "
            f"{', '.join(str(a.shape) for a in arrs)}"
        )
    q = int(z["y_phase"]) if "y_phase" in z else 0
    return Realizations(arrs[0], arrs[1], arrs[2], fs, F, q)


def write_bla(path: str | Path, bla: BLA, *, fs_high: float, ratio: int, period: int) -> None:
    """The BLA as a result NPZ that ``read_result`` takes.

    ``frequency``, ``P``, ``P_std``, with ``noise_std``, ``nl_std``, ``odd_level``,
    ``even_level``, ``noise_level``, ``periods``, ``realizations``, ``lines`` and
    ``period`` beside (:func:`read_bla` reads them back); ``pfg_data``, ``pfg_data_std``
    where a lifted design measured the PFG from data at some lines (nan at the others).
    """
    f = bla.lines * fs_high / period
    arrays: dict[str, Any] = {
        "frequency": f,
        "P": bla.response[:, None, None],
        "P_std": bla.std[:, None, None],
        "noise_std": bla.noise_std[:, None, None],
        "nl_std": bla.nl_std[:, None, None],
        "odd_level": bla.odd_level,
        "even_level": bla.even_level,
        "noise_level": bla.noise_level,
        "periods": bla.periods,
        "realizations": bla.realizations,
        "lines": bla.lines,
        "period": int(period),
        "method": "bla",
        "fs_high": float(fs_high),
        "ratio": int(ratio),
    }
    if bla.pfg is not None and bla.pfg_std is not None and np.isfinite(bla.pfg).any():
        arrays |= {
            "pfg_data": bla.pfg,
            "pfg_data_std": bla.pfg_std,
            "pfg_data_source": np.array(LINE_PFG_SOURCE),
        }
    atomic_write(Path(path), lambda fh: np.savez(fh, **arrays), binary=True)


def read_bla(path: str | Path) -> tuple[BLA, FloatArray] | None:
    """The BLA of a result NPZ of :func:`write_bla` and its frequencies (Hz), or None.

    None when the result is another identification (no ``noise_std``/``nl_std``). One
    output and input (the BLA's). Lines are -1 where the file does not give them.
    DataError naming the file when it is not a result at all.
    """
    z = load_npz(path, ("frequency", "P", "P_std"), "an identification result")
    if "noise_std" not in z or "nl_std" not in z:
        return None
    f = np.asarray(z["frequency"], float)

    def col(key: str) -> Any:
        return np.asarray(z[key]).reshape(f.size, -1)[:, 0]

    def scalar(key: str) -> FloatArray:
        return np.atleast_1d(np.asarray(z[key], float)) if key in z else np.full(1, np.nan)

    lines = np.asarray(z["lines"], np.int64) if "lines" in z else np.full(f.size, -1, np.int64)
    bla = BLA(
        lines,
        col("P").astype(complex),
        col("P_std").astype(float),
        col("noise_std").astype(float),
        col("nl_std").astype(float),
        scalar("odd_level"),
        scalar("even_level"),
        scalar("noise_level"),
        int(z["periods"]) if "periods" in z else 0,
        int(z["realizations"]) if "realizations" in z else 0,
        col("pfg_data").astype(float) if "pfg_data" in z else None,
        col("pfg_data_std").astype(float) if "pfg_data_std" in z else None,
    )
    return bla, f
