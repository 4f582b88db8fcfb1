"""mr_ident: frequency-domain identification of multirate control loops.

The core (this package minus the ``ros`` adapters) is pure numpy/scipy and imports
no ROS code. Shapes: signals (n_samples, n_channels); FRFs (n_freq, n_out, n_in)
complex128.

The public names below are imported on first use (PEP 562), so that ``import
mr_ident`` and the console scripts start in milliseconds rather than paying for
scipy and every module up front.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module (relative to this package) that defines it
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(("ConfigError", "DataError", "DimensionError", "ModelError", "MrIdentError"), "errors"),
    **dict.fromkeys(("METHODS", "identify"), "identify"),
    **dict.fromkeys(("dft", "idft", "freq_lift", "freq_unlift", "time_lift", "time_unlift", "lift_frf",
                     "unlift_frf"), "lifting"),
    **dict.fromkeys(("LPMFit", "lpm", "pad_circular"), "lpm"),
    **dict.fromkeys(("Model", "load_model", "model_from_dict"), "model"),
    **dict.fromkeys(("pfg_from_lifted", "pfg_from_plant"), "pfg"),
    **dict.fromkeys(("FRF", "PFG", "Identification", "LiftedFRF"), "results"),
    **dict.fromkeys(("Simulation", "lifted_loop", "simulate"), "simulate"),
    **dict.fromkeys(("StateSpace", "TransferMatrix"), "systems"),
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


if TYPE_CHECKING:   # for type checkers and IDEs: the same names, eagerly
    from .errors import ConfigError, DataError, DimensionError, ModelError, MrIdentError  # noqa: F401
    from .identify import METHODS, identify  # noqa: F401
    from .lifting import (dft, freq_lift, freq_unlift, idft, lift_frf, time_lift,  # noqa: F401
                          time_unlift, unlift_frf)
    from .lpm import LPMFit, lpm, pad_circular  # noqa: F401
    from .model import Model, load_model, model_from_dict  # noqa: F401
    from .pfg import pfg_from_lifted, pfg_from_plant  # noqa: F401
    from .results import FRF, PFG, Identification, LiftedFRF  # noqa: F401
    from .simulate import Simulation, lifted_loop, simulate  # noqa: F401
    from .systems import StateSpace, TransferMatrix  # noqa: F401
