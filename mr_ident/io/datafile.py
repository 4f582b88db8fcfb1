# SPDX-License-Identifier: Apache-2.0
"""Data files: measured or simulated r_h, u_h, y_h, and identification results.

CSV
    A header line naming the columns ``t,r,u,y`` (t in s), or for several
    channels ``t,r0,r1,...,u0,u1,...,y0,...``; one row per high-rate sample.
    fs_high is taken from ``t`` (uniform spacing required); F from the caller. An output
    measured at the low rate leaves its y cells empty (or ``nan``) but on the rows q,
    q + F, q + 2F, ... to the end: y is then those N/F rows, taken at sample q of each
    period (the caller checks that the step is F). A u logged at the controller's rate is
    given the same way, on the rows where each value was applied: it is held to the next
    (the rows before the first are missing samples). Otherwise an empty (or ``nan``) cell of
    u or y is a **missing sample** (a dropped message): ``identify`` estimates it as an
    unknown of the fit (the method page, "Missing samples"); one of r is recovered from the
    loop where it determines it ("Missing samples of r"); t is complete.
NPZ (data)
    Arrays ``r``, ``u``, ``y`` of shape (N,) or (N, channels), and scalars
    ``fs_high`` (Hz) and ``ratio`` (F). ``y`` may hold N/F rows instead: the output measured
    at the low rate only, y_h at samples q, q + F, ... (exactly N/F; another length is an
    error naming the lengths), q the optional scalar ``y_phase`` (default 0). ``u`` may hold
    N/F rows: the controller's output at its rate, held to the high rate from sample
    ``u_phase`` of each block (optional scalar, default 0; the samples before it missing).
    A NaN of r, u or a high-rate y is a missing sample, as in the CSV.
NPZ (result, written by ``mr-ident identify``)
    ``frequency`` (K,), ``P`` (K, n_y, n_u) complex, ``P_std`` (K, n_y, n_u);
    ``pfg_data``, ``pfg_data_std`` (K,), the PFG identified from data alone (the lifted
    r -> y map), where the data give it; with a controller ``pfg``, ``pfg_std`` (K,), the
    PFG of P_h under that controller; plus ``method``, ``fs_high``, ``ratio`` and ``n`` (K,),
    the LPM window half-width used per bin (0: none; files written before it read the same;
    stored as int16 when it fits);
    ``n_missing`` (n_y + n_u,), the missing samples of every channel of y then u, when any;
    ``r_recovered`` and ``r_unknown``, r's missing samples recovered from the loop and not
    determined by the data, when any;
    ``injection`` where r entered (``plant_input`` or ``setpoint``), ``structure`` what the
    data showed of the loop (a sentence: the hold, F, where r enters), and with r at the
    setpoint ``undetermined`` (K,) bool, the bins whose window reaches a zero of the hold.

Writers go through a temporary file and a rename: a failed write leaves nothing.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DataError, DimensionError
from ..numerics.arrays import FloatArray, IntArray
from ..numerics.identify import DATA_PFG_SOURCE
from ..numerics.results import FRF, PFG, Identification
from ..numerics.signals import LoopData
from .atomic import atomic_write

_SIGNALS = ("r", "u", "y")


def _check_finite(
    name: str,
    a: FloatArray,
    where: str,
    csv: bool = False,
    rows: IntArray | None = None,
    holes: bool = False,
) -> None:
    """Raise at the first NaN/inf: a CSV's line number (header = line 1), else the array index.

    ``rows``: the CSV row of each row of ``a`` (a low-rate y's), default 0, 1, ...;
    ``holes``: NaN is a missing sample (u, a high-rate y), only inf is refused.
    """
    bad = np.isinf(a) if holes else ~np.isfinite(a)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        value = a[row, col]
        if csv:
            line = (row if rows is None else int(rows[row])) + 2
            raise DataError(
                f"{where}: line {line}, column {name!r}: {value} (need a finite number)"
            )
        at = f"[{row}]" if a.shape[1] == 1 else f"[{row}, {col}]"
        raise DataError(f"{where}: array {name!r} at index {at}: {value} (need a finite number)")


def _first_bad_line(p: Path, header: list[str]) -> str:
    """Where and why a CSV body does not parse as a table of numbers (for the error)."""
    with open(p) as fh:
        next(fh)
        for lineno, line in enumerate(fh, start=2):
            if not line.strip():
                continue
            values = line.rstrip("\r\n").split(",")
            if len(values) != len(header):
                return (
                    f"line {lineno} has {len(values)} values, "
                    f"the header names {len(header)} columns"
                )
            for name, v in zip(header, values, strict=True):
                try:
                    float(v)
                except ValueError:
                    return f"line {lineno}, column {name.strip()!r}: {v.strip()!r} is not a number"
    return "unreadable table"


def _columns(header: list[str], where: str) -> dict[str, list[int]]:
    cols: dict[str, list[tuple[int, int]]] = {s: [] for s in _SIGNALS}
    seen_t = False
    for j, name in enumerate(header):
        name = name.strip()
        if name == "t":
            seen_t = True
            continue
        m = re.fullmatch(r"([ruy])(\d*)", name)
        if not m:
            raise DataError(
                f"{where}: unexpected column {name!r}; expected t, r, u, y (or r0, r1, ... for "
                "MIMO)"
            )
        cols[m.group(1)].append((int(m.group(2)) if m.group(2) else 0, j))
    if not seen_t:
        raise DataError(f"{where}: missing column 't' (time in s)")
    out = {}
    for s in _SIGNALS:
        if not cols[s]:
            raise DataError(f"{where}: missing column {s!r}")
        idx = sorted(cols[s])
        if [i for i, _ in idx] != list(range(len(idx))):
            raise DataError(
                f"{where}: columns for {s!r} must be {s} or {s}0..{s}{len(idx) - 1}, "
                f"got {[header[j] for _, j in idx]}"
            )
        out[s] = [j for _, j in idx]
    return out


def read_csv(path: str | Path) -> LoopData:
    """Read a CSV data file (module docstring); fs_high from its ``t`` column."""
    p = Path(path)
    try:
        with open(p) as fh:
            header = fh.readline().strip().split(",")
    except OSError as err:
        raise DataError(f"cannot read {str(p)!r}: {err.strerror}") from err
    if header == [""]:
        raise DataError(f"{p}: empty file (expected a header line t,r,u,y)")
    cols = _columns(header, str(p))
    empty_is_nan: dict[int | str, Callable[[str], Any]] = dict.fromkeys(
        cols["r"] + cols["u"] + cols["y"], _cell_or_nan
    )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "no data": reported below
            try:
                table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
            except ValueError:  # empty y cells parse per cell, the rest as before
                table = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2, converters=empty_is_nan)
    except ValueError:
        raise DataError(f"{p}: {_first_bad_line(p, header)}") from None
    if table.shape[0] == 0:
        raise DataError(f"{p}: no data rows after the header")
    if table.shape[1] != len(header):
        raise DataError(
            f"{p}: rows have {table.shape[1]} values but the header names {len(header)} columns"
        )
    t = table[:, header.index("t")]
    _check_finite("t", t[:, None], str(p), csv=True)
    arrays = {}
    y_phase = 0
    for s in _SIGNALS:
        arrays[s] = table[:, cols[s]]
        rows = None
        if s in ("u", "y") and np.isnan(arrays[s]).any():
            arrays[s], q = _low_rate_rows(arrays[s], s, str(p))
            step = table.shape[0] // arrays[s].shape[0]
            rows = q + step * np.arange(arrays[s].shape[0])
            if s == "y":
                y_phase = q
        holes = arrays[s].shape[0] == table.shape[0]
        for c, j in enumerate(cols[s]):
            name = header[j].strip()
            _check_finite(name, arrays[s][:, c : c + 1], str(p), True, rows, holes)
        if s == "u" and rows is not None:  # the controller's rate: held to the next value
            arrays[s] = held_to_high_rate(arrays[s], table.shape[0], q)
    fs = None
    if t.size >= 2:
        dt = np.diff(t)
        h = float(np.median(dt))
        if h <= 0 or np.max(np.abs(dt - h)) > 1e-6 * max(h, 1e-12) + 1e-9:
            raise DataError(f"{p}: column 't' is not uniformly increasing (median step {h:g} s)")
        fs = 1.0 / h
    return LoopData(arrays["r"], arrays["u"], arrays["y"], fs, None, y_phase=y_phase)


def _cell_or_nan(cell: str) -> float:
    """A CSV cell as a number, an empty one as NaN (not measured, or missing, there)."""
    return float(cell) if cell.strip() else np.nan


def held_to_high_rate(x: FloatArray, n_samples: int, start: int) -> FloatArray:
    """A signal at the controller's rate held to the high rate, shape (n_samples, channels).

    ``x`` (M, channels): value k applied at sample ``start + k F`` (F = n_samples // M) and
    held to the next; the samples before ``start`` are missing (NaN).
    """
    F = n_samples // x.shape[0]
    out = np.full((n_samples, x.shape[1]), np.nan)
    held = np.repeat(x, F, axis=0)[: n_samples - start]
    out[start : start + held.shape[0]] = held
    return out


def _low_rate_rows(x: FloatArray, name: str, where: str) -> tuple[FloatArray, int]:
    """A CSV's y or u with empty (NaN) cells: its rows q, q + s, ... to the end, and q.

    DataError naming the first line that breaks that pattern (header = line 1); x as it is
    when most of its given rows are adjacent (a high-rate signal with missing samples).
    """
    N = x.shape[0]
    given = ~np.isnan(x)
    rows = np.flatnonzero(given.any(axis=1))
    mixed = np.flatnonzero(given.any(axis=1) & ~given.all(axis=1))
    rule = (
        f"{name} at the low rate must be given on one row of every low-rate period (rows q, "
        "q + F, q + 2F, ... to the end) and left empty on the others"
    )
    if rows.size >= 2 and (np.diff(rows) == 1).mean() > 0.5:  # high rate, missing samples
        return x, 0
    if mixed.size:
        raise DataError(
            f"{where}: line {mixed[0] + 2}: {name} is empty in some columns only; {rule}"
        )
    if rows.size < 2:
        raise DataError(f"{where}: {name} is given on {rows.size} row(s) of {N}; {rule}")
    q, step = int(rows[0]), int(rows[1] - rows[0])
    if q >= step:
        raise DataError(
            f"{where}: {name} is empty on lines 2..{q + 1}, more than a period; {rule}"
        )
    want = np.zeros(N, dtype=bool)
    want[q::step] = True
    off = np.flatnonzero(want != given.any(axis=1))
    if off.size:
        state = "empty" if want[off[0]] else "given"
        raise DataError(
            f"{where}: line {off[0] + 2}: {name} is {state} there, but given every {step} rows "
            f"from line {q + 2} before it; {rule}"
        )
    if N % step:
        raise DataError(
            f"{where}: {name} is given every {step} rows but the {N} rows are no whole number "
            f"of periods; {rule}"
        )
    return x[rows], q


def load_npz(path: str | Path, required: tuple[str, ...], what: str) -> dict[str, Any]:
    """Every array of an NPZ file (the file closed again), ``required`` ones checked.

    DataError naming the file, ``what`` it should be, and what it lacks and has.
    """
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise DataError(f"cannot read {str(p)!r} as {what}: {err}") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise DataError(
            f"{p} is not {what}: missing {', '.join(missing)}; it has "
            f"{', '.join(sorted(arrays)) or 'nothing'}"
        )
    return arrays


def read_npz(path: str | Path) -> LoopData:
    """Read an NPZ data file (module docstring)."""
    p = Path(path)
    z = load_npz(p, _SIGNALS, "an NPZ data file (r, u, y, fs_high, ratio)")
    arrays = {}
    for s in _SIGNALS:
        a = np.asarray(z[s])
        if a.dtype.kind not in "fiu":
            raise DataError(f"{p}: array {s!r} must be numeric, got dtype {a.dtype}")
        if a.ndim not in (1, 2) or a.shape[0] == 0 or a.size == 0:
            raise DataError(
                f"{p}: array {s!r} must have shape (N,) or (N, channels) with N > 0, got {a.shape}"
            )
        a = a.astype(float, copy=False)  # float64 as stored: no copy
        if a.ndim == 1:
            a = a[:, None]
        _check_finite(s, a, str(p), holes=True)  # a low-rate y: checked below
        arrays[s] = a
    fs = ratio = None
    if "fs_high" in z:
        v = np.asarray(z["fs_high"])
        if v.size != 1 or v.dtype.kind not in "fiu" or not np.isfinite(v).all() or float(v) <= 0:
            raise DataError(f"{p}: fs_high must be one positive number, got {v.tolist()!r}")
        fs = float(v)
    if "ratio" in z:
        v = np.asarray(z["ratio"])
        if v.size != 1 or v.dtype.kind not in "fiu" or float(v) != int(v) or int(v) < 1:
            raise DataError(f"{p}: ratio must be one integer >= 1, got {v.tolist()!r}")
        ratio = int(v)
    lens = {s: arrays[s].shape[0] for s in _SIGNALS}
    if lens["u"] != lens["r"]:
        F = ratio or lens["r"] // lens["u"]
        if lens["u"] * F != lens["r"]:
            raise DataError(
                f"{p}: r, u, y have unequal lengths {lens} (u may hold N/F rows: the "
                "controller's output at its rate)"
            )
        _check_finite("u", arrays["u"], str(p))  # a low-rate u has no missing samples
        arrays["u"] = held_to_high_rate(arrays["u"], lens["r"], _scalar(z, "u_phase", p))
    if lens["y"] != lens["r"]:
        _check_finite("y", arrays["y"], str(p))  # a low-rate y has no missing samples
    y_phase = _scalar(z, "y_phase", p)
    try:
        return LoopData(arrays["r"], arrays["u"], arrays["y"], fs, ratio, y_phase=y_phase)
    except DimensionError as err:
        raise DataError(f"{p}: {err}") from None


def _scalar(z: Any, key: str, p: Path) -> int:
    """An optional scalar sample index of an NPZ (0 when absent); DataError naming it."""
    if key not in z:
        return 0
    v = np.asarray(z[key])
    if v.size != 1 or v.dtype.kind not in "iu" or int(v) < 0:
        raise DataError(f"{p}: {key} must be one integer >= 0, got {v.tolist()!r}")
    return int(v)


def read_data(path: str | Path) -> LoopData:
    """Read a CSV or NPZ data file (chosen by suffix)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return read_csv(path)
    if suffix == ".npz":
        return read_npz(path)
    raise DataError(f"unsupported data file {str(path)!r}: expected a .csv or .npz suffix")


def write_data(
    path: str | Path,
    r: ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    fs_high: float,
    ratio: int,
    y_phase: int = 0,
) -> None:
    """Write r, u, y as CSV or NPZ (by suffix).

    A y of N/F rows is the output at the low rate, taken at sample ``y_phase`` of each
    period: the NPZ holds it with ``y_phase``, the CSV on those rows (``nan`` elsewhere).
    """
    p = Path(path)
    r2, u2, y2 = (np.atleast_2d(np.asarray(a, float).T).T for a in (r, u, y))
    data = LoopData(r2, u2, y2, fs_high, ratio, y_phase=y_phase)  # checks the lengths
    suffix = p.suffix.lower()
    if suffix == ".npz":
        arrays: dict[str, Any] = {
            "r": r2.squeeze(1) if r2.shape[1] == 1 else r2,
            "u": u2.squeeze(1) if u2.shape[1] == 1 else u2,
            "y": y2.squeeze(1) if y2.shape[1] == 1 else y2,
            "fs_high": float(fs_high),
            "ratio": int(ratio),
        }
        if data.y_step > 1:
            arrays["y_phase"] = int(y_phase)

        def w(fh: Any) -> None:
            np.savez(fh, **arrays)

        atomic_write(p, w, binary=True)
    elif suffix == ".csv":
        names = ["t"]
        for s, a in (("r", r2), ("u", u2), ("y", y2)):
            names += [s] if a.shape[1] == 1 else [f"{s}{i}" for i in range(a.shape[1])]
        t = np.arange(r2.shape[0]) / fs_high
        if data.y_step > 1:  # the low-rate samples on their rows
            y2 = np.full((r2.shape[0], y2.shape[1]), np.nan)
            y2[y_phase :: data.y_step] = data.y
        table = np.column_stack([t, r2, u2, y2])
        atomic_write(
            p,
            lambda fh: np.savetxt(
                fh, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g"
            ),
            binary=False,
        )
    else:
        raise DataError(f"unsupported output {str(p)!r}: expected a .csv or .npz suffix")


def write_result(path: str | Path, ident: Identification, structure: str = "") -> None:
    """Write an identification result NPZ (see the module docstring).

    ``structure``: what the data showed of the loop's structure, in words.
    """
    p = Path(path)
    if p.suffix.lower() != ".npz":
        raise DataError(f"the result file must end in .npz, got {str(p)!r}")
    arrays: dict[str, Any] = {
        "frequency": ident.plant.frequency,
        "P": ident.plant.response,
        "P_std": ident.plant.std,
        "method": np.array(ident.plant.method),
        "local": np.array(ident.local),
        "n": _compact(
            np.zeros(ident.plant.frequency.size, np.int64)
            if ident.n_used is None
            else ident.n_used
        ),
        "fs_high": ident.fs_high,
        "ratio": ident.ratio,
        "injection": np.array(ident.injection),
        "structure": np.array(structure),
    }
    if ident.undetermined is not None:
        arrays["undetermined"] = ident.undetermined
    if ident.n_missing is not None and ident.n_missing.any():
        arrays["n_missing"] = ident.n_missing
    if ident.r_recovered or ident.r_unknown:
        arrays["r_recovered"], arrays["r_unknown"] = ident.r_recovered, ident.r_unknown
    for key, g in (("pfg", ident.pfg), ("pfg_data", ident.pfg_data)):
        if g is not None:
            arrays[key] = g.gain
            arrays[f"{key}_std"] = g.std
            arrays[f"{key}_source"] = np.array(g.source)
    atomic_write(p, lambda fh: np.savez(fh, **arrays), binary=True)


def _compact(n: IntArray) -> np.ndarray:
    """Integers in the smallest of int16, int32, int64 that holds them (lossless).

    Signed, so that arithmetic on what is read (``n - 1``) does not wrap.
    """
    top = max(abs(int(n.max(initial=0))), abs(int(n.min(initial=0))))
    kind = next(t for t in (np.int16, np.int32, np.int64) if top <= np.iinfo(t).max)
    return n.astype(kind)


def read_result(path: str | Path) -> FRF:
    """P_h of a result NPZ written by :func:`write_result`, as an FRF (with its std)."""
    what = "an identification result (written by mr-ident identify)"
    z = load_npz(path, ("frequency", "P", "P_std"), what)
    method = str(z["method"]) if "method" in z else "reference"
    return FRF(z["frequency"], z["P"], z["P_std"], method)


def read_identification(path: str | Path) -> Identification:
    """A result NPZ as written by :func:`write_result`: P_h, both PFGs where present, n.

    The lifted maps are not stored (``lifted_J``, ``lifted_S`` None).
    """
    what = "an identification result (written by mr-ident identify)"
    z = load_npz(path, ("frequency", "P", "P_std", "fs_high", "ratio"), what)
    plant = FRF(
        z["frequency"], z["P"], z["P_std"], str(z["method"]) if "method" in z else "reference"
    )
    pfgs: dict[str, PFG | None] = {}
    for key, source in (("pfg", "plant"), ("pfg_data", DATA_PFG_SOURCE)):
        pfgs[key] = None
        if key in z:
            src = str(z[f"{key}_source"]) if f"{key}_source" in z else source
            pfgs[key] = PFG(z["frequency"], z[key], z[f"{key}_std"], src)
    return Identification(
        plant=plant,
        pfg=pfgs["pfg"],
        lifted_J=None,
        lifted_S=None,
        fs_high=float(z["fs_high"]),
        ratio=int(z["ratio"]),
        n_used=z["n"] if "n" in z else None,
        pfg_data=pfgs["pfg_data"],
        n_missing=z["n_missing"] if "n_missing" in z else None,
        injection=str(z["injection"]) if "injection" in z else "plant_input",
        undetermined=z["undetermined"] if "undetermined" in z else None,
        r_recovered=int(z["r_recovered"]) if "r_recovered" in z else 0,
        r_unknown=int(z["r_unknown"]) if "r_unknown" in z else 0,
    )
