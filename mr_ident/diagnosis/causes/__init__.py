# SPDX-License-Identifier: Apache-2.0
"""Causes: why a model is wrong, one class per cause.

:mod:`~mr_ident.diagnosis.causes.cause` (what a cause is, what a fitted one holds),
:mod:`~mr_ident.diagnosis.causes.plant_causes` (those that change P_h),
:mod:`~mr_ident.diagnosis.causes.loop_causes` (those in the controller's path and on the
output) and :mod:`~mr_ident.diagnosis.causes.registry` (:data:`CAUSES` by name). Nothing
is imported here: import the modules.
"""
