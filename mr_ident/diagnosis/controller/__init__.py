# SPDX-License-Identifier: Apache-2.0
"""The controller on the machine against the model's: its own equation.

:mod:`~mr_ident.diagnosis.controller.relation` (the controller's own equation: whether
the logged u follows from the logged y and r). The PFG from data against the PFG from
K_l, which ``identify`` reports too, lives beneath the diagnosis, in
:mod:`~mr_ident.numerics.lifted.pfg_check` (with the coverage level ``COVERAGE``).
Nothing is imported here: import the modules.
"""
