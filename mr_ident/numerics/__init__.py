# SPDX-License-Identifier: Apache-2.0
"""Numerics: the lowest layer (pure numpy/scipy, no I/O, no ROS).

Lifting (:mod:`~mr_ident.numerics.lifting`), identification
(:mod:`~mr_ident.numerics.identify`), the one container of loop signals and the frozen
result types at the top; in rooms: the local models (:mod:`~mr_ident.numerics.local`), the
lifted maps and the PFG (:mod:`~mr_ident.numerics.lifted`), excitation, periodic records
and the BLA (:mod:`~mr_ident.numerics.excitation`), LTI systems, the loop model and
simulation (:mod:`~mr_ident.numerics.systems`). Imports only :mod:`mr_ident.errors`;
nothing is imported here (import the modules).
"""
