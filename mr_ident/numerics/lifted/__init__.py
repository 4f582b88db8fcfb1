# SPDX-License-Identifier: Apache-2.0
"""The lifted maps: identification methods on the lifted loop, and the PFG.

:mod:`~mr_ident.numerics.lifted.methods` (the methods as a table),
:mod:`~mr_ident.numerics.lifted.structured`, the lifted loop
(:mod:`~mr_ident.numerics.lifted.loop`), the PFG from a plant and controller
(:mod:`~mr_ident.numerics.lifted.pfg`) and from data
(:mod:`~mr_ident.numerics.lifted.pfg_data`), the alias range
(:mod:`~mr_ident.numerics.lifted.alias_range`) and P_h from a low-rate output
(:mod:`~mr_ident.numerics.lifted.slow_periodic`). Nothing is imported here: import the
modules.
"""
