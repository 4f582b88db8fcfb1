# SPDX-License-Identifier: Apache-2.0
"""Model files (YAML): read, validate and write a :class:`~mr_ident.numerics.systems.model.Model`.

The form is the one in :mod:`mr_ident.numerics.systems.model`'s docstring and
docs/formats.md. Every problem is a :class:`~mr_ident.errors.ModelError` naming the file
and the key (``plant.num[2]``), or the YAML line and column; an unstable loop is refused.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import ModelError, yaml_problem
from ..numerics.structure import INJECTIONS
from ..numerics.systems.lti import TransferMatrix
from ..numerics.systems.modal import ModalPlant
from ..numerics.systems.model import Model
from ..numerics.systems.simulate import loop_poles
from .modal_yaml import modal_from_dict, modal_to_dict
from .model_extensions import model_extensions
from .units import units_from_dict

_KEYS = {
    "fs_high",
    "ratio",
    "plant",
    "controller",
    "noise_std",
    "reference_std",
    "sample_phase",
    "control_delay",
    "injection",
    "plant_gain",
    "input_delay_s",
    "additive_modes",
    "mode_changes",
    "series_dynamics",
    "controller_notches",
    "disturbances",
    "plant_corrections",
    "units",
}
_SYS_KEYS = {"num", "den", "domain"}


def _coeffs(value: Any, where: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise ModelError(f"{where} must be a non-empty list of numbers, got {value!r}")
    out = []
    for j, c in enumerate(value):
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c):
            raise ModelError(f"{where}[{j}] must be a finite number, got {c!r}")
        out.append(float(c))
    return tuple(out)


def _matrix(
    value: Any, where: str, shape: tuple[int, int] | None
) -> tuple[tuple[tuple[float, ...], ...], ...]:
    """A coefficient list (SISO) or nested [out][in][coeff] list."""
    if isinstance(value, (list, tuple)) and value and isinstance(value[0], (list, tuple)):
        rows = []
        for o, row in enumerate(value):
            if (
                not isinstance(row, (list, tuple))
                or not row
                or not isinstance(row[0], (list, tuple))
            ):
                raise ModelError(
                    f"{where}[{o}] must be a list of coefficient lists (MIMO form "
                    "[out][in][coeff])"
                )
            rows.append(tuple(_coeffs(e, f"{where}[{o}][{i}]") for i, e in enumerate(row)))
        if len({len(r) for r in rows}) != 1:
            raise ModelError(f"{where} rows have different lengths: {[len(r) for r in rows]}")
        m = tuple(rows)
    else:
        m = ((_coeffs(value, where),),)
    if shape is not None and (len(m), len(m[0])) != shape:
        if (len(m), len(m[0])) == (1, 1):
            return tuple(tuple(m[0][0] for _ in range(shape[1])) for _ in range(shape[0]))
        raise ModelError(f"{where} has shape {(len(m), len(m[0]))}, expected {shape}")
    return m


def _system(d: Any, name: str, dt: float | None) -> TransferMatrix:
    if not isinstance(d, dict):
        raise ModelError(f"{name} must be a mapping with num and den, got {type(d).__name__}")
    unknown = set(d) - _SYS_KEYS
    if unknown:
        raise ModelError(f"{name}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_SYS_KEYS)}")
    for key in ("num", "den"):
        if key not in d:
            raise ModelError(f"{name}.{key} is missing")
    num = _matrix(d["num"], f"{name}.num", None)
    den = _matrix(d["den"], f"{name}.den", (len(num), len(num[0])))
    for o, row in enumerate(den):
        for i, a in enumerate(row):
            if a[0] == 0.0:
                raise ModelError(f"{name}.den[{o}][{i}] has a zero leading coefficient")
            b = num[o][i]
            if len(np.trim_zeros(np.array(b), "f")) > len(a):
                raise ModelError(
                    f"{name} entry [{o}][{i}] is improper (numerator degree > denominator degree)"
                )
    return TransferMatrix(num, den, dt)


def model_from_dict(d: Any, *, source: str = "model") -> Model:
    """Validate a parsed model mapping (see the module docstring for the form).

    Parameters
    ----------
    d : mapping
        The model file's content (``yaml.safe_load``); ``source`` names it in errors.

    Returns
    -------
    Model

    Raises
    ------
    ModelError
        Unknown or missing keys, non-numeric coefficients, inconsistent
        dimensions, or a closed loop that is not stable.
    """
    if not isinstance(d, dict):
        raise ModelError(f"{source}: the model must be a mapping, got {type(d).__name__}")
    unknown = set(d) - _KEYS
    if unknown:
        raise ModelError(f"{source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_KEYS)}")
    for key in ("fs_high", "ratio", "plant"):
        if key not in d:
            raise ModelError(f"{source}: required key {key!r} is missing")
    units_from_dict(d.get("units"), source=source)  # the figures' (io.units), checked here
    fs = d["fs_high"]
    if (
        isinstance(fs, bool)
        or not isinstance(fs, (int, float))
        or not math.isfinite(fs)
        or fs <= 0
    ):
        raise ModelError(f"{source}: fs_high must be a positive number (Hz), got {fs!r}")
    F = d["ratio"]
    if isinstance(F, bool) or not isinstance(F, int) or F < 1:
        raise ModelError(f"{source}: ratio must be an integer >= 1, got {F!r}")
    ints = {}
    for key in ("sample_phase", "control_delay"):
        v = d.get(key, 0)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ModelError(f"{source}: {key} must be an integer >= 0, got {v!r}")
        ints[key] = v
    if ints["sample_phase"] >= F:
        raise ModelError(
            f"{source}: sample_phase must be in 0..{F - 1}, got {ints['sample_phase']}"
        )
    injection = d.get("injection")
    if injection is not None and injection not in INJECTIONS:
        raise ModelError(
            f"{source}: injection must be one of {', '.join(INJECTIONS)}, got {injection!r}"
        )
    if injection == "setpoint" and d.get("controller") is None:
        raise ModelError(
            f"{source}: injection setpoint needs a controller (the setpoint is its input)"
        )
    floats = {}
    for key, default in (("noise_std", 0.0), ("reference_std", 1.0)):
        v = d.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ModelError(f"{source}: {key} must be a number >= 0, got {v!r}")
        floats[key] = float(v)
    plant, controller = _plant_and_controller(d, source, float(fs), F)
    ext = model_extensions(d, source, float(fs), plant, F, controller is not None)
    model = Model(
        float(fs),
        F,
        plant,
        controller,
        floats["noise_std"],
        floats["reference_std"],
        ints["sample_phase"],
        ints["control_delay"],
        injection=injection,
        **ext,
    )
    rho = float(np.max(np.abs(loop_poles(model)), initial=0.0))
    if rho >= 1.0:
        what = "closed loop" if controller is not None else "open-loop plant"
        raise ModelError(
            f"{source}: the {what} is not stable (largest lifted pole magnitude "
            f"{rho:.6g} >= 1); identification needs a stable loop"
        )
    return model


def _plant_and_controller(
    d: dict[str, Any], source: str, fs: float, F: int
) -> tuple[TransferMatrix | ModalPlant, TransferMatrix | None]:
    """The plant (polynomials, or the modal form of ``mr-ident fit``) and the controller.

    ModelError naming the file and the key: a domain neither continuous nor discrete, a
    controller not discrete, or one that does not fit the plant (n_u x n_y).
    """
    pd = d["plant"]
    domain = pd.get("domain", "continuous") if isinstance(pd, dict) else "continuous"
    if domain not in ("continuous", "discrete"):
        raise ModelError(
            f'{source}: plant.domain must be "continuous" or "discrete", got {domain!r}'
        )
    try:  # _system's messages name the key; add the file
        dt = None if domain == "continuous" else 1.0 / fs
        plant: TransferMatrix | ModalPlant
        if isinstance(pd, dict) and ("direct" in pd or "modes" in pd or "real_poles" in pd):
            plant = modal_from_dict(pd, "plant", dt)  # the modal form (mr-ident fit)
        else:
            plant = _system(pd, "plant", dt)
        controller = None
        if d.get("controller") is not None:
            cd = d["controller"]
            if isinstance(cd, dict) and cd.get("domain", "discrete") != "discrete":
                raise ModelError(
                    "controller must be discrete (at the low rate), got domain "
                    f"{cd.get('domain')!r}"
                )
            controller = _system(cd, "controller", F / fs)
    except ModelError as err:
        raise ModelError(f"{source}: {err}") from None
    if controller is not None and controller.shape != (plant.shape[1], plant.shape[0]):
        raise ModelError(
            f"{source}: controller is {controller.shape[0]}x{controller.shape[1]}, "
            f"expected n_u x n_y = {plant.shape[1]}x{plant.shape[0]}"
        )
    return plant, controller


def load_model(path: str | Path) -> Model:
    """Read and validate a model YAML file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Model

    Raises
    ------
    ModelError
        The file cannot be read, is not YAML, or is not a valid model.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise ModelError(f"cannot read model file {str(p)!r}: {err.strerror}") from err
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ModelError(f"{p}: not valid YAML: {yaml_problem(err)}") from None
    return model_from_dict(d, source=str(p))


