# SPDX-License-Identifier: Apache-2.0
"""Local models: the per-bin fits every identification method rests on.

:mod:`~mr_ident.numerics.local.lpm` (the local polynomial method),
:mod:`~mr_ident.numerics.local.lrm` (the local rational method),
:mod:`~mr_ident.numerics.local.fit` (either, one call), their moment sums over sliding
windows (:mod:`~mr_ident.numerics.local.window_sums`) and the automatic window half-width
(:mod:`~mr_ident.numerics.local.bandwidth`). Nothing is imported here: import the modules.
"""
