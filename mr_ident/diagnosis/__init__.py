# SPDX-License-Identifier: Apache-2.0
"""Diagnosis: where and why a nominal model disagrees with measured data.

And the gain of an extended model (``mr-ident diagnose``).

:mod:`~mr_ident.diagnosis.diagnose` (the one call) and :mod:`~mr_ident.diagnosis.report`
(the JSON summary) at the top; in rooms: the criterion every cause is fitted by
(:mod:`~mr_ident.diagnosis.criterion`: prediction, the per-bin evidence, noise, the
objective), the causes (:mod:`~mr_ident.diagnosis.causes`: one class per cause, a
registry), their selection (:mod:`~mr_ident.diagnosis.selection`: fitting, forward
selection, equivalents), the controller's checks (:mod:`~mr_ident.diagnosis.controller`)
and monitoring (:mod:`~mr_ident.diagnosis.monitoring`: drift, the monitor). Above numerics
and I/O.
"""

from .diagnose import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