#: The model-file fields of each list extension (a Model attribute of the same name), in
#: the order of its tuples.
_EXTENSION_FIELDS: dict[str, tuple[str, ...]] = {
    "additive_modes": ("frequency_hz", "damping", "gain", "output", "input"),
    "mode_changes": ("from_hz", "frequency_hz", "damping", "residue_scale"),
    "series_dynamics": ("frequency_hz", "damping", "side", "channel"),
    "controller_notches": ("frequency_hz", "damping", "depth"),
    "disturbances": ("frequency_hz", "amplitude", "phase_rad", "output"),
}


def _plain(v: Any) -> Any:
    """A value as plain YAML: str stays, integers int, the rest float."""
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return int(v)
    return float(v)


def _rate(fs: float) -> float | int:
    """A rate as a person gives it: ``240``, not the ``239.99999999999997`` of stamps.

    12 significant digits; a whole number without a point.
    """
    v = float(f"{fs:.12g}")
    return int(v) if v.is_integer() else v


def model_to_dict(model: Model) -> dict[str, Any]:
    """The YAML mapping of a model (inverse of :func:`model_from_dict`): plain values.

    Parameters
    ----------
    model : Model

    Returns
    -------
    dict
    """

    def sysd(t: TransferMatrix, domain: str | None) -> dict[str, Any]:
        num = [[[float(c) for c in e] for e in row] for row in t.num]  # plain floats for YAML
        den = [[[float(c) for c in e] for e in row] for row in t.den]
        out: dict[str, Any] = (
            {"num": num[0][0], "den": den[0][0]} if t.shape == (1, 1) else {"num": num, "den": den}
        )
        if domain:
            out["domain"] = domain
        return out

    d: dict[str, Any] = {
        "fs_high": _rate(model.fs_high),
        "ratio": int(model.ratio),
        "plant": modal_to_dict(model.plant)
        if isinstance(model.plant, ModalPlant)
        else sysd(model.plant, "continuous" if model.plant.dt is None else "discrete"),
    }
    if model.controller is not None:
        d["controller"] = sysd(model.controller, None)
    d.update(
        noise_std=float(model.noise_std),
        reference_std=float(model.reference_std),
        sample_phase=int(model.sample_phase),
        control_delay=int(model.control_delay),
    )
    if model.injection is not None:
        d["injection"] = model.injection
    if model.plant_gain != 1.0:
        d["plant_gain"] = float(model.plant_gain)
    if model.input_delay:
        d["input_delay_s"] = float(model.input_delay)
    for key, names in _EXTENSION_FIELDS.items():
        items = getattr(model, key)  # the Model attribute has the key's name
        if items:
            d[key] = [{n: _plain(v) for n, v in zip(names, t, strict=True)} for t in items]
    if model.plant_corrections:
        d["plant_corrections"] = [
            {"kind": kind, **modal_to_dict(C)} for kind, C in model.plant_corrections
        ]
    return d
