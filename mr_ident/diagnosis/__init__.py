"""Diagnosis: where and why a nominal model disagrees with measured data.

And the gain of an extended model (``mr-ident diagnose``).

:mod:`~mr_ident.diagnosis.prediction` (the model simulated on the data),
:mod:`~mr_ident.diagnosis.evidence` (the per-bin test), :mod:`~mr_ident.diagnosis.noise`,
:mod:`~mr_ident.diagnosis.objective` (the criterion), :mod:`~mr_ident.diagnosis.causes`
(one class per cause, a registry), :mod:`~mr_ident.diagnosis.diagnose` and
:mod:`~mr_ident.diagnosis.report` (the JSON summary). Above numerics and I/O.
"""

from .diagnose import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
