# SPDX-License-Identifier: Apache-2.0
"""A fitted plant (``mr-ident fit``) as a model file, and its uncertainty beside it.

The model file holds the plant in modal form (:mod:`~mr_ident.io.modal_yaml`), the fitted
input delay as ``input_delay_s``, the rates of the identification and, when given, the
controller (and loop settings) of another model file; it is read back and checked like any
model (a loop that the fitted plant makes unstable is refused). The side file
``<stem>.fit.yaml`` holds the fit's cost and band, the orders tried and the std of each
mode's frequency, damping, residue and numerator.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import ModelError
from ..numerics.fit.frf_fit import FitResult
from ..numerics.systems.model import Model
from .atomic import atomic_write
from .modelfile import model_from_dict, model_to_dict


def fitted_model(fit: FitResult, *, ratio: int, controller: Model | None = None) -> Model:
    """The model of a fit: its plant and delay, the controller model's loop when given.

    Raises
    ------
    ModelError
        The controller model's rates or shape differ from the fit's, or the loop with the
        fitted plant is not stable.
    """
    if controller is not None:
        if not math.isclose(controller.fs_high, fit.fs, rel_tol=1e-9) or controller.ratio != ratio:
            raise ModelError(
                f"the controller model has fs_high {controller.fs_high:g} Hz and ratio "
                f"{controller.ratio}, expected those of the result: {fit.fs:g} Hz, {ratio}"
            )
        if controller.plant.shape != fit.plant.shape:
            raise ModelError(
                f"the controller model's plant is {controller.plant.shape}, expected the fit's "
                f"{fit.plant.shape}"
            )
        base = Model(
            fit.fs,
            ratio,
            fit.plant,
            controller.controller,
            controller.noise_std,
            controller.reference_std,
            controller.sample_phase,
            controller.control_delay,
            controller_notches=controller.controller_notches,
        )
    else:
        base = Model(fit.fs, ratio, fit.plant)
    model = replace(base, input_delay=fit.delay)
    return model_from_dict(model_to_dict(model), source="the fitted model")  # checked as read


def _mat(a: Any) -> Any:
    a = np.asarray(a, dtype=float)
    return float(a[0, 0]) if a.shape == (1, 1) else a.tolist()


def fit_summary(fit: FitResult) -> dict[str, Any]:
    """The side file's mapping: cost, band, orders tried, the std of every parameter."""
    modes = []
    for k, p in enumerate(fit.plant.poles):
        s = p if fit.domain == "continuous" else np.log(p) * fit.fs
        entry: dict[str, Any] = {
            "frequency_hz": float(abs(s) / (2 * math.pi)),
            "frequency_hz_std": float(fit.frequency_std[k]),
            "damping": float(-s.real / abs(s)),
            "damping_std": float(fit.damping_std[k]),
            "residue_re_std": _mat(fit.residue_std[k, ..., 0]),
            "residue_im_std": _mat(fit.residue_std[k, ..., 1]),
        }
        if p.imag > 0:
            entry.update(c1_std=_mat(fit.c1_std[k]), c0_std=_mat(fit.c0_std[k]))
        modes.append(entry)
    return {
        "order": fit.order,
        "domain": fit.domain,
        "delay_s": fit.delay,
        "delay_s_std": fit.delay_std,
        "delay_determined": fit.delay_determined,
        "cost": fit.cost,
        "expected_cost": fit.expected,
        "expected_cost_sd": fit.expected_sd,
        "bins": int(fit.frequency.size),
        "band_hz": [float(fit.frequency[0]), float(fit.frequency[-1])],
        "parameters": fit.n_params,
        "residual_rms_sigma": float(np.sqrt(np.mean(np.abs(fit.residual) ** 2))),
        "poles": modes,
        "orders": [
            {
                "order": r.order,
                "cost": r.cost,
                "expected": r.expected,
                "sd": r.sd,
                "aic": r.aic,
                "mdl": r.mdl,
                "delay_s": r.delay,
                "stable": r.stable,
            }
            for r in fit.orders
        ],
    }


def side_path(path: str | Path) -> Path:
    """``MODEL.yaml`` -> ``MODEL.fit.yaml``."""
    p = Path(path)
    return p.with_name(p.stem + ".fit.yaml")


def write_fit(
    path: str | Path, model: Model, fit: FitResult, units: tuple[str, str] | None = None
) -> tuple[Path, Path]:
    """Write the model file and its side file; returns both paths.

    ``units``: (u's, y's) physical units, written as the file's ``units`` (the
    ``--controller`` model's).
    """
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise ModelError(f"the model file must end in .yaml or .yml, got {str(p)!r}")
    head = (
        f"# fitted by mr-ident fit: order {fit.order} ({fit.domain}), cost {fit.cost:.6g} "
        f"(expected {fit.expected:.6g} ± {2 * fit.expected_sd:.3g}), delay {fit.delay:.6g} s\n"
        f"# the std of every parameter: {side_path(p).name}\n"
    )
    d = model_to_dict(model)
    if units is not None:
        d["units"] = {"u": units[0], "y": units[1]}
    text = head + yaml.safe_dump(d, sort_keys=False)
    atomic_write(p, lambda fh: fh.write(text), binary=False)
    side = side_path(p)
    body = yaml.safe_dump(fit_summary(fit), sort_keys=False)
    atomic_write(side, lambda fh: fh.write(body), binary=False)
    return p, side
