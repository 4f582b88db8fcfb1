# SPDX-License-Identifier: Apache-2.0
"""Excitation files: a multisine design written as NPZ or CSV (``mr-ident excite``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, DataError
from ..numerics.arrays import FloatArray
from ..numerics.excitation.multisine import Multisine
from .atomic import atomic_write
from .datafile import load_npz


def write_excitation(path: str | Path, ms: Multisine, *, ratio: int = 1) -> None:
    """``ms`` to ``path`` by suffix.

    NPZ: ``r`` (M, P·N) for one input, (M, P·N, n_in) for several; ``fs_high``, ``ratio``,
    ``period``, ``lines`` (n_in, L; -1 pads), ``detection``, ``kind``, ``crest_factor``
    (M, n_in), and a rotated design's ``realization_lines`` (M, n_in, L). CSV: a column
    ``t`` (s), then ``r`` per realization (``r_m<k>``; with several inputs ``r_m<k>_u<i>``),
    one row per sample; the design in a ``#`` header line.
    """
    p = Path(path)
    M, n, n_in = ms.r.shape
    suffix = p.suffix.lower()
    if suffix == ".npz":
        arrays: dict[str, Any] = {
            "r": ms.r[:, :, 0] if n_in == 1 else ms.r,
            "fs_high": ms.fs_high,
            "ratio": int(ratio),
            "period": ms.period,
            "lines": ms.lines,
            "detection": ms.detection,
            "kind": ms.kind,
            "crest_factor": ms.crest_factor,
        }
        if ms.realization_lines is not None:
            arrays["realization_lines"] = ms.realization_lines

        def w(fh: Any) -> None:
            np.savez(fh, **arrays)

        atomic_write(p, w, binary=True)
    elif suffix == ".csv":
        names = ["t"] + [
            f"r_m{m}" if n_in == 1 else f"r_m{m}_u{i}" for m in range(M) for i in range(n_in)
        ]
        t = np.arange(n) / ms.fs_high
        table = np.column_stack([t, ms.r.transpose(1, 0, 2).reshape(n, M * n_in)])
        head = (
            f"# multisine {ms.kind}: fs_high {ms.fs_high:g} Hz, period {ms.period} samples, "
            f"{n // ms.period} periods, {M} realizations, {n_in} inputs, ratio {ratio}\n"
        )

        def w_csv(fh: Any) -> None:
            fh.write(head)
            np.savetxt(fh, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g")

        atomic_write(p, w_csv, binary=False)
    else:
        raise ConfigError(f"an excitation file must end in .npz or .csv, got {str(p)!r}")


def read_excitation(path: str | Path) -> tuple[FloatArray, float, int]:
    """An excitation NPZ of :func:`write_excitation`: (r (M, P·N, n_in), fs_high, period).

    DataError naming the file and what it lacks.
    """
    p = Path(path)
    z = load_npz(
        p, ("r", "fs_high", "period"), "an excitation file (mr-ident excite --out FILE.npz)"
    )
    r = np.asarray(z["r"], float)
    r = r[:, :, None] if r.ndim == 2 else r
    if r.ndim != 3:
        raise DataError(f"{p}: r must be (M, P*N) or (M, P*N, n_in), got {z['r'].shape}")
    return r, float(z["fs_high"]), int(z["period"])
