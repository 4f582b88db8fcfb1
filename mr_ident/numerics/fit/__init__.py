# SPDX-License-Identifier: Apache-2.0
"""A parametric model from an identified FRF: weighted, stable, MIMO with common poles.

``basis`` (poles, their stable parametrisation, the partial-fraction columns of each
domain), ``start`` (vector fitting's pole relocation), ``normal`` (Gram matrices over
blocks of bins), ``refine`` (variable projection, Levenberg–Marquardt, the parameters'
covariance), ``restart`` (leaving a local minimum), ``strategy`` (one order: starts,
delay candidates, restarts, coarse to fine), ``frf_fit`` (the public
:func:`~mr_ident.numerics.fit.frf_fit.fit_frf`, the expected cost band and the order).
"""
