# SPDX-License-Identifier: Apache-2.0
"""Monitoring: the plant held against a reference, estimate after estimate.

:mod:`~mr_ident.diagnosis.monitoring.drift` (an estimate against a reference, bin by bin)
and :mod:`~mr_ident.diagnosis.monitoring.monitor` (hysteresis, when to diagnose,
:class:`~mr_ident.diagnosis.monitoring.monitor.PlantWatch`). Nothing is imported here:
import the modules.
"""
