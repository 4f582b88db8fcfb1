# SPDX-License-Identifier: Apache-2.0
"""The physical units of a loop's signals, from the model file's optional ``units`` key.

``units: {u: N m, y: rad}`` names the units of the plant's input and output; the figures
label the magnitude of P_h in dB re 1 y/u (``|P_h| [dB re 1 rad/(N m)]``). One unit per
signal: every channel of a MIMO loop shares it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..errors import ModelError


def units_from_dict(value: Any, *, source: str = "model") -> tuple[str, str] | None:
    """(u's unit, y's unit) of a model mapping's ``units`` value, or None where absent.

    Raises
    ------
    ModelError
        Not a mapping of ``u`` and ``y`` to non-empty strings.
    """
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) != {"u", "y"}:
        raise ModelError(
            f"{source}: units must be a mapping with keys u and y (units: {{u: N m, y: rad}}), "
            f"got {value!r}"
        )
    for key in ("u", "y"):
        v = value[key]
        if not isinstance(v, str) or not v.strip():
            raise ModelError(f"{source}: units.{key} must be a unit's name (text), got {v!r}")
    return value["u"].strip(), value["y"].strip()


def load_units(path: str | Path | None) -> tuple[str, str] | None:
    """The units a model file names (None without a file, or where it names none)."""
    if path is None:
        return None
    try:
        d = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError):
        return None  # the model's own reading says what is wrong with the file
    return units_from_dict(d.get("units") if isinstance(d, dict) else None, source=str(path))


def magnitude_label(units: tuple[str, str] | None, o: int, i: int, ny: int, nu: int) -> str:
    """The magnitude axis' label, in physical units where known.

    ``|P_h| [dB re 1 rad/(N m)]`` with the model file's units (``units: {u: N m, y:
    rad}``), else ``|P_h| [dB re 1 y/u]``; the entry (``y0←u1``) for MIMO.
    """
    entry = f" y{o}←u{i}" if ny * nu > 1 else ""
    if units is None:
        return f"|P_h{entry}| [dB re 1 y/u]"
    u, y = units
    u = f"({u})" if " " in u or "/" in u or "·" in u else u
    return f"|P_h{entry}| [dB re 1 {y}/{u}]"
