# SPDX-License-Identifier: Apache-2.0
"""A model file's extensions of the nominal loop, read and checked.

The plant's gain and delay, added and moved modes, series dynamics, controller notches,
disturbances and the fitted plant corrections. Read by
:func:`~mr_ident.io.modelfile.model_from_dict` (the form: docs/formats.md); every problem is
a :class:`~mr_ident.errors.ModelError` naming the file and the entry's key.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ModelError
from ..numerics.systems.lti import TransferMatrix
from ..numerics.systems.modal import ModalPlant
from ..numerics.systems.model import CORRECTION_KINDS
from .modal_yaml import modal_from_dict


def _number(
    v: Any, where: str, low: float, high: float = math.inf, *, open_low: bool = False
) -> float:
    ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    if ok:
        ok = (v > low if open_low else v >= low) and v <= high
    if not ok:
        rng = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise ModelError(f"{where} must be a number in {rng}, got {v!r}")
    return float(v)


def _entries(d: Any, key: str, source: str, fields: dict[str, Any]) -> list[dict[str, Any]]:
    """A list of mappings with exactly the allowed fields (required when the default is None)."""
    items = d.get(key, [])
    if items is None:
        return []
    if not isinstance(items, list):
        raise ModelError(f"{source}: {key} must be a list of mappings, got {type(items).__name__}")
    out = []
    for j, e in enumerate(items):
        where = f"{source}: {key}[{j}]"
        if not isinstance(e, dict):
            raise ModelError(f"{where} must be a mapping, got {e!r}")
        unknown = set(e) - set(fields)
        if unknown:
            raise ModelError(
                f"{where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(fields)}"
            )
        missing = [k for k, v in fields.items() if v is None and k not in e]
        if missing:
            raise ModelError(f"{where}: missing {', '.join(missing)}")
        out.append({k: e.get(k, v) for k, v in fields.items()})
    return out


def model_extensions(
    d: dict[str, Any],
    source: str,
    fs: float,
    plant: TransferMatrix | ModalPlant,
    ratio: int,
    has_controller: bool,
) -> dict[str, Any]:
    """The :class:`~mr_ident.numerics.systems.model.Model` fields of the extensions in ``d``.

    ``source`` names the file in messages; ``fs``, ``plant``, ``ratio`` and
    ``has_controller`` bound the entries (a notch needs a controller, below the low-rate
    Nyquist frequency). ModelError naming the entry's key for anything out of its range.
    """
    gain = _number(d.get("plant_gain", 1.0), f"{source}: plant_gain", 0.0, open_low=True)
    delay = _number(d.get("input_delay_s", 0.0), f"{source}: input_delay_s", 0.0, 10.0)
    if "extra_modes" in d:
        raise ModelError(
            f"{source}: extra_modes is now series_dynamics (each {{frequency_hz, damping, "
            "side: input|output, channel}); an extra mode adding to the plant is additive_modes"
        )
    no, ni = plant.shape
    nyq = fs / 2
    adds = []
    fields_a = {"frequency_hz": None, "damping": None, "gain": None, "output": 0, "input": 0}
    for j, e in enumerate(_entries(d, "additive_modes", source, fields_a)):
        where = f"{source}: additive_modes[{j}]"
        f = _number(e["frequency_hz"], f"{where}.frequency_hz", 0.0, 100 * fs, open_low=True)
        z = _number(e["damping"], f"{where}.damping", 0.0, 10.0, open_low=True)
        g = _number(e["gain"], f"{where}.gain", -math.inf)
        adds.append(
            (
                f,
                z,
                g,
                _index(e["output"], f"{where}.output", no),
                _index(e["input"], f"{where}.input", ni),
            )
        )
    changes = []
    fields_c = {"from_hz": None, "frequency_hz": None, "damping": None, "residue_scale": 1.0}
    for j, e in enumerate(_entries(d, "mode_changes", source, fields_c)):
        where = f"{source}: mode_changes[{j}]"
        f0 = _number(e["from_hz"], f"{where}.from_hz", 0.0, 100 * fs, open_low=True)
        f = _number(e["frequency_hz"], f"{where}.frequency_hz", 0.0, 100 * fs, open_low=True)
        z = _number(e["damping"], f"{where}.damping", 0.0, 0.999, open_low=True)
        sc = _number(e["residue_scale"], f"{where}.residue_scale", 0.0, 1e6, open_low=True)
        changes.append((f0, f, z, sc))
    series = []
    fields_s = {"frequency_hz": None, "damping": 0.0, "side": "output", "channel": 0}
    for j, e in enumerate(_entries(d, "series_dynamics", source, fields_s)):
        where = f"{source}: series_dynamics[{j}]"
        f = _number(e["frequency_hz"], f"{where}.frequency_hz", 0.0, 100 * fs, open_low=True)
        z = _number(e["damping"], f"{where}.damping", 0.0, 10.0)
        side = e["side"]
        if side not in ("input", "output"):
            raise ModelError(f'{where}.side must be "input" or "output", got {side!r}')
        ch = _index(e["channel"], f"{where}.channel", ni if side == "input" else no)
        series.append((f, z, side, ch))
    notches = []
    fields_n = {"frequency_hz": None, "damping": None, "depth": None}
    for j, e in enumerate(_entries(d, "controller_notches", source, fields_n)):
        where = f"{source}: controller_notches[{j}]"
        f = _number(e["frequency_hz"], f"{where}.frequency_hz", 0.0, nyq / ratio, open_low=True)
        z = _number(e["damping"], f"{where}.damping", 0.0, 10.0, open_low=True)
        dp = _number(e["depth"], f"{where}.depth", 0.0, 10.0)
        notches.append((f, z, dp))
    if notches and not has_controller:
        raise ModelError(f"{source}: controller_notches need a controller")
    dist = []
    fields = {"frequency_hz": None, "amplitude": None, "phase_rad": 0.0, "output": 0}
    for j, e in enumerate(_entries(d, "disturbances", source, fields)):
        where = f"{source}: disturbances[{j}]"
        f = _number(e["frequency_hz"], f"{where}.frequency_hz", 0.0, fs / 2)
        a = _number(e["amplitude"], f"{where}.amplitude", 0.0)
        ph = _number(e["phase_rad"], f"{where}.phase_rad", -1e6, 1e6)
        o = e["output"]
        if isinstance(o, bool) or not isinstance(o, int) or not 0 <= o < plant.shape[0]:
            raise ModelError(
                f"{where}.output must be an output index in 0..{plant.shape[0] - 1}, got {o!r}"
            )
        dist.append((f, a, ph, o))
    if plant.dt is not None:
        for key, items in (
            ("additive_modes", adds),
            ("mode_changes", changes),
            ("series_dynamics", series),
        ):
            if items:
                raise ModelError(
                    f"{source}: {key} need a continuous-time plant (plant.domain: continuous)"
                )
        if abs(delay * fs - round(delay * fs)) > 1e-9:
            raise ModelError(
                f"{source}: with a discrete plant, input_delay_s must be a whole number of "
                f"sample times (1/fs_high = {1 / fs:g} s), got {delay!r}"
            )
    return dict(
        plant_corrections=_corrections(d, source, fs, plant.shape),
        plant_gain=gain,
        input_delay=delay,
        additive_modes=tuple(adds),
        mode_changes=tuple(changes),
        series_dynamics=tuple(series),
        controller_notches=tuple(notches),
        disturbances=tuple(dist),
    )


def _corrections(
    d: dict[str, Any], source: str, fs: float, shape: tuple[int, int]
) -> tuple[tuple[str, ModalPlant], ...]:
    """``plant_corrections``: each a kind and a discrete modal system (the module docstring)."""
    items = d.get("plant_corrections") or []
    if not isinstance(items, list):
        raise ModelError(
            f"{source}: plant_corrections must be a list of mappings, got {type(items).__name__}"
        )
    out = []
    for j, e in enumerate(items):
        where = f"plant_corrections[{j}]"
        if not isinstance(e, dict):
            raise ModelError(f"{source}: {where} must be a mapping, got {e!r}")
        kind = e.get("kind")
        if kind not in CORRECTION_KINDS:
            raise ModelError(
                f"{source}: {where}.kind must be one of {', '.join(CORRECTION_KINDS)}, "
                f"got {kind!r}"
            )
        if e.get("domain") != "discrete":
            raise ModelError(
                f"{source}: {where}.domain must be discrete (at 1/fs_high), got "
                f"{e.get('domain')!r}"
            )
        body = {k: v for k, v in e.items() if k != "kind"}
        try:
            C = modal_from_dict(body, where, 1.0 / fs)
        except ModelError as err:
            raise ModelError(f"{source}: {err}") from None
        want = shape if kind == "additive" else (shape[1], shape[1])
        if C.shape != want:
            raise ModelError(
                f"{source}: {where} is {C.shape[0]}x{C.shape[1]}; a {kind} correction "
                f"must be {want[0]}x{want[1]}"
            )
        if np.any(np.abs(C.poles) >= 1.0):
            raise ModelError(f"{source}: {where} has a pole on or outside the unit circle")
        out.append((str(kind), C))
    return tuple(out)


def _index(v: Any, where: str, n: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n:
        raise ModelError(f"{where} must be an index in 0..{n - 1}, got {v!r}")
    return v
