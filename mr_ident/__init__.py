"""mr_ident: frequency-domain identification of multirate control loops.

The core (this package minus ``node``/``mcap`` adapters) is pure numpy/scipy and
imports no ROS code. Shapes: signals (n_samples, n_channels); FRFs
(n_freq, n_out, n_in) complex128.
"""

from .errors import ConfigError, DataError, DimensionError, ModelError, MrIdentError
from .identify import METHODS, identify
from .lifting import dft, freq_lift, freq_unlift, idft, lift_frf, time_lift, time_unlift, unlift_frf
from .lpm import LPMFit, lpm, pad_circular
from .model import Model, load_model, model_from_dict
from .pfg import pfg_from_lifted, pfg_from_plant
from .results import FRF, PFG, Identification, LiftedFRF
from .simulate import Simulation, lifted_loop, simulate
from .systems import StateSpace, TransferMatrix

__all__ = [
    "ConfigError", "DataError", "DimensionError", "ModelError", "MrIdentError",
    "METHODS", "identify", "dft", "idft", "freq_lift", "freq_unlift", "time_lift", "time_unlift",
    "lift_frf", "unlift_frf", "LPMFit", "lpm", "pad_circular", "Model", "load_model",
    "model_from_dict", "pfg_from_lifted", "pfg_from_plant", "FRF", "PFG", "Identification",
    "LiftedFRF", "Simulation", "lifted_loop", "simulate", "StateSpace", "TransferMatrix",
]
__version__ = "0.1.0"
