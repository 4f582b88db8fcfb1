# SPDX-License-Identifier: Apache-2.0
"""Excitation and periodic records: multisines, schedules, block sources and the BLA.

:mod:`~mr_ident.numerics.excitation.multisine` (periodic multisines),
:mod:`~mr_ident.numerics.excitation.schedule` (a periodic excitation played in a loop),
:mod:`~mr_ident.numerics.excitation.sources` (excitation and the simulated loop, block by
block) and :mod:`~mr_ident.numerics.excitation.bla` (the best linear approximation: noise
and nonlinear distortion). Nothing is imported here: import the modules.
"""
