# SPDX-License-Identifier: Apache-2.0
"""The modal form of a model file's plant (written by ``mr-ident fit``), read and written.

::

    plant:
      domain: continuous            # or discrete (z, sample time 1/fs_high)
      direct: [[0.0, 0.0], [0.0, 0.0]]   # D, n_out x n_in (a number when SISO)
      modes:                        # each (c1 x + c0) / (x^2 + 2 damping w x + w^2)
        - {frequency_hz: 55.4, damping: 0.047, c1: [[...]], c0: [[...]]}
      real_poles:                   # each residue / (x - pole)
        - {pole: -125.0, residue: [[...]]}

With ``domain: discrete`` a mode's frequency and damping are those of ``s = ln(z) fs_high``
and its numerator is in z; a real pole is the z-plane pole itself. The plant is realised
mode by mode (:class:`~mr_ident.numerics.systems.modal.ModalPlant`), no polynomial formed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ModelError
from ..numerics.arrays import FloatArray
from ..numerics.systems.modal import ModalPlant

MODAL_KEYS = {"domain", "direct", "modes", "real_poles"}


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ModelError(f"{where} must be a finite number, got {v!r}")
    return float(v)


def _mat(v: Any, where: str, shape: tuple[int, int] | None) -> FloatArray:
    """A number (SISO) or a nested [out][in] list of numbers."""
    if not isinstance(v, list):
        m = np.array([[_number(v, where)]])
    else:
        if not v or not all(isinstance(r, list) and r for r in v):
            raise ModelError(f"{where} must be a number or a nested list [out][in], got {v!r}")
        m = np.array(
            [[_number(c, f"{where}[{o}][{i}]") for i, c in enumerate(r)] for o, r in enumerate(v)]
        )
        if len({len(r) for r in v}) != 1:
            raise ModelError(f"{where} rows have different lengths: {[len(r) for r in v]}")
    if shape is not None and m.shape != shape:
        raise ModelError(f"{where} has shape {m.shape}, expected {shape} (the shape of direct)")
    return m


def modal_from_dict(d: dict[str, Any], name: str, dt: float | None) -> ModalPlant:
    """The modal plant of a model file's ``plant`` mapping (module docstring)."""
    unknown = set(d) - MODAL_KEYS
    if unknown:
        raise ModelError(
            f"{name}: unknown key(s) {sorted(unknown)}; allowed: {sorted(MODAL_KEYS)}"
        )
    if "direct" not in d:
        raise ModelError(f"{name}.direct is missing (the modal form needs it: n_out x n_in)")
    D = _mat(d["direct"], f"{name}.direct", None)
    poles: list[complex] = []
    residues: list[Any] = []
    for j, e in enumerate(_items(d, "modes", name, {"frequency_hz", "damping", "c1", "c0"})):
        where = f"{name}.modes[{j}]"
        f = _number(e["frequency_hz"], f"{where}.frequency_hz")
        z = _number(e["damping"], f"{where}.damping")
        if f <= 0 or not -1.0 < z < 1.0:
            raise ModelError(
                f"{where}: frequency_hz must be > 0 and damping in (-1, 1), got {f!r}, {z!r}"
            )
        w = 2.0 * math.pi * f
        p = complex(-z * w, w * math.sqrt(1.0 - z * z))
        if dt is not None:
            p = complex(np.exp(p * dt))
        c1 = _mat(e["c1"], f"{where}.c1", D.shape)
        c0 = _mat(e["c0"], f"{where}.c0", D.shape)
        poles.append(p)
        residues.append((c1 * p + c0) / (p - p.conjugate()))
    for j, e in enumerate(_items(d, "real_poles", name, {"pole", "residue"})):
        where = f"{name}.real_poles[{j}]"
        poles.append(complex(_number(e["pole"], f"{where}.pole")))
        residues.append(_mat(e["residue"], f"{where}.residue", D.shape).astype(complex))
    R = np.array(residues, dtype=complex).reshape(len(poles), *D.shape)
    return ModalPlant(np.array(poles, dtype=complex), R, D, dt)


def _items(d: dict[str, Any], key: str, name: str, fields: set[str]) -> list[dict[str, Any]]:
    items = d.get(key) or []
    if not isinstance(items, list):
        raise ModelError(f"{name}.{key} must be a list of mappings, got {type(items).__name__}")
    for j, e in enumerate(items):
        if not isinstance(e, dict) or set(e) != fields:
            raise ModelError(
                f"{name}.{key}[{j}] must be a mapping with {sorted(fields)}, got {e!r}"
            )
    return items


def _plain(m: FloatArray) -> Any:
    return float(m[0, 0]) if m.shape == (1, 1) else [[float(c) for c in r] for r in m]


def modal_to_dict(P: ModalPlant) -> dict[str, Any]:
    """The ``plant`` mapping of a modal plant (inverse of :func:`modal_from_dict`)."""
    out: dict[str, Any] = {"domain": "continuous" if P.dt is None else "discrete"}
    out["direct"] = _plain(P.direct)
    modes, reals = [], []
    for p, R in zip(P.poles, P.residues, strict=True):
        if p.imag > 0:
            s = p if P.dt is None else np.log(p) / P.dt
            w = abs(s)
            modes.append(
                {
                    "frequency_hz": float(w / (2.0 * math.pi)),
                    "damping": float(-s.real / w),
                    "c1": _plain(2.0 * R.real),
                    "c0": _plain(-2.0 * (R * np.conj(p)).real),
                }
            )
        else:
            reals.append({"pole": float(p.real), "residue": _plain(R.real)})
    if modes:
        out["modes"] = modes
    if reals:
        out["real_poles"] = reals
    return out
