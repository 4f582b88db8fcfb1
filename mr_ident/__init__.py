# SPDX-License-Identifier: Apache-2.0
"""mr_ident: frequency-domain identification of multirate control loops.

Layers, each importing only those beneath it: :mod:`~mr_ident.numerics` (pure
numpy/scipy), :mod:`~mr_ident.io`, :mod:`~mr_ident.live`, :mod:`~mr_ident.diagnosis`,
then the adapters (``ros/``, ``cli``, ``plots``, ``paper``, ``htmlreport``). Only
``ros/`` imports ROS code. Shapes: signals (n_samples, n_channels); FRFs (n_freq, n_out, n_in)
complex128.

The public names below are imported on first use (PEP 562), so that ``import
mr_ident`` and the console scripts start in milliseconds rather than paying for
scipy and every module up front.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .version import __version__  # noqa: F401  (re-exported)

#: public name -> module (relative to this package) that defines it
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(
        ("ConfigError", "DataError", "DimensionError", "ModelError", "MrIdentError"), "errors"
    ),
    **dict.fromkeys(("METHODS", "identify"), "numerics.identify"),
    **dict.fromkeys(
        (
            "dft",
            "idft",
            "freq_lift",
            "freq_unlift",
            "time_lift",
            "time_unlift",
            "lift_frf",
            "unlift_frf",
        ),
        "numerics.lifting",
    ),
    **dict.fromkeys(("LPMFit", "lpm", "pad_circular"), "numerics.local.lpm"),
    "Model": "numerics.systems.model",
    **dict.fromkeys(("load_model", "model_from_dict", "model_to_dict"), "io.modelfile"),
    **dict.fromkeys(("pfg_from_lifted", "pfg_from_plant"), "numerics.lifted.pfg"),
    **dict.fromkeys(("FRF", "PFG", "Identification", "LiftedFRF"), "numerics.results"),
    "LoopData": "numerics.signals",
    **dict.fromkeys(("lifted_loop", "simulate"), "numerics.systems.simulate"),
    **dict.fromkeys(("StateSpace", "TransferMatrix"), "numerics.systems.lti"),
    **dict.fromkeys(("Diagnosis", "diagnose"), "diagnosis"),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'mr_ident' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # for type checkers and IDEs: the same names, eagerly
    from .diagnosis import Diagnosis, diagnose  # noqa: F401
    from .errors import ConfigError, DataError, DimensionError, ModelError, MrIdentError  # noqa: F401
    from .io.modelfile import load_model, model_from_dict, model_to_dict  # noqa: F401
    from .numerics.identify import METHODS, identify  # noqa: F401
    from .numerics.lifted.pfg import pfg_from_lifted, pfg_from_plant  # noqa: F401
    from .numerics.lifting import (
        dft,
        freq_lift,
        freq_unlift,
        idft,
        lift_frf,
        time_lift,  # noqa: F401
        time_unlift,
        unlift_frf,
    )
    from .numerics.local.lpm import LPMFit, lpm, pad_circular  # noqa: F401
    from .numerics.results import FRF, PFG, Identification, LiftedFRF  # noqa: F401
    from .numerics.signals import LoopData  # noqa: F401
    from .numerics.systems.lti import StateSpace, TransferMatrix  # noqa: F401
    from .numerics.systems.model import Model  # noqa: F401
    from .numerics.systems.simulate import lifted_loop, simulate  # noqa: F401
