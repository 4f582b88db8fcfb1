"""The controller on the machine against the model's.

:mod:`~mr_ident.diagnosis.controller.check` (the PFG from data against the PFG from K_l;
:data:`~mr_ident.diagnosis.controller.check.COVERAGE`, the coverage level) and
:mod:`~mr_ident.diagnosis.controller.relation` (the controller's own equation: whether
the logged u follows from the logged y and r). Nothing is imported here: import the
modules.
"""
